// idmctl end to end: the built binary against a Server on the fake Instrument, over TCP and the
// Unix socket. Output, exit status, waiting for moves, errors shown.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>

#include "daemon/server.h"
#include "tests/daemon/fake_instrument.h"
#include "tests/daemon/socket_client.h"

using namespace idm::daemon;
using idm::daemon::testing::FakeInstrument;
using idm::daemon::testing::LineClient;

namespace {

struct Result {
  int status;
  std::string out;  // stdout and stderr
};

Result run_shell(const std::string& command) {
  FILE* p = popen((command + " 2>&1").c_str(), "r");
  std::string out;
  char buf[4096];
  while (p && fgets(buf, sizeof buf, p)) out += buf;
  const int raw = p ? pclose(p) : -1;
  return {WIFEXITED(raw) ? WEXITSTATUS(raw) : -1, out};
}

const std::string kIdmctl = std::string(IDM_BUILD_DIR) + "/tools/idmctl";

class IdmctlTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = idm::daemon::testing::make_temp_dir();
    ServerConfig c;
    c.tcp_port = 0;
    c.unix_path = dir_ + "/idmd.sock";
    server_ = std::make_unique<Server>(fake_, c);
    ASSERT_EQ(server_->start(), "");
  }
  void TearDown() override {
    server_->stop();
    std::filesystem::remove_all(dir_);
  }
  Result idmctl(const std::string& args) {
    return run_shell(kIdmctl + " --port " + std::to_string(server_->tcp_port()) + " " + args);
  }

  FakeInstrument fake_;
  std::unique_ptr<Server> server_;
  std::string dir_;
};

}  // namespace

TEST_F(IdmctlTest, QueriesPrintTheirReply) {
  Result r = idmctl("pos");
  EXPECT_EQ(r.status, 0) << r.out;
  EXPECT_EQ(r.out, "0\n");
  r = idmctl("region 200 0.1");
  EXPECT_EQ(r.status, 0) << r.out;
  EXPECT_EQ(r.out, "ONESTEP,-2e-07\n");
  EXPECT_EQ(fake_.last_call(), "region(200,0.1,9.91e+37)");
  r = idmctl("status");
  EXPECT_EQ(r.status, 0) << r.out;
  EXPECT_EQ(r.out.rfind("state=IDLE done=1 position=0 ", 0), 0u) << r.out;
  r = idmctl("limits");
  EXPECT_EQ(r.out, "-0.001,0.001\n");
  r = idmctl("loop");
  EXPECT_EQ(r.out.rfind("period=0.001 wakeups=1000 misses=2 ", 0), 0u) << r.out;
  r = run_shell(kIdmctl + " --unix " + server_->unix_path() + " idn");
  EXPECT_EQ(r.status, 0) << r.out;
  EXPECT_EQ(r.out, "idm,idmd,0,test\n");
}

TEST_F(IdmctlTest, MovesWaitUntilDoneThenPrintThePosition) {
  fake_.set_polls_until_done(20);
  Result r = idmctl("move 1e-6");
  EXPECT_EQ(r.status, 0) << r.out;
  EXPECT_EQ(r.out, "1e-06\n");
  EXPECT_TRUE(fake_.motion_done());
  r = idmctl("rel -2.5e-7");
  EXPECT_EQ(r.status, 0) << r.out;
  EXPECT_EQ(r.out, "7.5e-07\n");
  r = idmctl("moverel 2.5e-7");
  EXPECT_EQ(r.out, "1e-06\n");
  r = idmctl("step -100 0.9 250");
  EXPECT_EQ(r.status, 0) << r.out;
  EXPECT_EQ(r.out, "");
  EXPECT_EQ(fake_.last_call(), "step(-100,0.9,250,9.91e+37)");
  r = idmctl("limits -2e-3 2e-3");
  EXPECT_EQ(r.status, 0) << r.out;
  EXPECT_EQ(fake_.last_call(), "set_soft_limits(-0.002,0.002)");
}

TEST_F(IdmctlTest, ARefusedMoveShowsTheErrorAndExitsOne) {
  fake_.set_refusal({error_code::kDataOutOfRange, "target past the upper soft limit"});
  const Result r = idmctl("move 5e-3");
  EXPECT_EQ(r.status, 1);
  EXPECT_EQ(r.out, "idmctl: error -222,\"Data out of range; target past the upper soft limit\"\n");
}

TEST_F(IdmctlTest, AMoveThatEndsInAFaultShowsTheFault) {
  fake_.set_polls_until_done(5);
  fake_.set_fault_on_finish("stall");
  const Result r = idmctl("move 1e-6");
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.out.find("idmctl: error 102,\"Stall"), std::string::npos) << r.out;
}

TEST_F(IdmctlTest, NoWaitReturnsWhileTheMotionGoesOn) {
  fake_.set_polls_until_done(1 << 30);
  Result r = idmctl("--no-wait move 1e-6");
  EXPECT_EQ(r.status, 0) << r.out;
  EXPECT_EQ(r.out, "");
  EXPECT_FALSE(fake_.motion_done());
  r = idmctl("stop");
  EXPECT_EQ(r.status, 0) << r.out;
  EXPECT_EQ(fake_.last_call(), "stop");
  EXPECT_TRUE(fake_.motion_done());
}

TEST_F(IdmctlTest, WaitWaitsForAMotionStartedElsewhere) {
  fake_.set_polls_until_done(30);
  LineClient other = LineClient::tcp(server_->tcp_port());
  ASSERT_TRUE(other.send("MOVE:ABS 3e-6\n"));
  EXPECT_EQ(other.ask("*IDN?"), "idm,idmd,0,test");  // the move has been taken
  const Result r = idmctl("wait");
  EXPECT_EQ(r.status, 0) << r.out;
  EXPECT_EQ(idmctl("pos").out, "3e-06\n");
}

TEST_F(IdmctlTest, RawSendsOneLineAndShowsErrors) {
  Result r = idmctl("raw '*IDN?'");
  EXPECT_EQ(r.status, 0) << r.out;
  EXPECT_EQ(r.out, "idm,idmd,0,test\n");
  r = idmctl("raw MOVE:ABS 2e-6");
  EXPECT_EQ(r.status, 0) << r.out;
  EXPECT_EQ(fake_.last_call(), "move_absolute(2e-06)");
  r = idmctl("raw BOGUS");
  EXPECT_EQ(r.status, 1);
  EXPECT_EQ(r.out, "idmctl: error -113,\"Undefined header; 'BOGUS'\"\n");
  r = idmctl("raw 'MOVE:ABS inf'");
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.out.find("-120"), std::string::npos) << r.out;
  EXPECT_EQ(fake_.motion_calls(), 1u);
}

TEST_F(IdmctlTest, InteractivePrintsTheReplyOfEveryQuery) {
  fake_.set_polls_until_done(10);
  const Result r =
      run_shell("printf 'POS?\\nMOVE:ABS 2e-6\\n*OPC?\\npos?\\nBOGUS\\n\\nSYST:ERR?\\n' | " +
                kIdmctl + " --unix " + server_->unix_path());
  EXPECT_EQ(r.status, 0) << r.out;
  EXPECT_EQ(r.out, "0\n1\n2e-06\n-113,\"Undefined header; 'BOGUS'\"\n");
}

TEST_F(IdmctlTest, BadUsageExitsTwoAndConnectionErrorsNameTheAddress) {
  Result r = idmctl("fly 1");
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.out.find("unknown command 'fly'"), std::string::npos) << r.out;
  r = idmctl("move");
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.out.find("usage: idmctl move X"), std::string::npos) << r.out;
  r = idmctl("step 10 0.1");
  EXPECT_EQ(r.status, 2);
  r = run_shell(kIdmctl + " --port 99999 pos");
  EXPECT_EQ(r.status, 2);
  r = run_shell(kIdmctl + " --bogus 1 pos");
  EXPECT_EQ(r.status, 2);
  r = run_shell(kIdmctl + " --unix /x --port 5 pos");
  EXPECT_EQ(r.status, 2);

  const int port = server_->tcp_port();
  server_->stop();
  r = run_shell(kIdmctl + " --port " + std::to_string(port) + " pos");
  EXPECT_EQ(r.status, 1);
  EXPECT_EQ(r.out, "idmctl: cannot connect to 127.0.0.1:" + std::to_string(port) +
                       ": Connection refused\n");
  r = run_shell(kIdmctl + " --unix " + dir_ + "/idmd.sock pos");
  EXPECT_EQ(r.status, 1);
  EXPECT_EQ(r.out, "idmctl: cannot connect to unix socket " + dir_ +
                       "/idmd.sock: No such file or directory\n");
}
