// The command server over real TCP and Unix sockets, on a fake Instrument: many clients at once,
// hostile and slow clients, *OPC? without blocking others, start errors, clean stop.
#include <gtest/gtest.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <atomic>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "daemon/protocol.h"
#include "daemon/server.h"
#include "tests/daemon/fake_instrument.h"
#include "tests/daemon/socket_client.h"

using namespace idm::daemon;
using idm::daemon::testing::eventually;
using idm::daemon::testing::FakeInstrument;
using idm::daemon::testing::LineClient;

namespace {

class ServerTest : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = idm::daemon::testing::make_temp_dir(); }
  void TearDown() override {
    if (server_) server_->stop();
    std::filesystem::remove_all(dir_);
  }
  ServerConfig config() const {
    ServerConfig c;
    c.tcp_port = 0;
    c.unix_path = dir_ + "/idmd.sock";
    return c;
  }
  void start(ServerConfig c) {
    server_ = std::make_unique<Server>(fake_, std::move(c));
    const std::string error = server_->start();
    ASSERT_EQ(error, "");
    ASSERT_GT(server_->tcp_port(), 0);
  }
  void start() { start(config()); }
  LineClient tcp() { return LineClient::tcp(server_->tcp_port()); }
  LineClient unix_client() { return LineClient::unix_socket(server_->unix_path()); }

  FakeInstrument fake_;
  std::unique_ptr<Server> server_;  // after fake_: stopped before the fake goes
  std::string dir_;
};

}  // namespace

TEST_F(ServerTest, AnswersOnTcpAndOnTheUnixSocketWithMode0660) {
  start();
  LineClient t = tcp();
  ASSERT_TRUE(t.ok());
  EXPECT_EQ(t.ask("*IDN?"), "idm,idmd,0,test");
  LineClient u = unix_client();
  ASSERT_TRUE(u.ok());
  EXPECT_EQ(u.ask("*idn?"), "idm,idmd,0,test");
  struct stat st {};
  ASSERT_EQ(stat(server_->unix_path().c_str(), &st), 0);
  EXPECT_TRUE(S_ISSOCK(st.st_mode));
  EXPECT_EQ(st.st_mode & 0777, 0660u);
  // Commands get no reply: the next line read is the query's.
  ASSERT_TRUE(t.send("MOVE:ABS 1e-6\r\nPOS?\r\n"));
  EXPECT_EQ(t.line(), "1e-06");
  EXPECT_EQ(fake_.last_call(), "move_absolute(1e-06)");
}

TEST_F(ServerTest, ManyClientsAtOnceEachGetTheirOwnRepliesAndErrors) {
  ServerConfig config24 = config();
  config24.max_clients = 24;
  start(config24);
  std::vector<LineClient> clients;
  for (int k = 0; k < 24; ++k) {
    clients.push_back(k % 2 ? tcp() : unix_client());
    ASSERT_TRUE(clients.back().ok()) << k;
  }
  // Everyone pipelines first, then everyone reads.
  for (int k = 0; k < 24; ++k) {
    std::string batch;
    for (int q = 0; q < 20; ++q) batch += "REG? " + std::to_string(100 + k) + ",0.1\n";
    if (k % 3 == 0) batch += "BOGUS\n";
    batch += "SYST:ERR?\n";
    ASSERT_TRUE(clients[static_cast<std::size_t>(k)].send(batch));
  }
  for (int k = 0; k < 24; ++k) {
    LineClient& c = clients[static_cast<std::size_t>(k)];
    for (int q = 0; q < 20; ++q)
      ASSERT_EQ(c.line(), "ONESTEP," + format_value(-(100 + k) * 1e-9)) << k << " " << q;
    EXPECT_EQ(c.line(), k % 3 == 0 ? "-113,\"Undefined header; 'BOGUS'\"" : "0,\"No error\"") << k;
  }
  EXPECT_EQ(server_->clients(), 24);
}

TEST_F(ServerTest, AClientStreamingWithoutNewlineIsDisconnectedWhileOthersAreServed) {
  start();
  LineClient good = tcp();
  LineClient hostile = tcp();
  ASSERT_TRUE(good.ok() && hostile.ok());
  EXPECT_EQ(good.ask("*IDN?"), "idm,idmd,0,test");
  std::atomic<std::size_t> sent{0};
  std::atomic<bool> cut_off{false};
  std::thread flood([&] {
    const std::string chunk(65536, 'A');
    while (sent < (std::size_t{64} << 20)) {
      if (!hostile.send(chunk)) {
        cut_off = true;
        return;
      }
      sent += chunk.size();
    }
  });
  // Served while the flood goes on.
  for (int k = 0; k < 50; ++k) ASSERT_EQ(good.ask("POS?"), "0") << k;
  flood.join();
  EXPECT_TRUE(cut_off.load());                   // the server cut it off
  EXPECT_GE(sent.load(), std::size_t{1} << 20);  // not before a megabyte
  EXPECT_TRUE(hostile.wait_closed());
  EXPECT_TRUE(eventually([&] { return server_->counters().dropped_no_newline == 1; }));
  EXPECT_EQ(good.ask("*IDN?"), "idm,idmd,0,test");
  EXPECT_EQ(fake_.motion_calls(), 0u);
}

TEST_F(ServerTest, AClientThatNeverReadsIsDisconnectedAndDoesNotStallOthers) {
  ServerConfig c = config();
  c.max_output_bytes = 64 << 10;
  start(c);
  LineClient good = unix_client();
  LineClient slow = tcp();
  ASSERT_TRUE(good.ok() && slow.ok());
  const int small = 4096;
  setsockopt(slow.fd(), SOL_SOCKET, SO_RCVBUF, &small, sizeof small);
  std::atomic<bool> cut_off{false};
  std::thread writer([&] {
    std::string batch;
    for (int k = 0; k < 1000; ++k) batch += "SYST:LOOP?\n";  // ~14x more reply than request
    for (int k = 0; k < 20000; ++k)
      if (!slow.send(batch)) {
        cut_off = true;
        return;
      }
  });
  for (int k = 0; k < 50; ++k) ASSERT_EQ(good.ask("*IDN?"), "idm,idmd,0,test") << k;
  writer.join();
  EXPECT_TRUE(cut_off.load());
  EXPECT_TRUE(eventually([&] { return server_->counters().dropped_slow_reader == 1; }));
  EXPECT_EQ(good.ask("MOVE:DONE?"), "1");
}

TEST_F(ServerTest, ATooLongLineIsAnErrorAndTheConnectionStays) {
  start();
  LineClient t = tcp();
  ASSERT_TRUE(t.send(std::string(5000, 'A') + "\n"));
  EXPECT_EQ(t.ask("SYST:ERR?"),
            "-363,\"Input buffer overrun; line longer than 4096 bytes, discarded\"");
  ASSERT_TRUE(t.send("MOVE:ABS \xc3\xa9\n"));
  EXPECT_EQ(std::stoi(t.ask("SYST:ERR?")), error_code::kInvalidCharacter);
  EXPECT_EQ(fake_.motion_calls(), 0u);
}

TEST_F(ServerTest, OpcQueryWaitsForTheMotionWithoutBlockingOtherClients) {
  start();
  fake_.set_polls_until_done(1 << 30);  // a motion that does not end by itself
  LineClient mover = tcp();
  LineClient other = unix_client();
  ASSERT_TRUE(mover.send("MOVE:ABS 2e-6\n*OPC?\n*IDN?\n"));
  EXPECT_EQ(other.ask("MOVE:DONE?"), "0");  // the move is on, and the server still answers
  EXPECT_EQ(other.ask("*IDN?"), "idm,idmd,0,test");
  ASSERT_TRUE(other.send("STOP\n"));
  EXPECT_EQ(mover.line(), "1");
  EXPECT_EQ(mover.line(), "idm,idmd,0,test");
}

TEST_F(ServerTest, AHalfClosedClientStillGetsItsRepliesButItsUnterminatedLineNeverRuns) {
  start();
  LineClient t = tcp();
  ASSERT_TRUE(t.send("POS?\n*IDN?\nMOVE:REL 1"));  // the last line without its newline
  shutdown(t.fd(), SHUT_WR);
  EXPECT_EQ(t.line(), "0");
  EXPECT_EQ(t.line(), "idm,idmd,0,test");
  EXPECT_EQ(t.line(), "<eof>");
  EXPECT_TRUE(eventually([&] { return server_->clients() == 0; }));
  EXPECT_EQ(fake_.motion_calls(), 0u);
}

TEST_F(ServerTest, AHalfClosedClientWaitingForOpcGetsItsReplyAndFreesItsSlot) {
  ServerConfig c = config();
  c.max_clients = 1;
  start(c);
  fake_.set_polls_until_done(1 << 30);  // a motion that does not end by itself
  LineClient waiter = tcp();
  ASSERT_TRUE(waiter.send("MOVE:ABS 2e-6\n*OPC?\n"));
  shutdown(waiter.fd(), SHUT_WR);  // like `printf ... | nc -N`
  ASSERT_TRUE(eventually([&] { return fake_.motion_calls() == 1; }));
  // The half-closed waiter no longer holds the one slot: a new client is served in full.
  LineClient next = tcp();
  EXPECT_EQ(next.ask("*IDN?"), "idm,idmd,0,test");
  ASSERT_TRUE(next.send("STOP\n"));
  EXPECT_EQ(waiter.line(), "1");  // and the waiter still gets its reply
  EXPECT_EQ(waiter.line(), "<eof>");
}

TEST_F(ServerTest, ClientsThatVanishWhileWaitingForOpcFreeTheirSlotsAtOnce) {
  ServerConfig c = config();
  c.max_clients = 3;
  start(c);
  fake_.set_polls_until_done(1 << 30);
  {
    LineClient a = unix_client(), b = unix_client(), t = tcp();
    ASSERT_TRUE(a.send("MOVE:ABS 2e-6\n*OPC?\n"));
    ASSERT_TRUE(b.send("*OPC?\n"));
    ASSERT_TRUE(t.send("*OPC?\n"));
    ASSERT_TRUE(eventually([&] { return server_->clients() == 3; }));
  }  // all three close without reading
  // The Unix-socket peers hang up: closed at once. The TCP peer's FIN looks like a half-close
  // (it could still read): it drains, without a slot, until its reply fails or is written.
  EXPECT_TRUE(eventually([&] { return server_->clients() <= 1; }));
  LineClient d = tcp(), e = tcp(), f = unix_client();
  EXPECT_EQ(d.ask("MOVE:DONE?"), "0");  // the motion is still on: these are full clients
  EXPECT_EQ(e.ask("*IDN?"), "idm,idmd,0,test");
  ASSERT_TRUE(f.send("STOP\n"));
  EXPECT_EQ(d.ask("*OPC?"), "1");
}

TEST_F(ServerTest, WithTheTableFullAStopStillGetsThrough) {
  ServerConfig c = config();
  c.max_clients = 2;
  c.overflow_slots = 2;
  start(c);
  fake_.set_polls_until_done(1 << 30);
  LineClient a = tcp(), b = unix_client();
  EXPECT_EQ(a.ask("*OPC?"), "1");
  ASSERT_TRUE(a.send("MOVE:ABS 2e-6\n"));
  EXPECT_EQ(b.ask("MOVE:DONE?"), "0");
  // Two hogs take the stop-only slots and sit on them; a third newcomer evicts the oldest.
  LineClient hog1 = tcp(), hog2 = unix_client();
  ASSERT_TRUE(eventually([&] { return server_->clients() == 4; }));
  LineClient stopper = tcp();
  EXPECT_TRUE(hog1.wait_closed());
  EXPECT_EQ(stopper.ask("MOVE:ABS 1e-6\nSYST:ERR?").rfind("-221,", 0), 0u);  // only STOP here
  EXPECT_EQ(std::stoi(stopper.ask("SYST:ERR?")), 0);
  ASSERT_TRUE(stopper.send("STOP\n"));
  EXPECT_TRUE(eventually([&] { return fake_.last_call() == "stop"; }));
  EXPECT_EQ(b.ask("MOVE:DONE?"), "1");
  EXPECT_EQ(fake_.motion_calls(), 1u);  // the stop-only client's MOVE never ran
  EXPECT_GE(server_->counters().rejected_max_clients, 3u);
}

TEST_F(ServerTest, AStopOnlyClientIsClosedAfterItsLingerTime) {
  ServerConfig c = config();
  c.max_clients = 1;
  c.overflow_linger_s = 0.2;
  start(c);
  LineClient a = tcp();
  EXPECT_EQ(a.ask("*IDN?"), "idm,idmd,0,test");
  LineClient extra = tcp();
  EXPECT_EQ(extra.ask("*IDN?"), "idm,idmd,0,test");
  EXPECT_TRUE(extra.wait_closed());
  EXPECT_EQ(a.ask("*IDN?"), "idm,idmd,0,test");  // the full client is untouched
}

TEST_F(ServerTest, ClientsPastTheLimitGetAStopOnlySlot) {
  ServerConfig c = config();
  c.max_clients = 2;
  start(c);
  LineClient a = tcp(), b = unix_client();
  EXPECT_EQ(a.ask("*OPC?"), "1");
  EXPECT_EQ(b.ask("*OPC?"), "1");
  LineClient third = tcp();
  ASSERT_TRUE(third.ok());
  EXPECT_EQ(third.ask("*OPC?"), "");  // refused: the table is full
  EXPECT_EQ(std::stoi(third.ask("SYST:ERR?")), error_code::kSettingsConflict);
  EXPECT_EQ(server_->counters().rejected_max_clients, 1u);
  a.close();
  EXPECT_TRUE(eventually([&] { return server_->clients() == 2; }));
  LineClient fourth = tcp();
  EXPECT_EQ(fourth.ask("*OPC?"), "1");
}

TEST_F(ServerTest, SystClientsCountsTheTableAsItIsNow) {
  ServerConfig c = config();
  c.max_clients = 2;
  c.overflow_slots = 2;
  start(c);
  fake_.set_polls_until_done(1 << 30);  // a motion that does not end by itself
  LineClient a = tcp();
  EXPECT_EQ(a.ask("SYST:CLI?"), "1");  // the asking client counts
  EXPECT_EQ(a.ask("SYSTEM:CLIENTS:COUNT?"), "1");
  EXPECT_EQ(a.ask("SYST:CLI:TABL?"),
            "connected=1 slots=1 max_clients=2 stop_only=0 overflow_slots=2 draining=0");
  {
    LineClient waiter = unix_client();
    ASSERT_TRUE(waiter.send("MOVE:ABS 2e-6\n*OPC?\n"));
    ASSERT_TRUE(eventually([&] { return fake_.motion_calls() == 1; }));
    shutdown(waiter.fd(), SHUT_WR);  // half-closed, owed its *OPC? reply: draining, no slot
    EXPECT_TRUE(eventually(
        [&] { return a.ask("SYST:CLI:TABL?").find(" draining=1") != std::string::npos; }));
    LineClient b = tcp();
    EXPECT_EQ(b.ask("*IDN?"), "idm,idmd,0,test");
    LineClient extra = tcp();  // the table is full (a, b): a stop-only slot
    EXPECT_EQ(extra.ask("*IDN?"), "idm,idmd,0,test");
    EXPECT_EQ(a.ask("SYST:CLI:TABL?"),
              "connected=4 slots=2 max_clients=2 stop_only=1 overflow_slots=2 draining=1");
    EXPECT_EQ(a.ask("SYST:CLI?"), "4");
    EXPECT_EQ(extra.ask("SYST:CLI?"), "");  // a stop-only client may not ask
    ASSERT_TRUE(b.send("STOP\n"));
    EXPECT_EQ(waiter.line(), "1");
  }  // waiter, b and extra close
  EXPECT_TRUE(eventually([&] { return a.ask("SYST:CLI?") == "1"; }));
  EXPECT_EQ(server_->clients(), 1);
}

TEST_F(ServerTest, StopClosesClientsAndRemovesTheSocketFile) {
  start();
  LineClient t = tcp();
  EXPECT_EQ(t.ask("*OPC?"), "1");
  const std::string path = server_->unix_path();
  ASSERT_TRUE(std::filesystem::exists(path));
  server_->stop();
  EXPECT_TRUE(t.wait_closed());
  EXPECT_FALSE(std::filesystem::exists(path));
  EXPECT_FALSE(LineClient::tcp(server_->tcp_port()).ok());
  server_->stop();  // idempotent
}

TEST_F(ServerTest, AStaleSocketFileIsReplaced) {
  const std::string path = config().unix_path;
  {  // a socket file left behind by a process that died
    const int fd = socket(AF_UNIX, SOCK_STREAM, 0);
    sockaddr_un a{};
    a.sun_family = AF_UNIX;
    std::strncpy(a.sun_path, path.c_str(), sizeof a.sun_path - 1);
    ASSERT_EQ(bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a), 0);
    close(fd);
  }
  ASSERT_TRUE(std::filesystem::exists(path));
  start();
  EXPECT_EQ(unix_client().ask("*OPC?"), "1");
}

TEST_F(ServerTest, StartSaysWhatFailed) {
  start();
  {  // the TCP port is taken
    ServerConfig c = config();
    c.unix_path = dir_ + "/other.sock";
    c.tcp_port = server_->tcp_port();
    Server second(fake_, c);
    const std::string error = second.start();
    EXPECT_NE(error.find("TCP 127.0.0.1:" + std::to_string(server_->tcp_port())), std::string::npos)
        << error;
    EXPECT_NE(error.find("Address already in use"), std::string::npos) << error;
    EXPECT_FALSE(std::filesystem::exists(c.unix_path));
  }
  {  // the Unix socket is live
    ServerConfig c = config();
    Server second(fake_, c);
    const std::string error = second.start();
    EXPECT_NE(error.find(c.unix_path), std::string::npos) << error;
    EXPECT_NE(error.find("another server is listening"), std::string::npos) << error;
  }
  EXPECT_EQ(unix_client().ask("*OPC?"), "1");  // and the first server's socket is untouched
  {                                            // the path is a regular file
    ServerConfig c = config();
    c.unix_path = dir_ + "/plain-file";
    std::ofstream(c.unix_path) << "keep me\n";
    Server second(fake_, c);
    const std::string error = second.start();
    EXPECT_NE(error.find("is not a socket"), std::string::npos) << error;
    EXPECT_TRUE(std::filesystem::exists(c.unix_path));
  }
  {  // too long for sun_path; no directory
    ServerConfig c = config();
    c.unix_path = dir_ + "/" + std::string(120, 'x');
    EXPECT_NE(Server(fake_, c).start().find("path longer than"), std::string::npos);
    c.unix_path = dir_ + "/no/such/dir.sock";
    EXPECT_NE(Server(fake_, c).start().find("No such file or directory"), std::string::npos);
  }
  {  // nothing to listen on, a bad port
    ServerConfig c;
    c.tcp_host.clear();
    EXPECT_NE(Server(fake_, c).start().find("neither"), std::string::npos);
    c = config();
    c.tcp_port = 70000;
    EXPECT_NE(Server(fake_, c).start().find("out of range"), std::string::npos);
  }
}

TEST_F(ServerTest, LogsConnectionsAndWhyClientsWereDropped) {
  ServerConfig c = config();
  auto lines = std::make_shared<std::vector<std::string>>();
  auto mutex = std::make_shared<std::mutex>();
  c.log = [lines, mutex](std::string_view l) {
    std::lock_guard lock(*mutex);
    lines->emplace_back(l);
  };
  start(c);
  {
    LineClient t = tcp();
    EXPECT_EQ(t.ask("*OPC?"), "1");
  }
  EXPECT_TRUE(eventually([&] {
    std::lock_guard lock(*mutex);
    return lines->size() >= 2;
  }));
  std::lock_guard lock(*mutex);
  EXPECT_NE((*lines)[0].find("client connected (tcp 127.0.0.1:"), std::string::npos) << (*lines)[0];
  EXPECT_NE((*lines)[1].find("disconnected"), std::string::npos) << (*lines)[1];
}
