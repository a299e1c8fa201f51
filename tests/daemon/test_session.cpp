// A Session over a fake Instrument: every command in short and long form, line framing, every
// malformed line, and motion seen through the protocol.
#include <gtest/gtest.h>

#include <cctype>
#include <cstdio>
#include <ostream>
#include <random>
#include <string>
#include <vector>

#include "daemon/protocol.h"
#include "tests/daemon/fake_instrument.h"
#include "tests/daemon/session_harness.h"

using namespace idm::daemon;
using idm::daemon::testing::count_lines;
using idm::daemon::testing::FakeInstrument;
using idm::daemon::testing::Harness;
namespace ec = idm::daemon::error_code;

// ---------------------------------------------------------------------------------------------
// Session: every command, short and long forms

struct CommandCase {
  std::vector<std::string> forms;  // every form must give the same call and reply
  std::string call;                // the fake's record of the call ("" for none)
  std::string reply;               // "" for a command
};

// CTest names carry the parameter as printed: printable and stable.
std::string printable(const std::string& text) {
  std::string out;
  for (unsigned char c : text) {
    if (std::isalnum(c) ||
        std::string_view(":*?.,_+-/").find(static_cast<char>(c)) != std::string_view::npos) {
      out += static_cast<char>(c);
    } else {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\x%02X", c);
      out += buf;
    }
  }
  return out;
}
void PrintTo(const CommandCase& c, std::ostream* os) {
  *os << printable(c.forms.front());
}

class ProtocolCommands : public ::testing::TestWithParam<CommandCase> {};

TEST_P(ProtocolCommands, EveryFormMakesTheSameCallAndReply) {
  const CommandCase& c = GetParam();
  for (const std::string& form : c.forms) {
    Harness h;
    const std::string out = h.line(form);
    EXPECT_EQ(out, c.reply.empty() ? "" : c.reply + "\n") << form;
    EXPECT_EQ(h.fake.last_call(), c.call) << form;
    EXPECT_EQ(h.line("SYST:ERR?"), "0,\"No error\"\n") << form;
  }
}

INSTANTIATE_TEST_SUITE_P(
    AllCommands, ProtocolCommands,
    ::testing::Values(
        CommandCase{{"*IDN?", "*idn?"}, "", "idm,idmd,0,test"},
        CommandCase{{"*RST", "*rst"}, "reset", ""}, CommandCase{{"*CLS", "*cls"}, "", ""},
        CommandCase{{"*OPC?", "*opc?"}, "", "1"}, CommandCase{{"*WAI", "*wai"}, "", ""},
        CommandCase{{"*TST?", "*tst?"}, "", "0"},
        CommandCase{{"SYST:ERR:COUN?", "SYSTEM:ERROR:COUNT?", "syst:err:count?"}, "", "0"},
        CommandCase{{"SYST:ERR:ALL?", "system:error:all?"}, "", "0,\"No error\""},
        CommandCase{{"SYST:VERS?", "SYSTem:VERSion?"}, "", "1999.0"},
        CommandCase{
            {"SYST:LOOP?", "system:loop?"},
            "",
            "period=0.001 wakeups=1000 misses=2 min=1e-06 avg=5e-06 max=4e-05 bin_width=1e-05 "
            "hist=990;0;0;10;0;0;0;0;0;0;0;0;0;0;0;0;0;0;0;0;0;0;0;0;0;0;0;0;0;0;0;0"},
        CommandCase{{"POS?", "POSITION?", "position?", ":pos?"}, "", "0"},
        CommandCase{{"POS:SET 2.5e-3", "POSITION:SET 2.5e-3", "pos:set 0.0025"},
                    "set_position(0.0025)",
                    ""},
        CommandCase{{"POS:OFFS -1e-3", "POSITION:OFFSET -1e-3", "axis1:pos:offs -0.001"},
                    "set_user_offset(-0.001)",
                    ""},
        CommandCase{{"POS:OFFS?", "POSITION:OFFSET?"}, "", "0"},
        CommandCase{{"MOVE:ABS 1e-6", "MOVE:ABSOLUTE 1e-6", "move:absolute 0.000001", "MOVE 1e-6",
                     ":Move:Abs 1E-06"},
                    "move_absolute(1e-06)",
                    ""},
        CommandCase{{"MOVE:ABS?", "MOVE?", "move:absolute?"}, "", "0"},
        CommandCase{{"MOVE:REL -2e-7", "MOVE:RELATIVE -2e-7", "move:rel -0.0000002"},
                    "move_relative(-2e-07)",
                    ""},
        CommandCase{{"MOVE:DONE?", "move:done?"}, "", "1"},
        CommandCase{{"STOP", "stop", "ABOR", "ABORT", "abort"}, "stop", ""},
        CommandCase{{"STEP 100", "step 1e2"}, "step(100,9.91e+37,9.91e+37,9.91e+37)", ""},
        CommandCase{{"STEP -5,0.9,250", "step -5, 0.9, 250"}, "step(-5,0.9,250,9.91e+37)", ""},
        CommandCase{{"STEP 3,0.1,200,1.5e-5"}, "step(3,0.1,200,1.5e-05)", ""},
        CommandCase{{"REG? 200,0.1", "REGION? 200,0.1", "region? 200, 0.1"},
                    "region(200,0.1,9.91e+37)",
                    "ONESTEP,-2e-07"},
        CommandCase{{"REG? 2000,0.1,2e-5"}, "region(2000,0.1,2e-05)", "CUTOFF,-2e-06"},
        CommandCase{{"REG:RANG?", "REGION:RANGE?", "axis1:reg:rang?"},
                    "region_range()",
                    "10,2000,1e-07,2e-05"},
        CommandCase{{"LIM:LOW -5e-4", "LIMIT:LOWER -5e-4", "limit:low -0.0005"},
                    "set_soft_limits(-0.0005,0.001)",
                    ""},
        CommandCase{{"LIM:UPP 5e-4", "LIMIT:UPPER 5e-4"}, "set_soft_limits(-0.001,0.0005)", ""},
        CommandCase{{"LIM:LOW?", "LIMIT:LOWER?"}, "", "-0.001"},
        CommandCase{{"LIM:UPP?", "limit:upper?"}, "", "0.001"},
        CommandCase{{"LIM -2e-3,2e-3", "LIMIT -2e-3,2e-3"}, "set_soft_limits(-0.002,0.002)", ""},
        CommandCase{{"LIM?", "LIMIT?"}, "", "-0.001,0.001"},
        CommandCase{
            {"STAT?", "STATUS?", "status?"},
            "",
            "state=IDLE done=1 position=0 position_valid=1 target=0 fault=none lower=-0.001 "
            "upper=0.001 moves=0 bursts=0 cycles=0 errors=0 last_error=0 daemon_error=none axis=x "
            "referenced=0 device=up "
            "result=NONE eot=none in_position=0 holding=0 referencing=0 fault_reason=none "
            "offset=0 least_window=0"},
        CommandCase{
            {"SWEEP /tmp/s,100:300:100,0.1;0.2,3", "sweep \"/tmp/s\", 100:300:100, 0.1;0.2, 3"},
            "sweep(/tmp/s,100;200;300,0.1;0.2,3,12)",
            ""},
        CommandCase{{"SWEEP /tmp/s,250,0.3,2,40"}, "sweep(/tmp/s,250,0.3,2,40)", ""}));

TEST(ProtocolSession, SystClientsReadsTheServersTable) {
  struct Table : ClientTable {
    ClientTableStats client_table() const override { return {5, 3, 16, 1, 4, 1}; }
  } table;
  Harness h;
  EXPECT_EQ(h.line("SYST:CLI?"), "\n");  // outside a server there is no table: -200
  EXPECT_EQ(h.next_error(), ec::kExecutionError);
  h.session.set_client_table(&table);
  EXPECT_EQ(h.line("SYST:CLI?"), "5\n");
  EXPECT_EQ(h.line("system:clients:count?"), "5\n");
  EXPECT_EQ(h.line("SYSTem:CLIents:TABLe?"),
            "connected=5 slots=3 max_clients=16 stop_only=1 overflow_slots=4 draining=1\n");
  EXPECT_EQ(h.line("AXIS1:SYST:CLI?"), "\n");  // an instrument query: no axis prefix
  EXPECT_EQ(h.next_error(), ec::kUndefinedHeader);
  EXPECT_EQ(h.line("SYST:CLI? 1"), "\n");
  EXPECT_EQ(h.next_error(), ec::kParameterNotAllowed);
  EXPECT_EQ(h.next_error_text(), "0,\"No error\"\n");
}

TEST(ProtocolSession, CommandTableListsEveryHeaderOnce) {
  std::vector<std::string> seen;
  for (const CommandInfo& c : command_table()) {
    const std::string key = std::string(c.pattern) + (c.query ? "?" : "");
    for (const auto& s : seen) EXPECT_NE(s, key);
    seen.push_back(key);
    EXPECT_LE(c.min_args, c.max_args);
  }
  EXPECT_GE(seen.size(), 25u);
}

TEST(ProtocolSession, LinesEndInLfOrCrLfAndMaySplitAnywhere) {
  Harness h;
  EXPECT_EQ(h.send("*IDN?\r\n"), "idm,idmd,0,test\n");
  std::string out;
  for (char c : std::string("POS?\r\nMOVE:DONE?\n")) out += h.send(std::string(1, c));
  EXPECT_EQ(out, "0\n1\n");
  EXPECT_EQ(h.send("*IDN?\n*OPC?\nSTAT"), "idm,idmd,0,test\n1\n");
  EXPECT_EQ(h.session.held_bytes(), 4u);
  EXPECT_EQ(h.session.unterminated_bytes(), 4u);
  EXPECT_EQ(count_lines(h.send("US?\n")), 1);
  EXPECT_EQ(h.session.unterminated_bytes(), 0u);
}

TEST(ProtocolSession, BlankLinesAreIgnored) {
  Harness h;
  EXPECT_EQ(h.send("\n\r\n   \n\t\n"), "");
  EXPECT_EQ(h.line("SYST:ERR:COUN?"), "0\n");
}

TEST(ProtocolSession, AFinalLineWithoutNewlineNeverRuns) {
  // A client that dies mid-line (or a script whose last line lacks its newline) must not move
  // the stage with what it sent: a line runs only once it is terminated.
  Harness h;
  EXPECT_EQ(h.send("POS?\nMOVE:REL 1"), "0\n");
  std::string out;
  h.session.end_of_input(out);
  EXPECT_EQ(out, "");
  EXPECT_TRUE(h.session.idle());
  EXPECT_EQ(h.fake.motion_calls(), 0u);
  EXPECT_TRUE(h.fake.calls().empty() || h.fake.calls().back().rfind("move", 0) != 0);
}

TEST(ProtocolSession, AStopOnlySessionRefusesEverythingButStop) {
  Harness h;
  h.session.set_stop_only(true);
  EXPECT_EQ(h.line("MOVE:ABS 1e-6"), "");
  EXPECT_EQ(h.next_error(), ec::kSettingsConflict);
  EXPECT_EQ(h.line("POS?"), "\n");
  EXPECT_EQ(h.next_error(), ec::kSettingsConflict);
  EXPECT_EQ(h.line("STOP"), "");
  EXPECT_EQ(h.line("*IDN?"), "idm,idmd,0,test\n");
  EXPECT_EQ(h.line("SYST:ERR?"), "0,\"No error\"\n");
  EXPECT_EQ(h.fake.motion_calls(), 0u);
  EXPECT_EQ(h.fake.calls().back(), "stop");
}

TEST(ProtocolSession, AnUntrustedPositionIsNotANumberWithMinus230) {
  Harness h;
  h.fake.set_position(1e-6, false);
  // SCPI's not-a-number, never the last good value, never an empty line; -230 says why.
  EXPECT_EQ(h.line("POS?"), "9.91E37\n");
  EXPECT_EQ(h.next_error(), ec::kDataCorruptOrStale);
  EXPECT_NE(h.line("STAT?").find(" position=9.91E37 position_valid=0 "), std::string::npos);
  h.fake.set_position(1.25e-6, true);
  EXPECT_EQ(h.line("POS?"), "1.25e-06\n");
}

TEST(ProtocolSession, InstrumentRefusalsGoToTheQueueWithTheirText) {
  Harness h;
  h.fake.set_refusal({ec::kDataOutOfRange, "target 0.002 m past the upper soft limit 0.001 m"});
  EXPECT_EQ(h.line("MOVE:ABS 2e-3"), "");
  EXPECT_EQ(h.next_error_text(),
            "-222,\"Data out of range; target 0.002 m past the upper soft limit 0.001 m\"\n");
  EXPECT_EQ(h.line("REG? 200,1.5"), "\n");
  EXPECT_EQ(h.next_error(), ec::kDataOutOfRange);
}

TEST(ProtocolSession, ErrorQueueIsClearedByClsAndRst) {
  Harness h;
  h.line("BOGUS");
  h.line("BOGUS");
  EXPECT_NE(h.line("STAT?").find("errors=2 last_error=-113"), std::string::npos);
  EXPECT_EQ(h.line("SYST:ERR:ALL?"),
            "-113,\"Undefined header; 'BOGUS'\",-113,\"Undefined header; 'BOGUS'\"\n");
  h.line("BOGUS");
  h.line("*CLS");
  EXPECT_EQ(h.line("SYST:ERR:COUN?"), "0\n");
  h.line("BOGUS");
  h.line("*RST");
  EXPECT_EQ(h.line("SYST:ERR:COUN?"), "0\n");
  EXPECT_EQ(h.fake.last_call(), "reset");
}

TEST(ProtocolSession, QueuesArePerSession) {
  FakeInstrument fake;
  Session a(fake), b(fake);
  std::string out;
  a.receive("BOGUS\n", out);
  b.receive("SYST:ERR?\n", out);
  a.receive("SYST:ERR?\n", out);
  EXPECT_EQ(out, "0,\"No error\"\n-113,\"Undefined header; 'BOGUS'\"\n");
}

// ---------------------------------------------------------------------------------------------
// Session: malformed lines never move and always leave an error

struct MalformedCase {
  std::string line;
  int code;
};

void PrintTo(const MalformedCase& c, std::ostream* os) {
  *os << printable(c.line);
}

class ProtocolMalformed : public ::testing::TestWithParam<MalformedCase> {};

TEST_P(ProtocolMalformed, LeavesTheErrorAndMovesNothing) {
  const MalformedCase& c = GetParam();
  Harness h;
  const std::string out = h.line(c.line);
  EXPECT_EQ(out, looks_like_query(c.line) ? "\n" : "") << c.line;
  EXPECT_EQ(h.fake.motion_calls(), 0u) << c.line;
  EXPECT_EQ(h.next_error(), c.code) << c.line;
  EXPECT_EQ(h.next_error(), 0) << c.line;
}

INSTANTIATE_TEST_SUITE_P(
    AllMalformed, ProtocolMalformed,
    ::testing::Values(MalformedCase{"FOO", ec::kUndefinedHeader},
                      MalformedCase{"FOO?", ec::kUndefinedHeader},
                      MalformedCase{"MOVE:ABSO 1e-6", ec::kUndefinedHeader},
                      MalformedCase{"STOP?", ec::kUndefinedHeader},  // no query form
                      MalformedCase{"POS", ec::kUndefinedHeader},    // no command form
                      MalformedCase{"MOVE:DONE", ec::kUndefinedHeader},
                      MalformedCase{"*IDN", ec::kUndefinedHeader},
                      MalformedCase{"MOVE:ABS", ec::kMissingParameter},
                      MalformedCase{"MOVE:ABS 1,2", ec::kParameterNotAllowed},
                      MalformedCase{"MOVE:REL", ec::kMissingParameter},
                      MalformedCase{"POS? 1", ec::kParameterNotAllowed},
                      MalformedCase{"*RST 1", ec::kParameterNotAllowed},
                      MalformedCase{"STEP", ec::kMissingParameter},
                      MalformedCase{"STEP 10,0.1", ec::kMissingParameter},
                      MalformedCase{"STEP 10,0.1,200,1e-5,3", ec::kParameterNotAllowed},
                      MalformedCase{"STEP 1.5", ec::kDataOutOfRange},
                      MalformedCase{"STEP 1e12", ec::kDataOutOfRange},
                      MalformedCase{"STEP nan", ec::kNumericDataError},
                      MalformedCase{"STEP 0", ec::kDataOutOfRange},
                      MalformedCase{"STEP \"10\"", ec::kDataTypeError},
                      MalformedCase{"STEP 10,\"0.1\",200", ec::kDataTypeError},
                      MalformedCase{"MOVE:REL \"1e-6\"", ec::kDataTypeError},
                      MalformedCase{"MOVE:ABS \"1e-6\"", ec::kDataTypeError},
                      MalformedCase{"LIM:UPP \"1e-3\"", ec::kDataTypeError},
                      MalformedCase{"LIM \"-1e-3\",1e-3", ec::kDataTypeError},
                      MalformedCase{"REG? \"200\",0.1", ec::kDataTypeError},
                      MalformedCase{"SWEEP d,\"100;200\",0.1,3", ec::kDataTypeError},
                      MalformedCase{"SWEEP d,100,0.1,\"3\"", ec::kDataTypeError},
                      MalformedCase{"STEP 10,inf,200", ec::kNumericDataError},
                      MalformedCase{"REG? 200", ec::kMissingParameter},
                      MalformedCase{"REG? 200,0.1,1e-5,4", ec::kParameterNotAllowed},
                      MalformedCase{"REG? abc,0.1", ec::kNumericDataError},
                      MalformedCase{"LIM:LOW", ec::kMissingParameter},
                      MalformedCase{"LIM:UPP 1e999", ec::kNumericDataError},
                      MalformedCase{"LIM 1", ec::kMissingParameter},
                      MalformedCase{"MOVE:ABS inf", ec::kNumericDataError},
                      MalformedCase{"MOVE:ABS -INF", ec::kNumericDataError},
                      MalformedCase{"MOVE:ABS NaN", ec::kNumericDataError},
                      MalformedCase{"MOVE:ABS 1e400", ec::kNumericDataError},
                      MalformedCase{"MOVE:ABS 0x1p-20", ec::kNumericDataError},
                      MalformedCase{"MOVE:ABS 1um", ec::kNumericDataError},
                      MalformedCase{"MOVE:REL \"1e-6\"x", ec::kSyntaxError},
                      MalformedCase{"MOVE:ABS 1e-6,", ec::kSyntaxError},
                      MalformedCase{"MOVE:ABS 1\xc3\xa9-6", ec::kInvalidCharacter},
                      MalformedCase{"MOVE:ABS \xff", ec::kInvalidCharacter},
                      MalformedCase{std::string("MOVE:ABS 1e-6\0", 14), ec::kInvalidCharacter},
                      MalformedCase{"POS?\x01", ec::kInvalidCharacter},
                      MalformedCase{"MOVE::ABS 1", ec::kSyntaxError},
                      MalformedCase{"SWEEP /tmp/s,100:300,0.1,3", ec::kSyntaxError},
                      MalformedCase{"SWEEP /tmp/s,100,0.1,0", ec::kDataOutOfRange},
                      MalformedCase{"SWEEP /tmp/s,100,0.1,2.5", ec::kDataOutOfRange},
                      MalformedCase{"SWEEP /tmp/s,100,0.1;inf,3", ec::kNumericDataError},
                      MalformedCase{"SWEEP \"\",100,0.1,3", ec::kDataOutOfRange},
                      MalformedCase{"SWEEP /tmp/s,100,0.1", ec::kMissingParameter},
                      MalformedCase{"SWEEP /tmp/s,100,0.1,3,12,1", ec::kParameterNotAllowed}));

TEST(ProtocolSession, TooLongLineIsDiscardedUpToItsNewline) {
  Harness h;
  const std::string ok_line = "MOVE:ABS " + std::string(kMaxLineBytes - 10, ' ') + "1";
  ASSERT_EQ(ok_line.size(), kMaxLineBytes);
  EXPECT_EQ(h.send(ok_line + "\r\n"), "");
  EXPECT_EQ(h.fake.last_call(), "move_absolute(1)");
  h.fake.clear_calls();

  // One byte more, in one piece and in small pieces: -363, no move, the next line works.
  const std::string long_line = "MOVE:ABS " + std::string(kMaxLineBytes - 9, ' ') + "1";
  EXPECT_EQ(h.send(long_line + "\nPOS?\n"), "1\n");
  EXPECT_EQ(h.next_error(), ec::kInputBufferOverrun);
  std::string out;
  for (std::size_t k = 0; k < long_line.size(); k += 100) out += h.send(long_line.substr(k, 100));
  EXPECT_LE(h.session.held_bytes(), kMaxLineBytes + 100);
  out += h.send("\nPOS?\n");
  EXPECT_EQ(out, "1\n");
  EXPECT_EQ(h.next_error(), ec::kInputBufferOverrun);
  EXPECT_EQ(h.next_error(), 0);
  EXPECT_EQ(h.fake.motion_calls(), 0u);
}

TEST(ProtocolSession, TooLongQueryStillGetsItsOneReplyLine) {
  Harness h;
  const std::string long_query = "REG? " + std::string(kMaxLineBytes, '1');
  EXPECT_EQ(h.send(long_query + "\n"), "\n");
  EXPECT_EQ(h.next_error(), ec::kInputBufferOverrun);
  // Streamed without its newline: the reply comes as soon as it is known to be too long.
  std::string out = h.send(long_query);
  EXPECT_EQ(out, "\n");
  EXPECT_EQ(h.send(std::string(100000, '2')), "");  // the rest of it is dropped, not held
  EXPECT_EQ(h.session.held_bytes(), 0u);
  EXPECT_EQ(h.session.unterminated_bytes(), long_query.size() + 100000);
  EXPECT_EQ(h.send("\n*IDN?\n"), "idm,idmd,0,test\n");
}

// Found by tests/fuzz/fuzz_protocol: a first word longer than the line limit, ending in '?'. The
// session judges a too-long line by its start (the '?' had not arrived), the client by the whole
// line, so the client waited for a reply that never came. Such a word is no query for either.
TEST(ProtocolSession, AQueryWordLongerThanTheLineLimitIsNoQueryForServerOrClient) {
  const std::string long_word = "STAT" + std::string(5910, 'U') + "?";
  EXPECT_FALSE(looks_like_query(long_word));
  EXPECT_FALSE(looks_like_query(long_word + " 1"));
  EXPECT_TRUE(looks_like_query(std::string(kMaxLineBytes - 1, 'X') + "?"));
  EXPECT_FALSE(looks_like_query(std::string(kMaxLineBytes, 'X') + "?"));
  for (std::size_t piece : {std::size_t{1}, std::size_t{256}, std::size_t{100000}}) {
    SCOPED_TRACE(piece);
    Harness h;
    const std::string stream = "POS?\n" + long_word + "\n*IDN?\n";
    std::string out;
    for (std::size_t at = 0; at < stream.size(); at += piece)
      h.session.receive(std::string_view(stream).substr(at, piece), out);
    EXPECT_EQ(out, "0\nidm,idmd,0,test\n");
    EXPECT_EQ(h.next_error(), ec::kInputBufferOverrun);
  }
}

TEST(ProtocolSession, RandomLinesGetOneReplyPerQueryAndNeverMove) {
  // Lines built from pieces of real commands, garbage and bytes that must be refused.
  const std::vector<std::string> heads = {"POS?",  "MOVE",      "MOVE:ABS", "MOVE:",     "REG?",
                                          "STEP?", "SYST:ERR?", "LIM:LOW?", "*IDN?",     "FOO?",
                                          "?",     ":",         "*",        "\xc3\xa9?", "STAT?"};
  const std::vector<std::string> args = {"",      " ",          " 1",     " inf", " 1,",
                                         " ,",    " \"",        " 1e999", " a;b", " 1:2:0",
                                         " \x01", " 1,2,3,4,5", "?",      "\r"};
  std::mt19937 rng(7);
  Harness h;
  int queries = 0;
  std::string out;
  for (int k = 0; k < 5000; ++k) {
    std::string line =
        heads[rng() % heads.size()] + args[rng() % args.size()] + args[rng() % args.size()];
    if (line.rfind("MOVE", 0) == 0 && line.find('?') == std::string::npos)
      line += ",x";  // never valid
    queries += looks_like_query(line);
    out += h.line(line);
  }
  EXPECT_EQ(count_lines(out), queries);
  EXPECT_EQ(h.fake.motion_calls(), 0u);
}

// ---------------------------------------------------------------------------------------------
// Session: *OPC?, *WAI and the end of a motion

TEST(ProtocolSession, OpcQueryRepliesOnceTheMotionIsDoneAndHoldsLaterLines) {
  Harness h;
  h.fake.set_polls_until_done(3);
  EXPECT_EQ(h.line("MOVE:ABS 1e-6"), "");
  EXPECT_EQ(h.send("*OPC?\n*IDN?\nMOVE:REL 1e-6\n"), "");
  EXPECT_TRUE(h.session.waiting());
  EXPECT_EQ(h.fake.calls().size(), 1u);  // the relative move is held
  std::string out;
  for (int k = 0; k < 10 && h.session.waiting(); ++k) h.session.poll(out);
  EXPECT_EQ(out, "1\nidm,idmd,0,test\n");
  EXPECT_EQ(h.fake.last_call(), "move_relative(1e-06)");
}

TEST(ProtocolSession, WaiHoldsLaterLinesWithoutAReply) {
  Harness h;
  h.fake.set_polls_until_done(5);  // (every line asks motion_done() too)
  EXPECT_EQ(h.send("STEP 10\n*WAI\nPOS?\n"), "");
  EXPECT_TRUE(h.session.waiting());
  std::string out;
  for (int k = 0; k < 10 && h.session.waiting(); ++k) h.session.poll(out);
  EXPECT_EQ(out, "0\n");
}

TEST(ProtocolSession, MoveDoneFollowsTheInstrument) {
  Harness h;
  h.fake.set_polls_until_done(4);  // (every line asks motion_done() too)
  h.line("MOVE:ABS 1e-6");
  EXPECT_EQ(h.line("MOVE:DONE?"), "0\n");
  EXPECT_EQ(h.line("MOVE:DONE?"), "1\n");
  EXPECT_EQ(h.line("POS?"), "1e-06\n");
}

TEST(ProtocolSession, StatusShowsTheDaemonsLastErrorAsOneWord) {
  Harness h;
  h.fake.set_last_error("fault driver: read\ttimed out\n");
  const std::string stat = h.line("STAT?");
  EXPECT_NE(stat.find(" daemon_error=fault_driver:_read_timed_out_ "), std::string::npos) << stat;
  h.fake.set_last_error("");
  EXPECT_NE(h.line("STAT?").find(" daemon_error=none "), std::string::npos);
}

TEST(ProtocolSession, AMotionThatEndsInAFaultLeavesItsPositiveCode) {
  Harness h;
  h.fake.set_polls_until_done(2);
  h.fake.set_fault_on_finish("stall");
  h.line("MOVE:ABS 1e-6");
  while (h.line("MOVE:DONE?") != "1\n") {
  }
  EXPECT_EQ(h.next_error_text(), "102,\"Stall; motion ended in fault stall\"\n");
  EXPECT_EQ(h.next_error(), 0);  // reported once
  EXPECT_EQ(h.line("*TST?"), "1\n");
  EXPECT_NE(h.line("STAT?").find("state=FAULT"), std::string::npos);
  // Another session that started nothing hears nothing of it.
  Session other(h.fake);
  std::string out;
  other.receive("SYST:ERR?\n", out);
  EXPECT_EQ(out, "0,\"No error\"\n");
}

TEST(ProtocolSession, FaultNamesMapToTheirCodes) {
  EXPECT_TRUE(fault_error("none").ok());
  EXPECT_TRUE(fault_error("").ok());
  EXPECT_EQ(fault_error("invalid_sample").code, ec::kFaultInvalidSample);
  EXPECT_EQ(fault_error("stall").code, ec::kFaultStall);
  EXPECT_EQ(fault_error("retry_limit").code, ec::kFaultRetryLimit);
  EXPECT_EQ(fault_error("driver").code, ec::kFaultDriver);
  EXPECT_EQ(fault_error("no_plan").code, ec::kFaultNoPlan);
  EXPECT_EQ(fault_error("capture_overrun").code, ec::kFaultCaptureOverrun);
  // Every device fault's code has its own text, from the one table.
  for (const DeviceFault& f : kDeviceFaults) {
    EXPECT_EQ(fault_error(f.name).code, f.code);
    EXPECT_STREQ(standard_error_text(f.code), f.text);
  }
  EXPECT_EQ(fault_error("something_new").code, ec::kExecutionError);
}

TEST(ProtocolSession, AnInstrumentThatThrowsIsAnExecutionErrorNotACrash) {
  Harness h;
  h.fake.set_polls_until_done(1 << 30);
  h.line("MOVE:ABS 1e-6");
  EXPECT_EQ(h.send("*OPC?\n"), "");
  h.fake.set_throw(true);
  std::string out;
  h.session.poll(out);
  EXPECT_EQ(out, "\n");  // the wait ends, with its one (empty) reply line
  EXPECT_EQ(h.line("*IDN?"), "\n");
  h.fake.set_throw(false);
  EXPECT_EQ(h.next_error_text(), "-200,\"Execution error; motion_done broke\"\n");
  EXPECT_EQ(h.next_error(), ec::kExecutionError);  // notice_motion_end's motion_done()
  EXPECT_EQ(h.next_error_text(), "-200,\"Execution error; identity broke\"\n");
}
