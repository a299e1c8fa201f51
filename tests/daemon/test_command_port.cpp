// The command port talks only to clients that mean it: HTTP (a web page's cross-origin POST, a
// browser pointed at the port) is closed before any of its lines runs, and a listener with a token
// runs nothing that moves or changes a setting before `*AUTH <token>`. Session-level cases with
// generated requests and lines; the server's part over real sockets.
#include <gtest/gtest.h>

#include <filesystem>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "daemon/protocol.h"
#include "daemon/server.h"
#include "tests/daemon/session_harness.h"
#include "tests/daemon/socket_client.h"

using namespace idm::daemon;
using idm::daemon::testing::FakeInstrument;
using idm::daemon::testing::Harness;
using idm::daemon::testing::LineClient;
namespace ec = idm::daemon::error_code;

namespace {

// A request as some HTTP client would send it: a method, a path, headers in any order and case,
// CR LF or bare LF, and a body of command lines.
std::string random_http_request(std::mt19937& rng, const std::string& body) {
  const std::vector<std::string> methods = {"GET",  "POST",   "PUT",  "OPTIONS",
                                            "HEAD", "DELETE", "PATCH"};
  const std::vector<std::string> paths = {"/", "/x?a=1", "*", "http://127.0.0.1:5025/",
                                          "/MOVE:REL%201e-4"};
  const std::vector<std::string> headers = {
      "Host: 127.0.0.1:5025",        "host:localhost",
      "Origin: http://evil.example", "Accept: */*",
      "User-Agent: Mozilla/5.0",     "Content-Type: text/plain;charset=UTF-8",
      "Content-Length: 14",          "Sec-Fetch-Mode: no-cors",
      "Connection: keep-alive",      "Referer: http://evil.example/"};
  const std::string eol = rng() % 2 ? "\r\n" : "\n";
  std::string r = methods[rng() % methods.size()] + " " + paths[rng() % paths.size()] + " HTTP/1." +
                  std::to_string(rng() % 2) + eol;
  const std::size_t n = rng() % 5;
  for (std::size_t k = 0; k < n; ++k) r += headers[rng() % headers.size()] + eol;
  return r + eol + body;
}

// Feeds `bytes` to the session in pieces of random sizes.
std::string feed(Harness& h, std::mt19937& rng, const std::string& bytes) {
  std::string out;
  for (std::size_t at = 0; at < bytes.size();) {
    const std::size_t piece = 1 + rng() % 40;
    h.session.receive(std::string_view(bytes).substr(at, piece), out);
    at += piece;
  }
  return out;
}

}  // namespace

TEST(CommandPort, EveryHttpRequestIsRefusedBeforeAnyOfItsLinesRuns) {
  std::mt19937 rng(11);
  for (int k = 0; k < 500; ++k) {
    Harness h;
    feed(h, rng, random_http_request(rng, "MOVE:REL 2e-4\nSTEP 100\n*RST\nLIM -1,1\n"));
    EXPECT_FALSE(h.session.close_reason().empty()) << k;
    EXPECT_EQ(h.fake.motion_calls(), 0u) << k;
    EXPECT_TRUE(h.fake.calls().empty()) << k << ": " << h.fake.last_call();
  }
}

TEST(CommandPort, ARequestLineTooLongForALineIsRefusedAsHttpToo) {
  Harness h;
  const std::string request = "POST /" + std::string(9000, 'a') + " HTTP/1.1\r\n\r\nMOVE:REL 1\n";
  std::mt19937 rng(3);
  feed(h, rng, request);
  EXPECT_FALSE(h.session.close_reason().empty());
  EXPECT_EQ(h.fake.motion_calls(), 0u);
}

TEST(CommandPort, NoLineOfTheProtocolLooksLikeHttp) {
  // Every command's short and long form, with and without an axis prefix and arguments.
  std::mt19937 rng(5);
  const std::vector<std::string> args = {"",     " 1e-6", " 1,0.2,300", " \"a,b\",100:200:50,0.1,3",
                                         " NEG", " -1"};
  for (const CommandInfo& c : command_table()) {
    std::string full, shortform;
    for (const char* p = c.pattern; *p; ++p) {
      if (*p == '[' || *p == ']') continue;
      full += *p;
      if (!(*p >= 'a' && *p <= 'z')) shortform += *p;
    }
    for (const std::string& form : {full, shortform}) {
      for (const std::string& prefix : {std::string(), std::string("AXIS2:"), std::string(":")}) {
        std::string line = prefix + form + (c.query ? "?" : "") + args[rng() % args.size()];
        EXPECT_FALSE(looks_like_http(line)) << line;
        for (char& ch : line) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
        EXPECT_FALSE(looks_like_http(line)) << line;
      }
    }
  }
}

TEST(CommandPort, HttpShapesAreRecognisedAndOnlyThose) {
  for (const char* line :
       {"GET / HTTP/1.1", "POST /api HTTP/1.0\r", "PRI * HTTP/2.0", "MKCOL /x HTTP/1.1", "GET /",
        "Host: a", "ORIGIN: null", "sec-fetch-site: cross-site", "Content-Length:14"})
    EXPECT_TRUE(looks_like_http(line)) << line;
  for (const char* line : {"MOVE:REL 1e-6", "POS?", "SWEEP \"get a\",100,0.1,3", "SYST:ERR?",
                           "HOST?", "*IDN?", "GETS", "", "host"})
    EXPECT_FALSE(looks_like_http(line)) << line;
}

TEST(CommandPort, ATokenGuardsMotionAndSettingsButNotQueriesOrStop) {
  const std::string token = "s3cret-token-0123456789";
  Harness h;
  h.session.require_token(&token);
  EXPECT_EQ(h.line("*AUTH?"), "0\n");
  for (const char* line :
       {"MOVE:ABS 1e-6", "MOVE:REL 1e-6", "STEP 10", "LIM -1e-3,1e-3", "MOVE:WIND 1e-8", "HOLD 1",
        "REF", "*RST", "SIM:PUSH 1e-6", "SWEEP a,100,0.1,3"}) {
    h.line(line);
    EXPECT_EQ(h.next_error(), ec::kCommandProtected) << line;
  }
  EXPECT_EQ(h.fake.motion_calls(), 0u);
  EXPECT_EQ(h.line("POS?"), "0\n");
  h.line("STOP");
  EXPECT_EQ(h.next_error(), 0);
  h.line("*AUTH " + token);
  EXPECT_EQ(h.line("*AUTH?"), "1\n");
  h.line("MOVE:ABS 1e-6");
  EXPECT_EQ(h.next_error(), 0);
  EXPECT_EQ(h.fake.motion_calls(), 1u);
  EXPECT_TRUE(h.session.close_reason().empty());
}

TEST(CommandPort, AWrongTokenClosesTheConnectionAndRunsNothingAfterIt) {
  const std::string token = "s3cret-token-0123456789";
  std::mt19937 rng(9);
  for (int k = 0; k < 50; ++k) {
    Harness h;
    h.session.require_token(&token);
    // A wrong token of the token's own alphabet: one character changed, or a prefix.
    const std::string alphabet = "abcdefghijklmnopqrstuvwxyz0123456789-";
    std::string wrong = token;
    char& c = wrong[rng() % wrong.size()];
    c = alphabet[(alphabet.find(c) + 1 + rng() % (alphabet.size() - 1)) % alphabet.size()];
    if (k % 3 == 0) wrong = token.substr(0, rng() % token.size());
    if (wrong.empty()) wrong = "x";
    feed(h, rng, "*AUTH " + wrong + "\n*AUTH " + token + "\nMOVE:ABS 1e-6\n");
    EXPECT_FALSE(h.session.close_reason().empty()) << wrong;
    EXPECT_EQ(h.fake.motion_calls(), 0u) << wrong;
  }
}

// ---- the server ---------------------------------------------------------------------------------

TEST(CommandPortServer, AnHttpClientIsClosedLoggedOnceAndNothingMoves) {
  FakeInstrument fake;
  ServerConfig c;
  c.tcp_port = 0;
  std::vector<std::string> warnings;
  c.warn = [&warnings](std::string_view line) { warnings.emplace_back(line); };
  Server server(fake, c);
  ASSERT_EQ(server.start(), "");
  for (int k = 0; k < 3; ++k) {
    LineClient http = LineClient::tcp(server.tcp_port());
    ASSERT_TRUE(http.ok());
    ASSERT_TRUE(
        http.send("POST / HTTP/1.1\r\nHost: 127.0.0.1:5025\r\nOrigin: http://evil\r\n"
                  "Content-Type: text/plain\r\nContent-Length: 14\r\n\r\nMOVE:REL 2e-4\n"));
    EXPECT_TRUE(http.wait_closed());
  }
  LineClient scpi = LineClient::tcp(server.tcp_port());
  EXPECT_EQ(scpi.ask("*IDN?"), "idm,idmd,0,test");  // the port still serves its own clients
  server.stop();
  EXPECT_EQ(fake.motion_calls(), 0u);
  EXPECT_EQ(server.counters().refused, 3u);
  ASSERT_EQ(warnings.size(), 1u);  // one line, not one per request
  EXPECT_NE(warnings[0].find("HTTP"), std::string::npos) << warnings[0];
}

TEST(CommandPortServer, TheTokenIsAskedOnTcpOnlyNotOnTheUnixSocket) {
  FakeInstrument fake;
  const std::string dir = idm::daemon::testing::make_temp_dir();
  ServerConfig c;
  c.tcp_port = 0;
  c.unix_path = dir + "/idmd.sock";
  c.tcp_token = "0123456789abcdef0123";
  Server server(fake, c);
  ASSERT_EQ(server.start(), "");
  LineClient tcp = LineClient::tcp(server.tcp_port());
  ASSERT_TRUE(tcp.send("MOVE:ABS 1e-6\n"));
  EXPECT_EQ(tcp.ask("SYST:ERR?").substr(0, 4), "-203");
  LineClient local = LineClient::unix_socket(c.unix_path);
  ASSERT_TRUE(local.send("MOVE:ABS 2e-6\n"));
  EXPECT_EQ(local.ask("SYST:ERR?"), "0,\"No error\"");
  ASSERT_TRUE(tcp.send("*AUTH 0123456789abcdef0123\nMOVE:ABS 3e-6\n"));
  EXPECT_EQ(tcp.ask("SYST:ERR?"), "0,\"No error\"");
  server.stop();
  EXPECT_EQ(fake.motion_calls(), 2u);
  std::filesystem::remove_all(dir);
}

TEST(CommandPortServer, LoopbackAddressesAreTold) {
  for (const char* a : {"127.0.0.1", "127.1.2.3", "::1", "localhost", "::ffff:127.0.0.1"})
    EXPECT_TRUE(is_loopback_address(a)) << a;
  for (const char* a : {"0.0.0.0", "::", "192.168.1.2", "10.0.0.1", "lab-pc", "", "128.0.0.1",
                        "::ffff:10.0.0.1", "localhost.evil.example"})
    EXPECT_FALSE(is_loopback_address(a)) << a;
}
