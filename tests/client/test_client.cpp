// The client side of idmd's socket (client/): reply parsers, addresses, the error-queue
// discipline against a Server on the fake Instrument, and the Tango state mapping.
#include <gtest/gtest.h>
#include <stdlib.h>

#include <cmath>
#include <filesystem>
#include <memory>
#include <string>

#include "client/connection.h"
#include "client/replies.h"
#include "daemon/server.h"
#include "tango/axis_state.h"
#include "tests/daemon/fake_instrument.h"
#include "tests/daemon/socket_client.h"

using namespace idm::client;

namespace {

const char* kStatus =
    "state=IDLE done=1 position=1.5e-06 position_valid=1 target=1.5e-06 fault=none lower=-0.005 "
    "upper=0.005 moves=3 bursts=12 cycles=340 errors=0 last_error=0 daemon_error=none axis=x "
    "referenced=1 device=up";

TEST(Replies, StatusHasEveryField) {
  const AxisStatus s = parse_status(kStatus);
  EXPECT_EQ(s.name, "x");
  EXPECT_EQ(s.state, "IDLE");
  EXPECT_TRUE(s.done);
  EXPECT_TRUE(s.position_valid);
  EXPECT_DOUBLE_EQ(s.position_m, 1.5e-6);
  EXPECT_DOUBLE_EQ(s.lower_m, -0.005);
  EXPECT_EQ(s.moves, 3u);
  EXPECT_EQ(s.cycles, 340u);
  EXPECT_TRUE(s.referenced);
  EXPECT_EQ(s.device, "up");
  EXPECT_EQ(s.eot, "");
  // The daemon says eot=none away from the ends: no end of travel.
  EXPECT_EQ(parse_status(std::string(kStatus) + " eot=none").eot, "");
  // The user offset: 0 from a daemon that does not report one.
  EXPECT_EQ(s.offset_m, 0.0);
  EXPECT_DOUBLE_EQ(parse_status(std::string(kStatus) + " offset=-0.00125").offset_m, -1.25e-3);
  EXPECT_THROW(parse_status(std::string(kStatus) + " offset=far"), ReplyError);
}

TEST(Replies, AnUntrustedPositionIsNaNAndUnsetLimitsAreInfinite) {
  const AxisStatus s = parse_status(
      "state=FAULT done=1 position=9.91E37 position_valid=0 target=0 fault=invalid_sample "
      "lower=-9.9e+37 upper=9.9e+37 moves=0 bursts=0 cycles=0 errors=0 last_error=0 "
      "daemon_error=none axis=y referenced=0 device=lost eot=low");
  EXPECT_FALSE(s.position_valid);
  EXPECT_TRUE(std::isnan(s.position_m));
  EXPECT_EQ(s.lower_m, -INFINITY);
  EXPECT_EQ(s.upper_m, INFINITY);
  EXPECT_EQ(s.eot, "low");
  EXPECT_TRUE(std::isnan(parse_reply_number("9.91E37")));
}

TEST(Replies, MalformedStatusIsAReplyError) {
  EXPECT_THROW(parse_status(""), ReplyError);
  EXPECT_THROW(parse_status("state=IDLE"), ReplyError);  // fields missing
  std::string twice = std::string(kStatus) + " axis=y";
  EXPECT_THROW(parse_status(twice), ReplyError);
  std::string bad_flag = kStatus;
  bad_flag.replace(bad_flag.find("done=1"), 6, "done=2");
  EXPECT_THROW(parse_status(bad_flag), ReplyError);
  std::string valid_nan = kStatus;
  valid_nan.replace(valid_nan.find("position=1.5e-06"), 16, "position=9.91E37");
  EXPECT_THROW(parse_status(valid_nan), ReplyError);
  std::string bad_count = kStatus;
  bad_count.replace(bad_count.find("moves=3"), 7, "moves=-3");
  EXPECT_THROW(parse_status(bad_count), ReplyError);
}

TEST(Replies, ErrorsWithQuotes) {
  const ErrorReply e = parse_error("-113,\"Undefined header; \"\"X\"\"\"");
  EXPECT_EQ(e.code, -113);
  EXPECT_EQ(e.text, "Undefined header; \"X\"");
  EXPECT_EQ(parse_error("0,\"No error\"").code, 0);
  EXPECT_EQ(parse_error("102,\"Stall\"").code, 102);
  // "00,..." and "-0,..." would read as code 0, "no error".
  for (const char* bad : {"", "0", ",\"x\"", "-,\"x\"", "1,x", "1,\"a\"b\"", "12345678,\"x\"",
                          "00,\"o#r\"", "-0,\"x\"", "-0113,\"x\""})
    EXPECT_THROW(parse_error(bad), ReplyError) << bad;
}

TEST(Replies, LoopSweepRegionAndLists) {
  const LoopStats l = parse_loop(
      "period=0.0001 wakeups=10 misses=1 min=1e-06 avg=2e-06 max=3e-05 bin_width=5e-06 "
      "hist=1;2;3;4");
  EXPECT_EQ(l.wakeups, 10u);
  EXPECT_EQ(l.hist.size(), 4u);
  EXPECT_EQ(l.hist[3], 4u);
  EXPECT_THROW(parse_loop("period=1 wakeups=1 misses=0 min=0 avg=0 max=0 bin_width=0 hist=1"),
               ReplyError);
  const SweepInfo s = parse_sweep("RUNNING,1,12,1,80,\"runs/a,\"\"b\"\"\"");
  EXPECT_EQ(s.state, "RUNNING");
  EXPECT_EQ(s.axis, 1);
  EXPECT_EQ(s.written, 12u);
  EXPECT_EQ(s.planned, 80u);
  EXPECT_EQ(s.directory, "runs/a,\"b\"");
  EXPECT_EQ(parse_sweep("NONE,-1,0,0,0,\"\"").axis, -1);
  EXPECT_THROW(parse_sweep("NONE,0,0,0,\"\""), ReplyError);
  const RegionReply r = parse_region("ONESTEP,-5.4e-06");
  EXPECT_EQ(r.region, "ONESTEP");
  EXPECT_DOUBLE_EQ(r.step_m, -5.4e-6);
  EXPECT_THROW(parse_region("SOMESTEP,1"), ReplyError);
  const auto v = parse_number_list("1e-6,-2e-6,9.91E37");
  ASSERT_EQ(v.size(), 3u);
  EXPECT_TRUE(std::isnan(v[2]));
  EXPECT_THROW(parse_number_list("1,,2"), ReplyError);
  EXPECT_EQ(operation_bit_words(0x103),
            (std::vector<std::string>{"moving", "in position", "position valid"}));
}

TEST(Replies, ClientTable) {
  const ClientTable t = parse_client_table(
      "connected=5 slots=3 max_clients=16 stop_only=1 overflow_slots=4 draining=1");
  EXPECT_EQ(t.connected, 5u);
  EXPECT_EQ(t.slots, 3u);
  EXPECT_EQ(t.max_clients, 16u);
  EXPECT_EQ(t.stop_only, 1u);
  EXPECT_EQ(t.overflow_slots, 4u);
  EXPECT_EQ(t.draining, 1u);
  // Parts that do not add up, a missing field, a negative count.
  EXPECT_THROW(parse_client_table(
                   "connected=5 slots=3 max_clients=16 stop_only=0 overflow_slots=4 draining=1"),
               ReplyError);
  EXPECT_THROW(
      parse_client_table("connected=1 slots=1 max_clients=16 stop_only=0 overflow_slots=4"),
      ReplyError);
  EXPECT_THROW(parse_client_table(
                   "connected=1 slots=-1 max_clients=16 stop_only=2 overflow_slots=4 draining=0"),
               ReplyError);
}

TEST(Address, HostPortForms) {
  EXPECT_EQ(parse_host_port("10.0.0.2:5026").text(), "10.0.0.2:5026");
  EXPECT_EQ(parse_host_port("lab-pc").port, 5025);
  EXPECT_EQ(parse_host_port("[::1]:7").host, "::1");
  EXPECT_EQ(parse_host_port("[::1]:7").text(), "[::1]:7");
  EXPECT_EQ(parse_host_port("127.0.0.1:0", 8080, true).port, 0);
  for (const char* bad : {"", ":5025", "h:", "h:0", "h:65536", "h:5x", "::1:5025", "[::1", "[::1]x",
                          "h h:1", "h/x:1", "h:123456"})
    EXPECT_THROW(parse_host_port(bad), AddressError) << bad;
}

TEST(Address, FromTheEnvironment) {
  unsetenv("IDMD_SOCKET");
  unsetenv("IDMD_ADDRESS");
  EXPECT_EQ(address_from_environment().text(), "127.0.0.1:5025");
  setenv("IDMD_ADDRESS", "192.168.1.5:6000", 1);
  EXPECT_EQ(address_from_environment().text(), "192.168.1.5:6000");
  setenv("IDMD_SOCKET", "/run/idmd/idmd.sock", 1);
  EXPECT_THROW(address_from_environment(), AddressError);
  unsetenv("IDMD_ADDRESS");
  EXPECT_EQ(address_from_environment().unix_path, "/run/idmd/idmd.sock");
  unsetenv("IDMD_SOCKET");
  setenv("IDMD_ADDRESS", "nonsense:port", 1);
  EXPECT_THROW(address_from_environment(), AddressError);
  unsetenv("IDMD_ADDRESS");
}

class ClientOnFake : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = idm::daemon::testing::make_temp_dir();
    idm::daemon::ServerConfig c;
    c.tcp_port = 0;
    c.unix_path = dir_ + "/idmd.sock";
    server_ = std::make_unique<idm::daemon::Server>(fake_, c);
    ASSERT_EQ(server_->start(), "");
  }
  void TearDown() override {
    server_->stop();
    std::filesystem::remove_all(dir_);
  }
  idm::daemon::testing::FakeInstrument fake_;
  std::unique_ptr<idm::daemon::Server> server_;
  std::string dir_;
};

TEST_F(ClientOnFake, QueriesCommandsAndErrorsAsExceptions) {
  Address a;
  a.port = server_->tcp_port();
  Client c(a, 5);
  EXPECT_FALSE(c.query("*IDN?").empty());
  c.command("*CLS");
  try {
    c.query("AXIS9:POS?");
    FAIL() << "no exception";
  } catch (const DaemonError& e) {
    EXPECT_EQ(e.code, -114);
  }
  try {
    c.command("NOSUCH:THING 1");
    FAIL() << "no exception";
  } catch (const DaemonError& e) {
    EXPECT_EQ(e.code, -113);
  }
  EXPECT_TRUE(c.drain_errors().empty());  // the queue was drained by the exceptions
  Address u;
  u.unix_path = dir_ + "/idmd.sock";
  Client cu(u, 5);
  EXPECT_EQ(cu.query("*IDN?"), c.query("*IDN?"));
}

TEST_F(ClientOnFake, NoDaemonIsARuntimeError) {
  Address a;
  a.unix_path = dir_ + "/nothing.sock";
  EXPECT_THROW(Client(a, 1), std::runtime_error);
}

TEST(TangoState, MappingOfTheDaemonsStatus) {
  using idm::tango::axis_state;
  using idm::tango::AxisState;
  AxisStatus s = parse_status(kStatus);
  EXPECT_EQ(axis_state(s), AxisState::On);
  AxisStatus moving = s;
  moving.done = false;
  moving.state = "MOVING";
  EXPECT_EQ(axis_state(moving), AxisState::Moving);
  AxisStatus settling = s;
  settling.state = "SETTLING";
  EXPECT_EQ(axis_state(settling), AxisState::Moving);
  AxisStatus fault = moving;
  fault.state = "FAULT";
  EXPECT_EQ(axis_state(fault), AxisState::Fault);
  AxisStatus lost = s;
  lost.position_valid = false;
  lost.position_m = NAN;
  EXPECT_EQ(axis_state(lost), AxisState::Disable);
  AxisStatus at_limit = s;
  at_limit.position_m = at_limit.upper_m;
  EXPECT_EQ(axis_state(at_limit), AxisState::Alarm);
  AxisStatus eot = s;
  eot.eot = "high";
  EXPECT_EQ(axis_state(eot), AxisState::Alarm);
  AxisStatus unlimited = s;
  unlimited.lower_m = -INFINITY;
  unlimited.upper_m = INFINITY;
  EXPECT_EQ(axis_state(unlimited), AxisState::On);
  EXPECT_NE(idm::tango::axis_status_text(fault, AxisState::Fault).find("FAULT"), std::string::npos);
}

}  // namespace
