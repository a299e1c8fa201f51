// idm-web's request reader and access rules (web/http_request.h, web/access.h): the bytes a
// client sends on one connection, read as the server reads them (RequestReader, request after
// request), and the decision on each whole request.
//
// Input: byte 0 picks where the bytes are cut into pieces (as they would arrive); the rest is what
// the client sends.
//
// Invariants:
//  * the reader decides the same on the bytes in pieces as on them at once (the refusal's status
//    and words, the request's fields, body and size);
//  * a refusal is 400, 411, 413, 414, 431 or 505 and says why; more is waited for only below the
//    limits' sum (max_request_bytes); all of it with the server's limits and with small ones that
//    short inputs reach;
//  * a whole request: a token for a method, a target of printable ASCII starting with '/' that is
//    its path and query, HTTP/1.0 or 1.1, header names in lower case, values without control
//    bytes or blanks at their ends, at most max_header_fields of them, one Host, no
//    Transfer-Encoding, a body of its Content-Length within max_body_bytes, no more bytes than
//    were sent; written again as a request and read back, the same request;
//  * the requests after it (pipelined) are read from where it ends, each by a fresh reader;
//  * the access rules let a request through only with an allowed Host name (a loopback one or one
//    listed), by GET or HEAD, or as control with --control, X-Idm-Control: 1 and the token; a
//    denial is 401, 403 or 405; a Host name is allowed whatever its case; a name the policy took
//    (--allow-host) is allowed as a Host; same_secret is string equality.
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <string_view>
#include <vector>

#include "web/access.h"
#include "web/http_request.h"

namespace {

using idm::web::HttpLimits;
using idm::web::HttpRequest;
using idm::web::ParsedRequest;
using idm::web::RequestReader;
using Step = RequestReader::Step;

[[noreturn]] void fail(const char* what, std::string_view input) {
  std::fprintf(stderr, "fuzz_http_request: %s: '%.*s'\n", what,
               static_cast<int>(std::min<std::size_t>(input.size(), 400)), input.data());
  std::abort();
}

// The server's limits, and small ones that short inputs reach.
const HttpLimits kLimits;
const HttpLimits kSmall = [] {
  HttpLimits l;
  l.max_request_line_bytes = 40;
  l.max_header_bytes = 120;
  l.max_header_fields = 4;
  l.max_body_bytes = 16;
  return l;
}();
constexpr std::string_view kToken = "0123456789abcdef0123";

// The reader given growing prefixes of `bytes`, cut where a generator seeded by `seed` says.
ParsedRequest read_in_pieces(std::string_view bytes, std::uint8_t seed, const HttpLimits& limits) {
  RequestReader reader(limits);
  std::uint32_t state = 0x9e3779b9U ^ seed;
  std::size_t cut = 0;
  Step step = Step::kMore;
  while (step == Step::kMore && cut < bytes.size()) {
    state ^= state << 13;
    state ^= state >> 17;
    state ^= state << 5;
    cut = std::min(bytes.size(), cut + 1 + (seed == 0 ? bytes.size() : state % 64));
    step = reader.read(bytes.substr(0, cut));
  }
  if (bytes.empty()) step = reader.read(bytes);
  ParsedRequest out;
  out.step = step;
  if (step == Step::kWhole) {
    out.request = reader.request();
    out.size = reader.size();
  }
  if (step == Step::kRefused) out.refusal = reader.refusal();
  return out;
}

bool same_request(const HttpRequest& a, const HttpRequest& b) {
  return a.method == b.method && a.target == b.target && a.path == b.path && a.query == b.query &&
         a.version == b.version && a.headers == b.headers && a.body == b.body;
}

bool control_byte(char c) {
  const auto u = static_cast<unsigned char>(c);
  return (u < 0x20 && c != '\t') || u == 0x7f;
}

void check_fields(const HttpRequest& r, std::string_view in, const HttpLimits& limits) {
  const bool printable_target = !r.target.empty() && r.target[0] == '/' &&
                                std::all_of(r.target.begin(), r.target.end(), [](char c) {
                                  const auto u = static_cast<unsigned char>(c);
                                  return u > 0x20 && u < 0x7f;
                                });
  if (r.method.empty() || r.method.size() > 32 || !printable_target)
    fail("a method or target out of its promises", in);
  const bool has_query = r.target.find('?') != std::string::npos;
  if (r.target != r.path + (has_query ? "?" + r.query : std::string()))
    fail("a target that is not its path and query", in);
  if (r.version != "HTTP/1.1" && r.version != "HTTP/1.0") fail("a version not 1.0 or 1.1", in);
  if (r.headers.size() > limits.max_header_fields) fail("more fields than the limit", in);
  for (const auto& [name, value] : r.headers) {
    if (name.empty() || std::any_of(name.begin(), name.end(), [](char c) {
          return (c >= 'A' && c <= 'Z') || static_cast<unsigned char>(c) <= 0x20 || c == ':';
        }))
      fail("a header name not a lower-case token", in);
    if (std::any_of(value.begin(), value.end(), control_byte)) fail("a control byte kept", in);
    if (!value.empty() && (value.front() == ' ' || value.front() == '\t' || value.back() == ' ' ||
                           value.back() == '\t'))
      fail("a value not trimmed", in);
  }
  if (r.header_count("host") != 1 || r.header("transfer-encoding"))
    fail("a request without one Host, or with chunks", in);
  const std::string* length = r.header("content-length");
  if (r.body.size() != (length ? std::stoull(*length) : 0) || r.body.size() > limits.max_body_bytes)
    fail("a body not of its Content-Length", in);
}

// The request written again (canonically) and read back: the same request.
void check_round_trip(const HttpRequest& r, std::string_view in, const HttpLimits& limits) {
  std::string again = r.method + " " + r.target + " " + r.version + "\r\n";
  for (const auto& [name, value] : r.headers) again += name + ": " + value + "\r\n";
  again += "\r\n" + r.body;
  HttpLimits roomy = limits;  // the canonical form may add a CR or a blank per line
  roomy.max_request_line_bytes = 2 * limits.max_request_line_bytes + 2;
  roomy.max_header_bytes = 4 * limits.max_header_bytes;
  const ParsedRequest back = idm::web::parse_request(again, roomy);
  if (back.step != Step::kWhole || back.size != again.size() || !same_request(back.request, r))
    fail("a request written again reads differently", in);
}

// same_secret against string equality over the request's header values: halves of each, and each
// against the token.
bool auth_secret_differs(const HttpRequest& r) {
  for (const auto& [name, value] : r.headers) {
    const std::string_view v = value;
    const std::string_view a = v.substr(0, v.size() / 2), b = v.substr(v.size() / 2);
    if (idm::web::same_secret(a, b) != (a == b)) return true;
    if (idm::web::same_secret(v, kToken) != (v == kToken)) return true;
  }
  return false;
}

// The access rules on a whole request, against what they promise.
void check_access(const HttpRequest& r, std::string_view in) {
  idm::web::AccessRules rules;
  rules.hosts.allow("lab-pc");
  rules.hosts.allow("fe80::1");
  rules.hosts.allow("0.0.0.0");
  for (int variant = 0; variant < 3; ++variant) {
    rules.control = variant > 0;
    rules.token = variant == 2 ? std::string(kToken) : std::string();
    const auto denial = idm::web::deny(rules, r);
    const std::string& host = *r.header("host");
    std::string name;
    const bool host_ok = idm::web::host_name(host, name) &&
                         (idm::web::loopback_name(name) ||
                          std::find(rules.hosts.listed().begin(), rules.hosts.listed().end(),
                                    name) != rules.hosts.listed().end());
    const bool read = r.method == "GET" || r.method == "HEAD";
    const std::string* mark = r.header("x-idm-control");
    const std::string* auth = r.header("authorization");
    const bool control_ok = rules.control && idm::web::is_control(r) && mark && *mark == "1" &&
                            (rules.token.empty() || (auth && *auth == "Bearer " + rules.token));
    if (denial.has_value() == (host_ok && (read || control_ok)))
      fail("an access decision against the rules", in);
    if (denial && denial->status != 401 && denial->status != 403 && denial->status != 405)
      fail("a denial of another status", in);
    std::string upper = host;
    for (char& c : upper)
      if (c >= 'a' && c <= 'z') c = static_cast<char>(c - 'a' + 'A');
    if (rules.hosts.allows(upper) != rules.hosts.allows(host))
      fail("a Host name's case counts", in);
  }
  // A name taken as --allow-host takes it is allowed as a Host (brackets as a Host carries them).
  idm::web::HostPolicy policy;
  const std::string& host = *r.header("host");
  const bool bare_v6 = std::count(host.begin(), host.end(), ':') > 1 && host.front() != '[';
  if (policy.allow(host) && !bare_v6 && !policy.allows(host))
    fail("a name allowed is not allowed as a Host", in);
  if (auth_secret_differs(r)) fail("same_secret is not equality", in);
}

// The requests of `bytes` one after the other, with `limits`.
void check_connection(std::string_view rest, std::uint8_t seed, const HttpLimits& limits) {
  for (int k = 0; k < 8; ++k) {  // request after request, as on a kept-alive connection
    const ParsedRequest whole = idm::web::parse_request(rest, limits);
    const ParsedRequest pieces = read_in_pieces(rest, seed, limits);
    if (whole.step != pieces.step || whole.size != pieces.size ||
        whole.refusal.status != pieces.refusal.status || whole.refusal.why != pieces.refusal.why ||
        !same_request(whole.request, pieces.request))
      fail("the bytes in pieces read differently", rest);
    if (whole.step == Step::kRefused) {
      const int s = whole.refusal.status;
      if ((s != 400 && s != 411 && s != 413 && s != 414 && s != 431 && s != 505) ||
          whole.refusal.why.empty())
        fail("a refusal out of its promises", rest);
      return;
    }
    if (whole.step == Step::kMore) {
      if (rest.size() >= limits.max_request_bytes()) fail("waiting past the limits", rest);
      return;
    }
    if (whole.size == 0 || whole.size > rest.size() || whole.size > limits.max_request_bytes())
      fail("a request's size out of its bytes", rest);
    check_fields(whole.request, rest, limits);
    check_round_trip(whole.request, rest, limits);
    check_access(whole.request, rest);
    for (const char* name : {"axis", "target", ""}) {
      const auto v = whole.request.param(name);
      if (v && v->size() > whole.request.query.size() + whole.request.body.size())
        fail("a parameter longer than the query and body", rest);
    }
    (void)whole.request.keep_alive();
    rest.remove_prefix(whole.size);
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size == 0) return 0;
  const std::string_view bytes(reinterpret_cast<const char*>(data) + 1, size - 1);
  check_connection(bytes, data[0], kLimits);
  check_connection(bytes, data[0], kSmall);
  return 0;
}
