// idm-web's HTTP/1.1 server: one thread reads every connection (epoll, non-blocking) until it
// holds a whole request, within size and time limits; only whole requests reach the handler, on
// a small pool of workers (control requests on a worker of their own). A client that sends
// slowly, or never finishes, holds a connection slot and nothing else (README.md here).
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <stdexcept>
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
};

struct HttpResponse {
  int status = 200;
  std::string content_type = "text/plain; charset=utf-8";
  std::string body;
  HeaderList headers;
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
  std::size_t max_requests_per_connection = 1000;
  int workers = 4;  // the handler's threads, besides the one for urgent (control) requests
};

// The listening socket could not be had (a taken port, an address not of this machine, ...).
struct BindError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Every address `host` resolves to for a listener is a loopback one (127.0.0.0/8, ::1); BindError
// when it does not resolve.
bool listens_on_loopback(const std::string& host);

class HttpServer {
 public:
  using Handler = std::function<HttpResponse(const HttpRequest&)>;
  // True for a request that must not wait behind others (STOP): served by its own worker.
  using Urgent = std::function<bool(const HttpRequest&)>;

  // default_headers go on every reply, the server's own refusals included.
  HttpServer(HttpLimits limits, Handler handler, Urgent urgent, HeaderList default_headers);
  ~HttpServer();
  HttpServer(const HttpServer&) = delete;
  HttpServer& operator=(const HttpServer&) = delete;

  // Binds host:port (port 0: a free one) for this process alone (SO_REUSEADDR for a quick
  // restart, never SO_REUSEPORT: a second server on a taken port is refused). BindError says
  // why it could not.
  void bind(const std::string& host, int port);
  int port() const;
  // The bound address is a loopback one (127.0.0.0/8, ::1 or ::ffff:127.x).
  bool loopback() const;
  // Serves until stop() (from any thread); false when the event loop failed.
  bool run();
  void stop();
  // HTTP connections open now (being read, answered or kept alive), and requests answered.
  std::uint64_t open_connections() const;
  std::uint64_t requests() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace idm::web
