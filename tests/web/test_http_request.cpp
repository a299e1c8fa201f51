// idm-web's request reader (web/http_request.h) and access rules (web/access.h): framing (the
// body's length, chunks, a length given twice), line folding and stray control bytes, the limits,
// pipelined requests, requests cut into pieces, the query's decoding, the Host header's names and
// ports, and the decision on every request.
//
// Inputs that vary come from a seeded generator: each run the same cases, many of them.
#include <gtest/gtest.h>

#include <random>
#include <string>
#include <vector>

#include "web/access.h"
#include "web/http_request.h"

using idm::web::AccessRules;
using idm::web::HttpLimits;
using idm::web::HttpRequest;
using idm::web::parse_request;
using idm::web::ParsedRequest;
using idm::web::RequestReader;
using Step = idm::web::RequestReader::Step;

namespace {

const HttpLimits kLimits;

std::string get(const std::string& fields = "Host: 127.0.0.1\r\n", const std::string& path = "/") {
  return "GET " + path + " HTTP/1.1\r\n" + fields + "\r\n";
}

std::string post(const std::string& fields, const std::string& body) {
  return "POST /api/stop HTTP/1.1\r\nHost: 127.0.0.1\r\n" + fields + "\r\n" + body;
}

int status_of(const std::string& bytes) {
  const ParsedRequest p = parse_request(bytes, kLimits);
  return p.step == Step::kRefused ? p.refusal.status : p.step == Step::kWhole ? 0 : -1;
}

// The reader given the bytes as they would come in pieces cut at `cuts` (the same prefix each
// time, longer), as the server gives them.
ParsedRequest read_in_pieces(const std::string& bytes, std::vector<std::size_t> cuts) {
  RequestReader reader(kLimits);
  ParsedRequest out;
  cuts.push_back(bytes.size());
  std::sort(cuts.begin(), cuts.end());
  for (const std::size_t cut : cuts) {
    out.step = reader.read(std::string_view(bytes).substr(0, std::min(cut, bytes.size())));
    if (out.step != Step::kMore) break;
  }
  if (out.step == Step::kWhole) {
    out.request = reader.request();
    out.size = reader.size();
  }
  if (out.step == Step::kRefused) out.refusal = reader.refusal();
  return out;
}

void expect_same(const ParsedRequest& a, const ParsedRequest& b, const std::string& bytes) {
  ASSERT_EQ(a.step, b.step) << bytes;
  EXPECT_EQ(a.refusal.status, b.refusal.status) << bytes;
  EXPECT_EQ(a.refusal.why, b.refusal.why) << bytes;
  EXPECT_EQ(a.size, b.size) << bytes;
  EXPECT_EQ(a.request.target, b.request.target) << bytes;
  EXPECT_EQ(a.request.headers, b.request.headers) << bytes;
  EXPECT_EQ(a.request.body, b.request.body) << bytes;
}

}  // namespace

TEST(HttpRequest, AWholeRequestIsReadWithItsFieldsAndBody) {
  const std::string bytes =
      post("Content-Type: application/x-www-form-urlencoded\r\nContent-Length: 6\r\nX-A:  b \t\r\n",
           "axis=1");
  const ParsedRequest p = parse_request(bytes + "GET / HTTP/1.1\r\n", kLimits);
  ASSERT_EQ(p.step, Step::kWhole);
  EXPECT_EQ(p.size, bytes.size());  // the next request starts there
  EXPECT_EQ(p.request.method, "POST");
  EXPECT_EQ(p.request.path, "/api/stop");
  EXPECT_EQ(p.request.body, "axis=1");
  EXPECT_EQ(*p.request.header("x-a"), "b");
  EXPECT_EQ(p.request.param("axis"), "1");
}

TEST(HttpRequest, EveryPrefixOfARequestWaitsForMore) {
  const std::string bytes = post("Content-Length: 6\r\n", "axis=1");
  for (std::size_t n = 0; n < bytes.size(); ++n) EXPECT_EQ(status_of(bytes.substr(0, n)), -1) << n;
  EXPECT_EQ(status_of(bytes), 0);
}

// Request smuggling: nothing is left for a second reader to frame another way.
TEST(HttpRequest, ABodyIsFramedOneWayOnly) {
  EXPECT_EQ(status_of(post("Transfer-Encoding: chunked\r\n", "1\r\nx\r\n0\r\n\r\n")), 411);
  EXPECT_EQ(status_of(post("Content-Length: 3\r\nTransfer-Encoding: chunked\r\n", "0\r\n\r\n")),
            411);
  EXPECT_EQ(status_of(post("Transfer-Encoding: chunked\r\nContent-Length: 3\r\n", "0\r\n\r\n")),
            411);
  EXPECT_EQ(status_of(post("Transfer-Encoding: identity\r\n", "")), 411);
  EXPECT_EQ(status_of(post("Content-Length: 3\r\nContent-Length: 4\r\n", "abcd")), 400);
  EXPECT_EQ(status_of(post("Content-Length: 3\r\nContent-Length: 3\r\n", "abc")), 0);
  for (const char* bad : {"+3", "-3", "3 3", "3,3", "0x3", "", "1234567890123456789", "3.0"})
    EXPECT_EQ(status_of(post(std::string("Content-Length: ") + bad + "\r\n", "abc")), 400) << bad;
  EXPECT_EQ(status_of(post("Content-Length: 65537\r\n", "")), 413);
  EXPECT_EQ(status_of(post("Content-Length: 999999999999999999\r\n", "")), 413);
  // A name with a blank before its colon is no Content-Length, nor anything else.
  EXPECT_EQ(status_of(post("Content-Length : 3\r\n", "abc")), 400);
}

TEST(HttpRequest, FoldedLinesAndControlBytesAreRefused) {
  EXPECT_EQ(status_of(get("Host: 127.0.0.1\r\nX-A: a\r\n b\r\n")), 400);
  EXPECT_EQ(status_of(get("Host: 127.0.0.1\r\nX-A: a\r\n\tb\r\n")), 400);
  EXPECT_EQ(status_of("GET / HTTP/1.1\r\n Host: 127.0.0.1\r\n\r\n"), 400);
  for (const char c : {'\r', '\0', '\x01', '\x1f', '\x7f'}) {
    std::string value = "a";
    value += c;
    value += "b";
    EXPECT_EQ(status_of(get("Host: 127.0.0.1\r\nX-A: " + value + "\r\n")), 400) << int(c);
    EXPECT_EQ(status_of(get("Host: 127.0.0.1\r\n", "/a" + std::string(1, c) + "b")), 400);
  }
  // A bare CR is no line end: the request line runs on and is refused.
  EXPECT_EQ(status_of("GET / HTTP/1.1\rHost: 127.0.0.1\r\n\r\n"), 400);
  EXPECT_EQ(status_of(get("Host: 127.0.0.1\r\nX-A: a\rContent-Length: 5\r\n")), 400);
}

TEST(HttpRequest, TheHostIsThereExactlyOnce) {
  EXPECT_EQ(status_of(get("")), 400);
  EXPECT_EQ(status_of(get("Host: 127.0.0.1\r\nHost: evil.example\r\n")), 400);
  EXPECT_EQ(status_of(get("HOST: 127.0.0.1\r\n")), 0);
  EXPECT_EQ(status_of("GET / HTTP/1.0\r\n\r\n"), 400);
}

TEST(HttpRequest, TheRequestLineIsMethodPathVersion) {
  EXPECT_EQ(status_of("GET http://evil.example/ HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"), 400);
  EXPECT_EQ(status_of("GET * HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"), 400);
  EXPECT_EQ(status_of("GET  / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"), 400);
  EXPECT_EQ(status_of("GET / HTTP/1.1 \r\nHost: 127.0.0.1\r\n\r\n"), 400);
  EXPECT_EQ(status_of("G(T / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"), 400);
  EXPECT_EQ(status_of("GET / HTTP/2.0\r\nHost: 127.0.0.1\r\n\r\n"), 505);
  EXPECT_EQ(status_of("GET / HTTP/1.1\r\r\nHost: 127.0.0.1\r\n\r\n"), 400);
  EXPECT_EQ(status_of("GET / HTTP/1.1\nHost: 127.0.0.1\n\n"), 0);
  // Blank lines before the request line are skipped; a line of CRs is not blank.
  EXPECT_EQ(status_of("\r\n\n\r\n" + get()), 0);
  const ParsedRequest p = parse_request("\r\r\r\nGET / HTTP/1.1\r\nHost: x\r\n\r\n", kLimits);
  ASSERT_EQ(p.step, Step::kRefused);
  EXPECT_EQ(p.refusal.why, "a request line is METHOD /path HTTP/1.1");
  EXPECT_EQ(status_of("\r\r\r\n\r\n"), 400);
  EXPECT_EQ(status_of("\r\n\r\r\n\r\n\r\n\r\n"), 400);
}

TEST(HttpRequest, TheLimitsAreThoseOfHttpLimits) {
  const std::string line_head = "GET /";
  const std::string line_tail = " HTTP/1.1";
  const auto line_of = [&](std::size_t n) {  // a request line of n bytes with its CR
    return line_head + std::string(n - 1 - line_head.size() - line_tail.size(), 'a') + line_tail +
           "\r\nHost: 127.0.0.1\r\n\r\n";
  };
  EXPECT_EQ(status_of(line_of(kLimits.max_request_line_bytes)), 0);
  EXPECT_EQ(status_of(line_of(kLimits.max_request_line_bytes + 1)), 414);
  EXPECT_EQ(status_of(std::string(kLimits.max_request_line_bytes + 1, '\n')), 414);
  std::string fields = "Host: 127.0.0.1\r\n";
  for (std::size_t k = 1; k < kLimits.max_header_fields; ++k) fields += "X-A: b\r\n";
  EXPECT_EQ(status_of(get(fields)), 0);
  EXPECT_EQ(status_of(get(fields + "X-A: b\r\n")), 431);
  const std::size_t room = kLimits.max_header_bytes - std::string("Host: 1\r\nX: \r\n\r\n").size();
  EXPECT_EQ(status_of(get("Host: 1\r\nX: " + std::string(room, 'v') + "\r\n")), 0);
  EXPECT_EQ(status_of(get("Host: 1\r\nX: " + std::string(room + 1, 'v') + "\r\n")), 431);
  // Bytes that never make a request within the limits are refused once the limits are passed.
  EXPECT_EQ(status_of("GET / HTTP/1.1\r\nX: " + std::string(kLimits.max_request_bytes(), 'v')),
            431);
}

TEST(HttpRequest, PipelinedRequestsFollowOneAnother) {
  std::mt19937 rng(7);
  for (int round = 0; round < 200; ++round) {
    std::vector<std::string> bodies;
    std::string bytes;
    const int n = 1 + static_cast<int>(rng() % 6);
    for (int k = 0; k < n; ++k) {
      bodies.emplace_back(rng() % 40, static_cast<char>('a' + k));
      bytes += rng() % 2 ? get()
                         : post("Content-Length: " + std::to_string(bodies.back().size()) + "\r\n",
                                bodies.back());
    }
    std::string_view rest = bytes;
    int seen = 0;
    while (!rest.empty()) {
      const ParsedRequest p = parse_request(rest, kLimits);
      ASSERT_EQ(p.step, Step::kWhole) << bytes;
      ASSERT_GT(p.size, 0U);
      if (p.request.method == "POST") {
        EXPECT_EQ(p.request.body, bodies[seen]);
      }
      rest.remove_prefix(p.size);
      ++seen;
    }
    EXPECT_EQ(seen, n);
  }
}

// Whatever the pieces, the reader decides as it does on the whole (the fuzzer checks the same
// over its inputs: tests/fuzz/fuzz_http_request.cpp).
TEST(HttpRequest, PiecesOfAnySizeReadAsTheWhole) {
  std::mt19937 rng(11);
  const std::vector<std::string> requests = {
      get(),
      post("Content-Length: 6\r\n", "axis=1"),
      get("Host: a\r\nX-A: b\r\n b\r\n"),
      post("Transfer-Encoding: chunked\r\n", "0\r\n\r\n"),
      "\r\n\r\n" + get(),
      get("Host: 1\r\nX: " + std::string(kLimits.max_header_bytes, 'v') + "\r\n"),
      "GET /" + std::string(kLimits.max_request_line_bytes, 'a') + " HTTP/1.1\r\n\r\n",
      "GET / HTTP/1.1\r\n" + std::string(300, 'x') + "\r\n"};
  for (const std::string& bytes : requests) {
    const ParsedRequest whole = parse_request(bytes, kLimits);
    for (int round = 0; round < 100; ++round) {
      std::vector<std::size_t> cuts(rng() % 8);
      for (std::size_t& c : cuts) c = rng() % (bytes.size() + 1);
      expect_same(read_in_pieces(bytes, cuts), whole, bytes.substr(0, 80));
    }
  }
}

TEST(HttpRequest, ParametersArePercentDecoded) {
  HttpRequest r;
  r.query = "a=1&b=x%41y+z&axis=%00%ff&c&axis=2&%61xis2=3&bad=%4&bad2=%zz";
  EXPECT_EQ(r.param("a"), "1");
  EXPECT_EQ(r.param("b"), "xAy z");
  EXPECT_EQ(r.param("axis"), std::string("\0\xff", 2));  // the first of that name
  EXPECT_EQ(r.param("c"), "");
  EXPECT_EQ(r.param("axis2"), "3");
  EXPECT_EQ(r.param("bad"), "%4");
  EXPECT_EQ(r.param("bad2"), "%zz");
  EXPECT_EQ(r.param("none"), std::nullopt);
  r.query.clear();
  r.body = "axis=4";
  EXPECT_EQ(r.param("axis"), std::nullopt);  // a body without the form's type is not read
  r.headers.emplace_back("content-type", "Application/X-WWW-Form-Urlencoded; charset=utf-8");
  EXPECT_EQ(r.param("axis"), "4");
}

TEST(HttpRequest, KeepAliveAsTheVersionAndConnectionSay) {
  const auto keep = [](const std::string& version, const std::string& connection) {
    HttpRequest r;
    r.version = version;
    if (!connection.empty()) r.headers.emplace_back("connection", connection);
    return r.keep_alive();
  };
  EXPECT_TRUE(keep("HTTP/1.1", ""));
  EXPECT_FALSE(keep("HTTP/1.1", "Close"));
  EXPECT_FALSE(keep("HTTP/1.1", "keep-alive, close"));
  EXPECT_FALSE(keep("HTTP/1.0", ""));
  EXPECT_TRUE(keep("HTTP/1.0", "Keep-Alive"));
}

// ---- the Host header and the access rules ------------------------------------------------------

TEST(HostName, APortIsANumberUpTo65535) {
  std::mt19937 rng(80);
  std::string name;
  for (int k = 0; k < 2000; ++k) {
    const unsigned port = rng() % 100000;
    const std::string p = std::to_string(port);
    EXPECT_EQ(idm::web::host_name("localhost:" + p, name), port <= 65535) << p;
    EXPECT_EQ(idm::web::host_name("[::1]:" + p, name), port <= 65535) << p;
  }
  for (const char* bad : {"localhost:", "localhost:-1", "localhost:+80", "localhost:080a",
                          "localhost:123456", "localhost:80:80", "[::1]:", "[::1]80"})
    EXPECT_FALSE(idm::web::host_name(bad, name)) << bad;
}

TEST(HostName, BracketsHoldAnIPv6AddressOnly) {
  std::string name;
  for (const char* good : {"[::1]", "[FE80::1]:8080", "[::ffff:127.0.0.1]", "[::]"}) {
    EXPECT_TRUE(idm::web::host_name(good, name)) << good;
    EXPECT_EQ(name.front(), '[');
  }
  for (const char* bad :
       {"[]", "[::1", "::1", "[[::1]]", "[::1]]", "[lab-pc]", "[::1%25eth0]", "a]b", "a[b", "lab]",
        "[::1]x", "user@localhost", "localhost/x", "local host", "", ":80"})
    EXPECT_FALSE(idm::web::host_name(bad, name)) << bad;
  EXPECT_TRUE(idm::web::host_name("LocalHost.:80", name));
  EXPECT_EQ(name, "localhost");
}

TEST(HostPolicy, LoopbackNamesAndThoseListed) {
  idm::web::HostPolicy hosts;
  ASSERT_TRUE(hosts.allow("lab-pc"));
  ASSERT_TRUE(hosts.allow("fe80::1"));
  ASSERT_TRUE(hosts.allow("0.0.0.0"));
  EXPECT_FALSE(hosts.allow("fe80::1%eth0"));
  for (const char* yes :
       {"localhost", "LOCALHOST:1", "localhost.", "127.0.0.1", "127.255.0.9:80", "[::1]:8080",
        "lab-pc", "LAB-PC.:9", "[fe80::1]", "[FE80::1]:80", "0.0.0.0:8080"})
    EXPECT_TRUE(hosts.allows(yes)) << yes;
  for (const char* no : {"evil.example", "127.0.0.1.evil.example", "127.1", "127.0.0.256",
                         "localhost..", "lab-pc.evil", "[::2]", "[0:0:0:0:0:0:0:1]:80",
                         "user@localhost", "localhost:99999", "fe80::1", ""})
    EXPECT_FALSE(hosts.allows(no)) << no;
}

namespace {

HttpRequest request(const std::string& method, const std::string& path,
                    const idm::web::HeaderList& extra = {}) {
  HttpRequest r;
  r.method = method;
  r.path = path;
  r.version = "HTTP/1.1";
  r.headers.emplace_back("host", "127.0.0.1:8080");
  r.headers.insert(r.headers.end(), extra.begin(), extra.end());
  return r;
}

int decision(const AccessRules& rules, const HttpRequest& r) {
  const auto d = idm::web::deny(rules, r);
  return d ? d->status : 0;
}

}  // namespace

TEST(Access, ReadsControlTheHeaderAndTheToken) {
  AccessRules read_only;
  EXPECT_EQ(decision(read_only, request("GET", "/")), 0);
  EXPECT_EQ(decision(read_only, request("HEAD", "/metrics")), 0);
  EXPECT_EQ(decision(read_only, request("POST", "/api/stop", {{"x-idm-control", "1"}})), 405);
  EXPECT_EQ(decision(read_only, request("get", "/")), 405);
  HttpRequest foreign = request("GET", "/");
  foreign.headers[0].second = "evil.example:8080";
  EXPECT_EQ(decision(read_only, foreign), 403);

  AccessRules control;
  control.control = true;
  EXPECT_EQ(decision(control, request("POST", "/api/stop")), 403);
  EXPECT_EQ(decision(control, request("POST", "/api/stop", {{"x-idm-control", "1"}})), 0);
  EXPECT_EQ(decision(control, request("POST", "/api/stop/", {{"x-idm-control", "1"}})), 405);
  EXPECT_EQ(decision(control, request("PUT", "/api/stop", {{"x-idm-control", "1"}})), 405);
  // Jogs and the speed limit are control requests too, under the same rules.
  for (const char* path : {"/api/jog", "/api/velocity"}) {
    EXPECT_EQ(decision(read_only, request("POST", path, {{"x-idm-control", "1"}})), 405) << path;
    EXPECT_EQ(decision(control, request("POST", path)), 403) << path;
    EXPECT_EQ(decision(control, request("POST", path, {{"x-idm-control", "1"}})), 0) << path;
    EXPECT_EQ(decision(control, request("GET", path)), 0) << path;  // a GET: 404 from the routes
    HttpRequest elsewhere = request("POST", path, {{"x-idm-control", "1"}});
    elsewhere.headers[0].second = "evil.example";
    EXPECT_EQ(decision(control, elsewhere), 403) << path;
  }
  control.token = "0123456789abcdef0123";
  const idm::web::HeaderList mark = {{"x-idm-control", "1"}};
  EXPECT_EQ(decision(control, request("POST", "/api/move", mark)), 401);
  std::mt19937 rng(401);
  for (int k = 0; k < 500; ++k) {  // wrong tokens: a byte changed, cut, or longer
    std::string wrong = control.token;
    if (k % 3 == 0) wrong[rng() % wrong.size()] ^= static_cast<char>(1 + rng() % 127);
    if (k % 3 == 1) wrong.resize(rng() % wrong.size());
    if (k % 3 == 2) wrong += static_cast<char>('!' + rng() % 90);
    EXPECT_EQ(
        decision(control, request("POST", "/api/move",
                                  {{"x-idm-control", "1"}, {"authorization", "Bearer " + wrong}})),
        401)
        << wrong;
  }
  EXPECT_EQ(decision(control, request("POST", "/api/move",
                                      {{"x-idm-control", "1"},
                                       {"authorization", "Bearer " + control.token}})),
            0);
  EXPECT_EQ(decision(control, request("GET", "/api/state")), 0);
  for (const char* path : {"/api/jog", "/api/velocity"}) {
    EXPECT_EQ(decision(control, request("POST", path, mark)), 401) << path;
    EXPECT_EQ(decision(control, request("POST", path,
                                        {{"x-idm-control", "1"},
                                         {"authorization", "Bearer " + control.token}})),
              0)
        << path;
  }
}
