// idm-web's HTTP server (web/http_server.h) on real sockets: a client that does not read its
// reply holds no worker, and the replies waiting for their clients stay within their budget.
// Waits are bounded (a request answered within 20 s), never timed.
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <functional>
#include <string>
#include <thread>

#include "web/http_server.h"

using idm::web::HttpLimits;
using idm::web::HttpRequest;
using idm::web::HttpResponse;
using idm::web::HttpServer;

namespace {

// A server on 127.0.0.1 (a free port) running in a thread of its own while it lives.
class Running {
 public:
  Running(const HttpLimits& limits, HttpServer::Handler handler)
      : server_(limits, std::move(handler), nullptr, {}) {
    server_.bind("127.0.0.1", 0);
    thread_ = std::thread([this] { server_.run(); });
  }
  ~Running() {
    server_.stop();
    thread_.join();
  }
  Running(const Running&) = delete;
  Running& operator=(const Running&) = delete;
  HttpServer& server() { return server_; }

 private:
  HttpServer server_;
  std::thread thread_;
};

// A client connection; receive_buffer > 0 makes its socket's buffer that small (a slow reader).
int connect_to(int port, int receive_buffer = 0) {
  const int fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (receive_buffer > 0)
    setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &receive_buffer, sizeof receive_buffer);
  timeval wait{20, 0};  // the bound of every wait below
  setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &wait, sizeof wait);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(static_cast<std::uint16_t>(port));
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  EXPECT_EQ(connect(fd, reinterpret_cast<const sockaddr*>(&a), sizeof a), 0);
  return fd;
}

void send_text(int fd, const std::string& text) {
  EXPECT_EQ(send(fd, text.data(), text.size(), MSG_NOSIGNAL), static_cast<ssize_t>(text.size()));
}

// Everything until the server closes, the bound passes or the connection fails.
std::string read_all(int fd) {
  std::string out;
  char buf[65536];
  for (;;) {
    const ssize_t n = recv(fd, buf, sizeof buf, 0);
    if (n <= 0) return out;
    out.append(buf, static_cast<std::size_t>(n));
  }
}

std::string request(const std::string& path) {
  return "GET " + path + " HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n";
}

HttpResponse reply(std::size_t bytes, char fill) {
  HttpResponse res;
  res.body.assign(bytes, fill);
  return res;
}

bool wait_until(const std::function<bool()>& done) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(20);
  while (!done()) {
    if (std::chrono::steady_clock::now() > end) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  return true;
}

constexpr std::size_t kMiB = std::size_t{1024} * 1024;

}  // namespace

// The old server wrote each reply from its worker, waiting up to the write timeout for a client
// that did not read: one such client per worker stopped every other request for that long.
TEST(HttpServer, AClientThatDoesNotReadHoldsNoWorker) {
  HttpLimits limits;
  limits.workers = 1;
  limits.write_timeout_s = 60;
  Running web(limits, [](const HttpRequest& r) {
    return r.path == "/big" ? reply(32 * kMiB, 'b') : reply(2, 'k');
  });
  const int slow = connect_to(web.server().port(), 4096);
  send_text(slow, request("/big"));
  ASSERT_TRUE(wait_until([&] { return web.server().requests() == 1; }));
  for (int k = 0; k < 3; ++k) {
    const int fd = connect_to(web.server().port());
    send_text(fd, request("/small"));
    const std::string got = read_all(fd);
    close(fd);
    EXPECT_EQ(got.rfind("HTTP/1.1 200 OK\r\n", 0), 0U) << got.substr(0, 80);
    EXPECT_EQ(got.substr(got.size() - 4), "\r\nkk");
  }
  // The slow client still gets all of its reply once it reads.
  const std::string big = read_all(slow);
  close(slow);
  EXPECT_EQ(big.size() - big.find("\r\n\r\n") - 4, 32 * kMiB);
}

// Replies waiting for their clients stay within max_pending_reply_bytes: one of two 24 MiB
// replies to clients that do not read waits, the other (that would pass 32 MiB) is dropped.
TEST(HttpServer, RepliesWaitingForTheirClientsStayWithinTheBudget) {
  HttpLimits limits;
  limits.max_pending_reply_bytes = 32 * kMiB;
  limits.write_timeout_s = 60;
  Running web(limits, [](const HttpRequest&) { return reply(24 * kMiB, 'p'); });
  const int a = connect_to(web.server().port(), 4096);
  const int b = connect_to(web.server().port(), 4096);
  send_text(a, request("/a"));
  send_text(b, request("/b"));
  ASSERT_TRUE(wait_until([&] { return web.server().requests() == 2; }));
  std::size_t whole = 0, cut = 0;
  for (const int fd : {a, b}) {
    const std::string got = read_all(fd);
    close(fd);
    const std::size_t body = got.size() - got.find("\r\n\r\n") - 4;
    (body == 24 * kMiB ? whole : cut) += 1;
  }
  EXPECT_EQ(whole, 1U);
  EXPECT_EQ(cut, 1U);
}
