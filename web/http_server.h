// idm-web's HTTP/1.1 server: one thread reads every connection (epoll, non-blocking) until it
// holds a whole request (http_request.h), within size and time limits; only whole requests reach
// the handler, on a small pool of workers (control requests on a worker of their own); the same
// thread writes the replies as the clients take them. A client that sends or reads slowly, or
// never finishes, holds a connection slot and nothing else (README.md here).
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <stdexcept>
#include <string>

#include "web/http_request.h"

namespace idm::web {

struct HttpResponse {
  int status = 200;
  std::string content_type = "text/plain; charset=utf-8";
  std::string body;
  HeaderList headers;
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
