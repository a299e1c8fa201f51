// idm-web's HTTP/1.1 request reader: a connection's bytes, as they come, into a whole request
// (method, target, fields, body) or a refusal (a status and why, in words), within HttpLimits. No
// sockets: the server (http_server.h), the unit tests and the fuzzer run the same code.
#pragma once

#include <cstddef>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace idm::web {

using HeaderList = std::vector<std::pair<std::string, std::string>>;

struct HttpRequest {
  std::string method;   // "GET", as sent
  std::string target;   // "/api/regions?axis=1", as sent
  std::string path;     // "/api/regions"
  std::string query;    // "axis=1"
  std::string version;  // "HTTP/1.1" or "HTTP/1.0"
  HeaderList headers;   // names in lower case, values trimmed, in the order sent
  std::string body;
  // The first header of that name (lower case), nullptr when there is none.
  const std::string* header(std::string_view name) const;
  std::size_t header_count(std::string_view name) const;
  // A parameter of the query string, or of a form body (application/x-www-form-urlencoded),
  // percent-decoded; the first of that name, nullopt when there is none.
  std::optional<std::string> param(std::string_view name) const;
  // The client asks to keep the connection (HTTP/1.1 without "Connection: close", HTTP/1.0 with
  // "Connection: keep-alive").
  bool keep_alive() const;
};

struct HttpLimits {
  std::size_t max_connections =
      128;  // open at once; more: 503 (an idle keep-alive one is closed first)
  std::size_t max_request_line_bytes = 8192;  // 414 past it
  std::size_t max_header_bytes = 16384;       // the header fields, without the request line: 431
  std::size_t max_header_fields = 100;        // 431 past it
  std::size_t max_body_bytes = 65536;         // 413 past it
  double request_timeout_s = 5;  // from a request's first byte to its last: 408 past it
  double idle_timeout_s = 5;     // a kept-alive connection with no request: closed
  double write_timeout_s = 5;    // a reply not taken by the client in that time: closed
  // Replies waiting for their clients to take them, all connections together: past it a reply
  // that does not fit its socket at once is dropped (its connection closed).
  std::size_t max_pending_reply_bytes = std::size_t{64} * 1024 * 1024;
  std::size_t max_requests_per_connection = 1000;
  int workers = 4;  // the handler's threads, besides the one for urgent (control) requests

  // The most bytes a request at every limit takes, with its line ends: a connection never holds
  // more unread.
  std::size_t max_request_bytes() const {
    return max_request_line_bytes + max_header_bytes + max_body_bytes + 64;
  }
};

// A request the server refuses itself: the status (400, 408, 411, 413, 414, 431, 505) and why.
struct Refusal {
  int status = 0;
  std::string why;
};

// Reads one request from the front of a connection's bytes. read() is given all the bytes
// received so far from the request's first (the same prefix each time, longer), looks only at
// what it has not seen, and says whether the request is whole, still coming, or refused.
class RequestReader {
 public:
  enum class Step { kMore, kWhole, kRefused };

  explicit RequestReader(const HttpLimits& limits) : limits_(limits) {}
  Step read(std::string_view in);
  Step step() const { return step_; }
  // Once kWhole: the request, and its size in bytes (head and body: the next request starts
  // there).
  const HttpRequest& request() const { return request_; }
  HttpRequest& request() { return request_; }
  std::size_t size() const { return step_ == Step::kWhole ? head_end_ + body_ : 0; }
  // Once kRefused: the status and why.
  const Refusal& refusal() const { return refusal_; }

 private:
  Step refuse(int status, std::string why);
  Step scan_head(std::string_view in);
  Step parse_head(std::string_view in);
  Step parse_fields(std::string_view in);
  Step body_length();

  static constexpr std::size_t kNone = std::string_view::npos;
  HttpLimits limits_;
  Step step_ = Step::kMore;
  HttpRequest request_;
  Refusal refusal_;
  // The head as scanned so far: up to scanned_; the current line starts at line_start_; the
  // request line runs from request_line_ to its '\n' at line_end_ (kNone: not yet); fields_
  // header lines so far; head_end_ past the blank line once it came, then body_ bytes.
  std::size_t scanned_ = 0, line_start_ = 0, request_line_ = kNone, line_end_ = kNone;
  std::size_t fields_ = 0, head_end_ = kNone, body_ = 0;
};

// The first request of `bytes` read at once (what RequestReader gives for all of them).
struct ParsedRequest {
  RequestReader::Step step = RequestReader::Step::kMore;
  HttpRequest request;   // kWhole
  std::size_t size = 0;  // kWhole: its bytes
  Refusal refusal;       // kRefused
};
ParsedRequest parse_request(std::string_view bytes, const HttpLimits& limits);

// "%41b+c" -> "Ab c" (a plus as a blank, as forms encode it); a '%' without two hex digits is kept.
std::string percent_decode(std::string_view text);

}  // namespace idm::web
