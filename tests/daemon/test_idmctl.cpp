// idmctl end to end: the built binary against a Server on the fake Instrument, over TCP and the
// Unix socket. Output, exit status, waiting for moves, errors shown.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <random>
#include <sstream>
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

// An environment variable set for the life of one test (so an idmctl started by popen sees it).
class ScopedEnv {
 public:
  ScopedEnv(const char* name, const std::string& value) : name_(name) {
    if (const char* old = std::getenv(name)) old_ = old, had_ = true;
    setenv(name, value.c_str(), 1);
  }
  ~ScopedEnv() {
    if (had_)
      setenv(name_, old_.c_str(), 1);
    else
      unsetenv(name_);
  }
  ScopedEnv(const ScopedEnv&) = delete;
  ScopedEnv& operator=(const ScopedEnv&) = delete;

 private:
  const char* name_;
  std::string old_;
  bool had_ = false;
};

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
  // A shell command whose stdout and stderr are kept apart: {status, stdout}, and stderr in err.
  Result run_apart(const std::string& command, std::string& err) {
    const std::string err_file = dir_ + "/stderr";
    FILE* p = popen((command + " 2>" + err_file).c_str(), "r");
    std::string out;
    char buf[4096];
    while (p && fgets(buf, sizeof buf, p)) out += buf;
    const int raw = p ? pclose(p) : -1;
    std::ifstream in(err_file);
    std::stringstream text;
    text << in.rdbuf();
    err = text.str();
    return {WIFEXITED(raw) ? WEXITSTATUS(raw) : -1, out};
  }
  // idmctl (over the Unix socket) reading `lines` from stdin.
  Result piped(const std::string& lines, std::string& err, const std::string& flags = "") {
    std::ofstream(dir_ + "/stdin") << lines;
    return run_apart(
        kIdmctl + " --unix " + server_->unix_path() + " " + flags + " < " + dir_ + "/stdin", err);
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

TEST_F(IdmctlTest, PipedLinesPrintTheReplyOfEveryQueryAndEveryErrorWithItsLine) {
  fake_.set_polls_until_done(10);
  std::string err;
  const Result r = piped("POS?\nMOVE:ABS 2e-6\n*OPC?\npos?\nBOGUS\n\nSYST:ERR?\n", err);
  EXPECT_EQ(r.status, 1) << err;
  // The error was read right after its line: the script's own SYST:ERR? finds the queue empty.
  EXPECT_EQ(r.out, "0\n1\n2e-06\n0,\"No error\"\n");
  EXPECT_EQ(err,
            "idmctl: line 5 (BOGUS): error -113,\"Undefined header; 'BOGUS'\"\n"
            "idmctl: 1 of 6 lines failed\n");
}

TEST_F(IdmctlTest, PipedLinesThatFailAreEachNamedAndTheStatusIsOne) {
  fake_.set_refusal({error_code::kDataOutOfRange, "target 99 m outside the soft limits"});
  std::string err;
  Result r = piped("FOO 1\nMOVE:ABS 99\nPOS?\n", err);
  EXPECT_EQ(r.status, 1);
  EXPECT_EQ(r.out, "0\n");
  EXPECT_EQ(err,
            "idmctl: line 1 (FOO 1): error -113,\"Undefined header; 'FOO'\"\n"
            "idmctl: line 2 (MOVE:ABS 99): error -222,\"Data out of range; target 99 m outside "
            "the soft limits\"\n"
            "idmctl: 2 of 3 lines failed\n");
  fake_.set_refusal({});
  r = piped("MOVE:ABS 1e-6\n*OPC?\n", err);
  EXPECT_EQ(r.status, 0) << err;
  EXPECT_EQ(err, "");
}

TEST_F(IdmctlTest, IdmctlsVerbsOnPipedLinesRunAsOnTheCommandLine) {
  fake_.set_polls_until_done(3);
  std::string err;
  Result r = piped(
      "move 1um\nrel -250nm\n  step -100 0.9 250\nstep 7,0.2,300,2um\nlimits -2mm 2mm\n"
      "limits\npos\nraw MOVE:REL 1e-7\n*OPC?\n",
      err);
  EXPECT_EQ(r.status, 0) << err;
  EXPECT_EQ(err, "");
  EXPECT_EQ(r.out, "1e-06\n7.5e-07\n-0.002,0.002\n7.5e-07\n1\n");
  const std::vector<std::string> want = {"move_absolute(1e-06)",          "move_relative(-2.5e-07)",
                                         "step(-100,0.9,250,9.91e+37)",   "step(7,0.2,300,2e-06)",
                                         "set_soft_limits(-0.002,0.002)", "move_relative(1e-07)"};
  std::vector<std::string> got;
  for (const std::string& c : fake_.calls())
    if (c.rfind("move", 0) == 0 || c.rfind("step", 0) == 0 || c.rfind("set_soft", 0) == 0)
      got.push_back(c);
  EXPECT_EQ(got, want);
  // A verb used wrongly is refused, naming its line, and the next lines still run.
  r = piped("move\nmove 5km\npos\n", err);
  EXPECT_EQ(r.status, 1);
  EXPECT_EQ(r.out, "8.5e-07\n");
  EXPECT_EQ(err,
            "idmctl: line 1 (move): move: usage: idmctl move X\n"
            "idmctl: line 2 (move 5km): move X: '5km': unknown unit 'km', accepted nm, um, mm, m "
            "(case matters; a bare number is metres)\n"
            "idmctl: 2 of 3 lines failed\n");
}

TEST_F(IdmctlTest, APositionThatIsNotValidIsAnErrorNeverANumber) {
  fake_.set_position(1e-6, false);
  std::string err;
  Result r = run_apart(kIdmctl + " --unix " + server_->unix_path() + " pos", err);
  EXPECT_EQ(r.status, 1);
  EXPECT_EQ(r.out, "");
  EXPECT_NE(err.find("idmctl: error -230,"), std::string::npos) << err;
  r = piped("pos\n", err, "--unit nm");
  EXPECT_EQ(r.status, 1);
  EXPECT_EQ(r.out, "");
  EXPECT_NE(err.find("idmctl: line 1 (pos): error -230,"), std::string::npos) << err;
  // The protocol line itself is idmd's: its reply is printed as it came, the error named.
  r = piped("POS?\n", err);
  EXPECT_EQ(r.out, "9.91E37\n");
  EXPECT_NE(err.find("idmctl: line 1 (POS?): error -230,"), std::string::npos) << err;
  fake_.set_position(1e-6, true);
  r = run_apart(kIdmctl + " --unix " + server_->unix_path() + " pos", err);
  EXPECT_EQ(r.status, 0) << err;
  EXPECT_EQ(r.out, "1e-06\n");
}

TEST_F(IdmctlTest, TheEnvironmentNamesTheDaemonUnlessAFlagDoes) {
  const std::string tcp = "127.0.0.1:" + std::to_string(server_->tcp_port());
  {
    ScopedEnv socket("IDMD_SOCKET", server_->unix_path());
    Result r = run_shell(kIdmctl + " idn");
    EXPECT_EQ(r.status, 0) << r.out;
    EXPECT_EQ(r.out, "idm,idmd,0,test\n");
    // A flag wins over the environment (which is then not read at all).
    r = run_shell(kIdmctl + " --port " + std::to_string(server_->tcp_port()) + " idn");
    EXPECT_EQ(r.status, 0) << r.out;
    ScopedEnv address("IDMD_ADDRESS", tcp);
    r = run_shell(kIdmctl + " idn");
    EXPECT_EQ(r.status, 2);
    EXPECT_EQ(r.out, "idmctl: IDMD_SOCKET and IDMD_ADDRESS are both set: set one\n");
    r = run_shell(kIdmctl + " --unix " + server_->unix_path() + " idn");
    EXPECT_EQ(r.status, 0) << r.out;
  }
  {
    ScopedEnv address("IDMD_ADDRESS", tcp);
    Result r = run_shell(kIdmctl + " idn");
    EXPECT_EQ(r.status, 0) << r.out;
    ScopedEnv bad("IDMD_ADDRESS", "127.0.0.1:http");
    r = run_shell(kIdmctl + " idn");
    EXPECT_EQ(r.status, 2);
    EXPECT_EQ(r.out,
              "idmctl: IDMD_ADDRESS: '127.0.0.1:http': the port is not a number in 1..65535\n");
  }
  {
    ScopedEnv nowhere("IDMD_SOCKET", dir_ + "/nowhere.sock");
    const Result r = run_shell(kIdmctl + " pos");
    EXPECT_EQ(r.status, 1);
    EXPECT_EQ(r.out, "idmctl: cannot connect to unix socket " + dir_ +
                         "/nowhere.sock: No such file or directory\n");
  }
}

TEST_F(IdmctlTest, LengthsTakeUnitsAndArePrintedInTheUnitAsked) {
  fake_.set_position(1e-6);
  EXPECT_EQ(idmctl("--unit nm pos").out, "1000\n");
  EXPECT_EQ(idmctl("--unit um pos").out, "1\n");
  EXPECT_EQ(idmctl("--unit mm pos").out, "0.001\n");
  EXPECT_EQ(idmctl("--unit m pos").out, "1e-6\n");
  EXPECT_EQ(idmctl("--unit um limits").out, "-1000,1000\n");
  EXPECT_EQ(idmctl("--unit nm region 200 0.1 5um").out, "ONESTEP,-200\n");
  EXPECT_EQ(fake_.last_call(), "region(200,0.1,5e-06)");
  Result r = idmctl("--unit nm move 1.5um");
  EXPECT_EQ(r.status, 0) << r.out;
  EXPECT_EQ(r.out, "1500\n");
  EXPECT_EQ(idmctl("rel 2e-7m").out, "1.7e-06\n");
  EXPECT_EQ(idmctl("--unit mm limits -1.5mm 2000um").status, 0);
  EXPECT_EQ(fake_.last_call(), "set_soft_limits(-0.0015,0.002)");
  // A bare number is metres; with --unit nm, um or mm it is ambiguous and refused.
  r = idmctl("--unit um move 5");
  EXPECT_EQ(r.status, 2);
  EXPECT_EQ(r.out,
            "idmctl: move X: '5' has no unit: write 5um, 5m, ... (a bare number is metres only "
            "without --unit or with --unit m)\n");
  for (const char* bad : {"5km", "5MM", "5Um", "1e", "5 um", "um", "0x10m", "1..2mm", "infm"}) {
    r = idmctl(std::string("move '") + bad + "'");
    EXPECT_EQ(r.status, 2) << bad;
    EXPECT_EQ(r.out.rfind(std::string("idmctl: move X: '") + bad + "'", 0), 0u) << r.out;
    EXPECT_NE(r.out.find("nm, um, mm, m"), std::string::npos) << r.out;
  }
  r = idmctl("--unit km pos");
  EXPECT_EQ(r.status, 2);
  EXPECT_EQ(r.out, "idmctl: --unit: 'km' is not a unit, allowed nm, um, mm, m\n");
  EXPECT_EQ(fake_.motion_calls(), 2u);  // nothing refused ever moved
}

TEST_F(IdmctlTest, StepSendsTheSignOfNAsGivenAndTheHelpSaysWhatItMeans) {
  std::mt19937 random(7);
  std::uniform_int_distribution<long> cycles(-1000000, 1000000);
  for (int k = 0; k < 12; ++k) {
    long n = cycles(random);
    if (n == 0) n = 1;
    const Result r = idmctl("--no-wait step " + std::to_string(n) + " 0.3 250");
    EXPECT_EQ(r.status, 0) << r.out;
    EXPECT_EQ(fake_.last_call(), "step(" + std::to_string(n) + ",0.3,250,9.91e+37)");
  }
  const Result help = run_shell(kIdmctl + " --help");
  EXPECT_EQ(help.status, 0);
  EXPECT_NE(help.out.find("the sign of N alone picks the\n"), std::string::npos) << help.out;
  EXPECT_NE(help.out.find("as for the positive direction (mirrored for negative N)"),
            std::string::npos)
      << help.out;
}

TEST_F(IdmctlTest, JogMovesTowardTheSoftLimitThatWayAndWaits) {
  // idmd's JOG is a move to the soft limit that way less the window: the fake's limits are
  // +-1 mm; the window is the fake's setting, given here.
  ASSERT_EQ(idmctl("raw MOVE:WIND 2e-6").status, 0);
  fake_.set_polls_until_done(5);
  const std::pair<const char*, const char*> kDirections[] = {
      {"+", "move_absolute(0.000998)"},        {"-", "move_absolute(-0.000998)"},
      {"positive", "move_absolute(0.000998)"}, {"negative", "move_absolute(-0.000998)"},
      {"POS", "move_absolute(0.000998)"},      {"Neg", "move_absolute(-0.000998)"}};
  for (const auto& [word, call] : kDirections) {
    const Result r = idmctl(std::string("jog ") + word);
    EXPECT_EQ(r.status, 0) << word << ": " << r.out;
    EXPECT_EQ(fake_.last_call().rfind(call, 0), 0u) << word << ": " << fake_.last_call();
    EXPECT_TRUE(fake_.motion_done()) << word;
    // It waited for the motion's end, then printed the position there (in --unit when given).
    EXPECT_EQ(r.out,
              word[0] == '+' || word[0] == 'p' || word[0] == 'P' ? "0.000998\n" : "-0.000998\n")
        << word;
  }
  EXPECT_EQ(idmctl("--unit um jog +").out, "998\n");
  // --no-wait: back at once, the jog goes on until a STOP.
  fake_.set_polls_until_done(1 << 30);
  Result r = idmctl("--no-wait jog -");
  EXPECT_EQ(r.status, 0) << r.out;
  EXPECT_EQ(r.out, "");
  EXPECT_FALSE(fake_.motion_done());
  EXPECT_EQ(idmctl("stop").status, 0);
  EXPECT_TRUE(fake_.motion_done());
  // A direction that is none is bad usage, and nothing is sent.
  const std::size_t motions = fake_.motion_calls();
  for (const char* bad : {"up", "1", "++", "'positive '", "''"}) {
    r = idmctl(std::string("jog ") + bad);
    EXPECT_EQ(r.status, 2) << bad;
    EXPECT_NE(r.out.find("is not a direction, allowed +, -, positive, negative"), std::string::npos)
        << r.out;
  }
  r = idmctl("jog");
  EXPECT_EQ(r.status, 2);
  EXPECT_EQ(r.out, "idmctl: jog: usage: idmctl jog +|-|positive|negative\n");
  EXPECT_EQ(fake_.motion_calls(), motions);
}

TEST_F(IdmctlTest, SetposAndOffsetSetTheUserFrameInUnits) {
  // setpos: the current position becomes X (POSition:SET), then the position is printed.
  Result r = idmctl("--unit um setpos 250um");
  EXPECT_EQ(r.status, 0) << r.out;
  EXPECT_EQ(fake_.last_call(), "set_position(0.00025)");
  EXPECT_EQ(r.out, "250\n");
  EXPECT_EQ(idmctl("--unit um offset").out, "250\n");  // the fake's position was 0
  r = idmctl("offset -1.5mm");
  EXPECT_EQ(r.status, 0) << r.out;
  EXPECT_EQ(r.out, "");
  EXPECT_EQ(fake_.last_call(), "set_user_offset(-0.0015)");
  EXPECT_EQ(idmctl("offset").out, "-0.0015\n");
  EXPECT_EQ(idmctl("--unit mm offset").out, "-1.5\n");
  r = idmctl("show");
  EXPECT_NE(r.out.find("user offset: -0.0015 m"), std::string::npos) << r.out;
  // Lengths take their units as every verb's do; usage errors send nothing.
  const std::size_t calls = fake_.calls().size();
  for (const char* bad :
       {"setpos", "setpos 1 2", "--unit um setpos 5", "offset 3 furlongs", "setpos 1um/s"}) {
    r = idmctl(bad);
    EXPECT_EQ(r.status, 2) << bad << ": " << r.out;
  }
  EXPECT_EQ(fake_.calls().size(), calls);
}

TEST_F(IdmctlTest, VelocityIsTheSpeedLimitInUnitsPerSecond) {
  const std::string kSet =
      "set_motion_setting(" + std::to_string(static_cast<int>(MotionSetting::MaxSpeed)) + ",";
  Result r = idmctl("velocity 400um/s");
  EXPECT_EQ(r.status, 0) << r.out;
  EXPECT_EQ(r.out, "");
  EXPECT_EQ(fake_.last_call(), kSet + "0.0004)");
  EXPECT_EQ(idmctl("velocity").out, "0.0004\n");
  EXPECT_EQ(idmctl("--unit um velocity").out, "400\n");
  EXPECT_EQ(idmctl("--unit nm velocity").out, "400000\n");
  EXPECT_EQ(idmctl("--unit mm velocity").out, "0.4\n");
  const std::pair<const char*, const char*> kSpeeds[] = {{"--unit mm velocity 0.5mm/s", "0.0005)"},
                                                         {"velocity 2.5e-4", "0.00025)"},
                                                         {"--unit m velocity 1e-3", "0.001)"},
                                                         {"velocity 250nm/s", "2.5e-07)"},
                                                         {"velocity 0m/s", "0)"},
                                                         {"velocity 1e-3m/s", "0.001)"}};
  for (const auto& [args, value] : kSpeeds) {
    r = idmctl(args);
    EXPECT_EQ(r.status, 0) << args << ": " << r.out;
    EXPECT_EQ(fake_.last_call(), kSet + value) << args;
  }
  // A bare number is m/s, ambiguous with --unit nm, um or mm; a length is not a speed.
  r = idmctl("--unit um velocity 5");
  EXPECT_EQ(r.status, 2);
  EXPECT_EQ(r.out,
            "idmctl: velocity SPEED: '5' has no unit: write 5um/s, 5m/s, ... (a bare number is "
            "m/s only without --unit or with --unit m)\n");
  r = idmctl("velocity 400um");
  EXPECT_EQ(r.status, 2);
  EXPECT_EQ(
      r.out.rfind("idmctl: velocity SPEED: '400um' is a length, not a speed: write 400um/s", 0), 0u)
      << r.out;
  for (const char* bad : {"5km/s", "5Um/s", "um/s", "/s", "5/s", "1e/s", "5 um/s", "infm/s",
                          "5um/h", "5\xC2\xB5m/s"}) {
    r = idmctl(std::string("velocity '") + bad + "'");
    EXPECT_EQ(r.status, 2) << bad;
    EXPECT_EQ(r.out.rfind(std::string("idmctl: velocity SPEED: '") + bad + "'", 0), 0u) << r.out;
    EXPECT_NE(r.out.find("nm/s, um/s, mm/s, m/s"), std::string::npos) << r.out;
  }
  EXPECT_EQ(idmctl("velocity 1um/s 2um/s").status, 2);
  EXPECT_EQ(fake_.last_call(), kSet + "0.001)");  // nothing refused was sent
  // The verbs on stdin's lines, as on the command line.
  std::string err;
  r = piped("velocity 3um/s\nvelocity\njog -\n", err, "--unit um");
  EXPECT_EQ(r.status, 0) << err;
  EXPECT_EQ(r.out, "3\n-1000\n");
  EXPECT_EQ(fake_.last_call().rfind("move_absolute(-0.001)", 0), 0u) << fake_.last_call();
}

TEST_F(IdmctlTest, VersionIsTheProjectsVersion) {
  const Result r = run_shell(kIdmctl + " --version");
  EXPECT_EQ(r.status, 0);
  EXPECT_EQ(r.out, std::string("idmctl ") + IDM_PROJECT_VERSION + "\n");
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
