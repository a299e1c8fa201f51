// The command protocol without sockets: the pure parsing functions (keywords, numbers, lists,
// replies, lines) and the error queue. A Session's commands: test_session.cpp.
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
// Pure functions

TEST(ProtocolKeywords, ShortAndLongFormsAnyCaseNothingInBetween) {
  EXPECT_TRUE(keyword_matches("ABSolute", "ABS"));
  EXPECT_TRUE(keyword_matches("ABSolute", "abs"));
  EXPECT_TRUE(keyword_matches("ABSolute", "Absolute"));
  EXPECT_FALSE(keyword_matches("ABSolute", "ABSO"));
  EXPECT_FALSE(keyword_matches("ABSolute", "AB"));
  EXPECT_TRUE(keyword_matches("STOP", "stop"));
  EXPECT_FALSE(keyword_matches("STOP", "sto"));
}

TEST(ProtocolKeywords, HeadersWithOptionalKeywordsAndCommonCommands) {
  EXPECT_TRUE(header_matches("SYSTem:ERRor[:NEXT]", "SYST:ERR"));
  EXPECT_TRUE(header_matches("SYSTem:ERRor[:NEXT]", "system:error:next"));
  EXPECT_TRUE(header_matches("SYSTem:ERRor[:NEXT]", ":SYST:ERR"));
  EXPECT_FALSE(header_matches("SYSTem:ERRor[:NEXT]", "SYST:ERR:COUN"));
  EXPECT_FALSE(header_matches("SYSTem:ERRor[:NEXT]", "SYST"));
  EXPECT_TRUE(header_matches("MOVE[:ABSolute]", "MOVE"));
  EXPECT_TRUE(header_matches("MOVE[:ABSolute]", "move:abs"));
  EXPECT_FALSE(header_matches("MOVE[:ABSolute]", "MOVE:REL"));
  EXPECT_TRUE(header_matches("*IDN", "*idn"));
  EXPECT_FALSE(header_matches("*IDN", "*ID"));
  EXPECT_FALSE(header_matches("LIMit:LOWer", "LIM"));
}

TEST(ProtocolNumbers, PlainAndExponentForms) {
  double v = 0;
  for (auto [text, want] : std::vector<std::pair<std::string, double>>{{"1", 1},
                                                                       {"-2.5", -2.5},
                                                                       {"+3", 3},
                                                                       {".5", 0.5},
                                                                       {"5.", 5},
                                                                       {"1e-6", 1e-6},
                                                                       {"1.5E+3", 1500},
                                                                       {" 7 ", 7},
                                                                       {"-0", 0}}) {
    ASSERT_TRUE(parse_number(text, "x", v).ok()) << text;
    EXPECT_DOUBLE_EQ(v, want) << text;
  }
}

TEST(ProtocolNumbers, NotANumberOrNotFiniteIsMinus120) {
  double v = 42;
  for (const char* text : {"", "abc", "1e", "e5", ".", "-", "1.2.3", "1e5x", "0x10", "inf", "-INF",
                           "nan", "NaN", "1e999", "-1e400", "1 2", "1,5", "++1"}) {
    const CommandError e = parse_number(text, "MOVE target", v);
    EXPECT_EQ(e.code, ec::kNumericDataError) << text;
    EXPECT_NE(e.text.find("MOVE target"), std::string::npos) << e.text;
  }
  EXPECT_EQ(v, 42);
}

TEST(ProtocolNumbers, IntegersAreIntegralAndInRange) {
  std::int64_t n = 0;
  EXPECT_TRUE(parse_integer("100", "n", -10, 1000, n).ok());
  EXPECT_EQ(n, 100);
  EXPECT_TRUE(parse_integer("1e2", "n", -10, 1000, n).ok());
  EXPECT_TRUE(parse_integer("-10", "n", -10, 1000, n).ok());
  EXPECT_EQ(n, -10);
  EXPECT_EQ(parse_integer("1.5", "n", -10, 1000, n).code, ec::kDataOutOfRange);
  EXPECT_EQ(parse_integer("1001", "n", -10, 1000, n).code, ec::kDataOutOfRange);
  EXPECT_EQ(parse_integer("x", "n", -10, 1000, n).code, ec::kNumericDataError);
}

TEST(ProtocolLists, RangesSemicolonsAndSingleValues) {
  std::vector<double> v;
  ASSERT_TRUE(parse_list("100:400:100", "f", v).ok());
  EXPECT_EQ(v, (std::vector<double>{100, 200, 300, 400}));
  ASSERT_TRUE(parse_list("0.05:0.95:0.1", "d", v).ok());
  ASSERT_EQ(v.size(), 10u);
  EXPECT_EQ(v[3], 0.35);
  ASSERT_TRUE(parse_list("0.1;0.2; 0.3", "d", v).ok());
  EXPECT_EQ(v, (std::vector<double>{0.1, 0.2, 0.3}));
  ASSERT_TRUE(parse_list("250", "f", v).ok());
  EXPECT_EQ(v, (std::vector<double>{250}));
}

TEST(ProtocolLists, BadListsSayWhy) {
  std::vector<double> v;
  EXPECT_EQ(parse_list("1;;2", "f", v).code, ec::kSyntaxError);
  EXPECT_EQ(parse_list("", "f", v).code, ec::kSyntaxError);
  EXPECT_EQ(parse_list("1:2", "f", v).code, ec::kSyntaxError);
  EXPECT_EQ(parse_list("1:2:3:4", "f", v).code, ec::kSyntaxError);
  EXPECT_EQ(parse_list("1:2:0", "f", v).code, ec::kDataOutOfRange);
  EXPECT_EQ(parse_list("2:1:1", "f", v).code, ec::kDataOutOfRange);
  EXPECT_EQ(parse_list("0:1e9:1", "f", v).code, ec::kDataOutOfRange);  // too many values
  EXPECT_EQ(parse_list("1;inf", "f", v).code, ec::kNumericDataError);
  EXPECT_EQ(parse_list("1:nan:1", "f", v).code, ec::kNumericDataError);
}

TEST(ProtocolFormat, RepliesAreFiniteNumbersAndQuotedStrings) {
  EXPECT_EQ(format_value(-1.234e-7), "-1.234e-07");
  EXPECT_EQ(format_value(0.001), "0.001");
  EXPECT_EQ(format_value(-3), "-3");
  EXPECT_EQ(format_value(0.012345678901234), "0.0123456789012");
  EXPECT_EQ(format_value(std::numeric_limits<double>::infinity()), "9.9e+37");
  EXPECT_EQ(format_value(-std::numeric_limits<double>::infinity()), "-9.9e+37");
  EXPECT_EQ(format_value(std::nan("")), "9.91e+37");
  EXPECT_EQ(quote("a\"b"), "\"a\"\"b\"");
  EXPECT_EQ(format_error({-113, "Undefined header"}), "-113,\"Undefined header\"");
  EXPECT_EQ(make_error(-222, "target past the upper limit").text,
            "Data out of range; target past the upper limit");
  EXPECT_EQ(make_error(-222, "data out of range; x").text, "data out of range; x");
  EXPECT_EQ(make_error(-222, std::string(1000, 'x')).text.size(), kMaxErrorTextBytes);
  EXPECT_EQ(make_error(-222, "a\nb").text, "Data out of range; a b");
}

TEST(ProtocolLines, QueriesAreLinesWhoseFirstWordEndsInAQuestionMark) {
  EXPECT_TRUE(looks_like_query("POS?"));
  EXPECT_TRUE(looks_like_query("  reg? 200,0.1"));
  EXPECT_TRUE(looks_like_query("FOO?"));
  EXPECT_TRUE(looks_like_query("POS?\r"));
  EXPECT_TRUE(looks_like_query("\xff?"));
  EXPECT_FALSE(looks_like_query("MOVE:ABS 1?"));
  EXPECT_FALSE(looks_like_query(""));
  EXPECT_FALSE(looks_like_query("STOP"));
}

TEST(ProtocolLines, SplitsHeaderAndCommaSeparatedArguments) {
  ParsedLine p;
  ASSERT_TRUE(parse_line("  :STEP  100, 0.1 ,200  ", p).ok());
  EXPECT_EQ(p.header, "STEP");
  EXPECT_FALSE(p.query);
  EXPECT_EQ(p.args, (std::vector<std::string>{"100", "0.1", "200"}));
  ASSERT_TRUE(parse_line("reg?\t200,0.1", p).ok());
  EXPECT_EQ(p.header, "reg");
  EXPECT_TRUE(p.query);
  ASSERT_TRUE(parse_line("SWEEP \"/tmp/a, b\"\"c\" ,100:200:100,0.1,3", p).ok());
  EXPECT_EQ(p.args, (std::vector<std::string>{"/tmp/a, b\"c", "100:200:100", "0.1", "3"}));
  ASSERT_TRUE(parse_line("   ", p).ok());
  EXPECT_TRUE(p.header.empty());
}

TEST(ProtocolLines, MalformedLinesAreSyntaxOrCharacterErrors) {
  ParsedLine p;
  EXPECT_EQ(parse_line("MOVE:ABS 1,,2", p).code, ec::kSyntaxError);
  EXPECT_EQ(parse_line("MOVE:ABS 1,", p).code, ec::kSyntaxError);
  EXPECT_EQ(parse_line("SWEEP \"abc", p).code, ec::kSyntaxError);
  EXPECT_EQ(parse_line("SWEEP \"abc\"x,1", p).code, ec::kSyntaxError);
  EXPECT_EQ(parse_line("MOVE::ABS 1", p).code, ec::kSyntaxError);
  EXPECT_EQ(parse_line("MOVE: 1", p).code, ec::kSyntaxError);
  EXPECT_EQ(parse_line("1MOVE", p).code, ec::kSyntaxError);
  EXPECT_EQ(parse_line("POS?1", p).code, ec::kSyntaxError);
  EXPECT_EQ(parse_line("*", p).code, ec::kSyntaxError);
  EXPECT_EQ(parse_line("?", p).code, ec::kSyntaxError);
  EXPECT_EQ(parse_line("MOVE:ABS 1\xc3\xa9", p).code, ec::kInvalidCharacter);
  EXPECT_EQ(parse_line(std::string("POS?\0", 5), p).code, ec::kInvalidCharacter);
  EXPECT_EQ(parse_line("POS?\x1b", p).code, ec::kInvalidCharacter);
  EXPECT_EQ(parse_line("POS?\x7f", p).code, ec::kInvalidCharacter);
  const CommandError e = parse_line("STOP \x80", p);
  EXPECT_NE(e.text.find("0x80 at column 6"), std::string::npos) << e.text;
}

// ---------------------------------------------------------------------------------------------
// Error queue

TEST(ProtocolErrorQueue, OldestFirstAndNoErrorWhenEmpty) {
  ErrorQueue q(4);
  EXPECT_EQ(q.pop().code, 0);
  q.push(make_error(-113));
  q.push(make_error(-222, "x"));
  q.push({});  // no error: not queued
  EXPECT_EQ(q.size(), 2u);
  EXPECT_EQ(q.last_code(), -222);
  EXPECT_EQ(q.pop().code, -113);
  EXPECT_EQ(q.pop().code, -222);
  const CommandError none = q.pop();
  EXPECT_EQ(none.code, 0);
  EXPECT_EQ(none.text, "No error");
}

TEST(ProtocolErrorQueue, OverflowReplacesTheNewestWithMinus350) {
  ErrorQueue q(4);
  for (int k = 0; k < 10; ++k) q.push(make_error(-100 - k));
  ASSERT_EQ(q.size(), 4u);
  EXPECT_EQ(q.pop().code, -100);
  EXPECT_EQ(q.pop().code, -101);
  EXPECT_EQ(q.pop().code, -102);
  EXPECT_EQ(q.pop().code, ec::kQueueOverflow);
  EXPECT_TRUE(q.empty());
  q.push(make_error(-113));  // room again
  EXPECT_EQ(q.pop().code, -113);
  q.push(make_error(-113));
  q.clear();
  EXPECT_TRUE(q.empty());
  EXPECT_EQ(q.last_code(), 0);
}

TEST(ProtocolErrorQueue, ASessionQueueOverflowsAtItsCapacity) {
  Harness h;
  for (std::size_t k = 0; k < kErrorQueueCapacity + 5; ++k) h.line("BOGUS");
  EXPECT_EQ(h.line("SYST:ERR:COUN?"), std::to_string(kErrorQueueCapacity) + "\n");
  for (std::size_t k = 0; k + 1 < kErrorQueueCapacity; ++k)
    EXPECT_EQ(h.next_error(), ec::kUndefinedHeader);
  EXPECT_EQ(h.next_error(), ec::kQueueOverflow);
  EXPECT_EQ(h.next_error_text(), "0,\"No error\"\n");
}
