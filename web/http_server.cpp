#include "web/http_server.h"

#include <arpa/inet.h>
#include <netdb.h>
#include <netinet/in.h>
#include <sys/epoll.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <sys/uio.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <deque>
#include <mutex>
#include <thread>
#include <unordered_map>
#include <vector>

namespace idm::web {

namespace {

using Clock = std::chrono::steady_clock;
constexpr std::size_t kNone = std::string::npos;
constexpr double kDrainS = 1;  // a refused client's bytes read for this long
constexpr std::size_t kMaxDrainBytes = std::size_t{1024} * 1024;  // ... or this many, then closed
constexpr std::size_t kReadChunk = 16384;

Clock::time_point after(double seconds) {
  return Clock::now() +
         std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(seconds));
}

const char* reason(int status) {
  switch (status) {
    case 200:
      return "OK";
    case 400:
      return "Bad Request";
    case 403:
      return "Forbidden";
    case 404:
      return "Not Found";
    case 405:
      return "Method Not Allowed";
    case 408:
      return "Request Timeout";
    case 411:
      return "Length Required";
    case 413:
      return "Content Too Large";
    case 414:
      return "URI Too Long";
    case 422:
      return "Unprocessable Content";
    case 431:
      return "Request Header Fields Too Large";
    case 500:
      return "Internal Server Error";
    case 501:
      return "Not Implemented";
    case 502:
      return "Bad Gateway";
    case 503:
      return "Service Unavailable";
    case 505:
      return "HTTP Version Not Supported";
    default:
      return status < 400 ? "OK" : "Error";
  }
}

std::string http_date() {
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&now, &tm);
  char buf[64];
  std::strftime(buf, sizeof buf, "%a, %d %b %Y %H:%M:%S GMT", &tm);
  return buf;
}

// The status line and header fields of a reply, with the blank line that ends them.
std::string reply_head(const HttpResponse& res, const HeaderList& defaults, bool keep_alive) {
  std::string out = "HTTP/1.1 " + std::to_string(res.status) + " " + reason(res.status) + "\r\n";
  out += "Date: " + http_date() + "\r\n";
  out += "Content-Type: " + res.content_type + "\r\n";
  out += "Content-Length: " + std::to_string(res.body.size()) + "\r\n";
  for (const auto& [name, value] : defaults) out += name + ": " + value + "\r\n";
  for (const auto& [name, value] : res.headers) out += name + ": " + value + "\r\n";
  out += keep_alive ? "Connection: keep-alive\r\n\r\n" : "Connection: close\r\n\r\n";
  return out;
}

// Idle: kept alive (or new), nothing of a request yet; Reading: a request coming; Busy: whole, with
// a worker; Writing: its reply waiting for the client to take it; Draining: refused, the client's
// further bytes read and dropped.
enum class Phase { Idle, Reading, Busy, Writing, Draining };

// One client connection. The event loop owns it; while Busy a worker alone touches it.
struct Connection {
  int fd = -1;
  std::string in;  // bytes received and not yet taken by a request
  Phase phase = Phase::Idle;
  Clock::time_point deadline{};  // of the phase (Idle, Reading, Writing, Draining)
  Clock::time_point since{};     // entered Idle: the oldest idle one makes room first
  std::size_t served = 0;
  bool peer_closed = false;  // the client shut its side: what is whole is answered, then closed
  RequestReader reader;      // the request at the front of `in`
  std::string reply_head, reply_body;  // the reply, while Writing
  std::size_t reply_sent = 0;          // ... and how much of head and body went
  bool close_after = false;            // the reply ends the connection
  std::size_t drained = 0;

  explicit Connection(const HttpLimits& limits) : reader(limits) {}

  std::size_t reply_left() const { return reply_head.size() + reply_body.size() - reply_sent; }

  void next_request(const HttpLimits& limits) {
    in.erase(0, reader.size());
    reader = RequestReader(limits);
    reply_head.clear();
    reply_body.clear();
    reply_body.shrink_to_fit();
    reply_sent = 0;
  }
};

enum class Sent { kAll, kPart, kFailed };

// Sends what the socket takes now of c's reply (head and body, without joining them).
Sent send_reply(Connection& c) {
  while (c.reply_left() > 0) {
    iovec iov[2];
    int n = 0;
    const std::size_t head = c.reply_head.size();
    if (c.reply_sent < head) iov[n++] = {c.reply_head.data() + c.reply_sent, head - c.reply_sent};
    const std::size_t from = c.reply_sent > head ? c.reply_sent - head : 0;
    if (from < c.reply_body.size())
      iov[n++] = {c.reply_body.data() + from, c.reply_body.size() - from};
    msghdr m{};
    m.msg_iov = iov;
    m.msg_iovlen = static_cast<std::size_t>(n);
    const ssize_t k = sendmsg(c.fd, &m, MSG_NOSIGNAL | MSG_DONTWAIT);
    if (k > 0) {
      c.reply_sent += static_cast<std::size_t>(k);
      continue;
    }
    if (k < 0 && errno == EINTR) continue;
    if (k < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) return Sent::kPart;
    return Sent::kFailed;
  }
  return Sent::kAll;
}

}  // namespace

// ---- the server ---------------------------------------------------------------------------------

struct HttpServer::Impl {
  HttpLimits limits;
  Handler handler;
  Urgent urgent;
  HeaderList defaults;
  int listen_fd = -1, epoll_fd = -1, wake_fd = -1;
  int bound_port = 0;
  bool bound_loopback = false;
  std::atomic<bool> stopping{false};
  std::atomic<std::uint64_t> open{0}, answered{0};
  std::unordered_map<int, std::unique_ptr<Connection>> connections;  // the loop's own
  std::size_t draining = 0;       // connections Draining (not counted in `open`)
  std::size_t pending_bytes = 0;  // of the replies Writing
  Clock::time_point accept_paused_until{};

  // A lane of workers: the urgent one (one thread) and the rest.
  struct Lane {
    std::mutex mutex;
    std::condition_variable ready;
    std::deque<Connection*> queue;
    bool stop = false;
    std::vector<std::thread> threads;
  };
  Lane urgent_lane, normal_lane;
  std::mutex returned_mutex;
  std::vector<Connection*> returned;  // answered by a worker, back to the loop

  Impl(HttpLimits l, Handler h, Urgent u, HeaderList d)
      : limits(l), handler(std::move(h)), urgent(std::move(u)), defaults(std::move(d)) {}

  ~Impl() {
    for (auto& [fd, c] : connections) close(fd);
    for (const int fd : {listen_fd, epoll_fd, wake_fd})
      if (fd >= 0) close(fd);
  }
  Impl(const Impl&) = delete;
  Impl& operator=(const Impl&) = delete;

  void wake() const {
    const std::uint64_t one = 1;
    if (write(wake_fd, &one, sizeof one) < 0 && errno != EAGAIN) std::perror("idm-web: eventfd");
  }

  bool watch(int fd, int op, std::uint32_t events = EPOLLIN | EPOLLRDHUP) const {
    epoll_event ev{};
    ev.events = events;
    ev.data.fd = fd;
    return epoll_ctl(epoll_fd, op, fd, &ev) == 0;
  }

  void bind_to(const std::string& host, int port);
  bool loop();
  void accept_all();
  void on_readable(Connection& c);
  void on_writable(Connection& c);
  void advance(Connection& c);
  void refuse(Connection& c, const Refusal& r);
  void close_connection(int fd);
  void take_returned();
  void reply_sent(Connection& c);
  void expire();
  int wait_ms() const;
  Connection* evictable() const;
  void start_workers();
  void stop_workers();
  void work(Lane& lane);
  void serve(Connection& c) const;
};

namespace {

using AddressList = std::unique_ptr<addrinfo, void (*)(addrinfo*)>;

std::string shown_address(const std::string& host, int port) {
  return (host.find(':') != kNone ? "[" + host + "]" : host) + ":" + std::to_string(port);
}

// The addresses a listener on host:port would bind (the first is the one taken); BindError.
AddressList resolve_listener(const std::string& host, int port) {
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = AI_PASSIVE | AI_NUMERICSERV;
  addrinfo* found = nullptr;
  if (const int e = getaddrinfo(host.c_str(), std::to_string(port).c_str(), &hints, &found); e)
    throw BindError("cannot listen on " + shown_address(host, port) + ": " + gai_strerror(e));
  return AddressList(found, freeaddrinfo);
}

bool is_loopback_address(const sockaddr* a) {
  if (a->sa_family == AF_INET)
    return (ntohl(reinterpret_cast<const sockaddr_in*>(a)->sin_addr.s_addr) >> 24) == 127;
  if (a->sa_family != AF_INET6) return false;
  const in6_addr& ip = reinterpret_cast<const sockaddr_in6*>(a)->sin6_addr;
  return IN6_IS_ADDR_LOOPBACK(&ip) || (IN6_IS_ADDR_V4MAPPED(&ip) && ip.s6_addr[12] == 127);
}

}  // namespace

bool listens_on_loopback(const std::string& host) {
  const AddressList list = resolve_listener(host, 0);
  for (const addrinfo* a = list.get(); a; a = a->ai_next)
    if (!is_loopback_address(a->ai_addr)) return false;
  return true;
}

void HttpServer::Impl::bind_to(const std::string& host, int port) {
  const AddressList list = resolve_listener(host, port);
  const std::string where = shown_address(host, port);
  const int fd = socket(list->ai_family, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (fd < 0) throw BindError("cannot listen on " + where + ": socket: " + std::strerror(errno));
  listen_fd = fd;
  // SO_REUSEADDR lets a restarted server bind while old connections linger in TIME_WAIT; it never
  // lets two servers listen on one port (Linux). SO_REUSEPORT would, and is never set.
  const int yes = 1;
  setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &yes, sizeof yes);
  if (::bind(fd, list->ai_addr, list->ai_addrlen) != 0 || listen(fd, 64) != 0) {
    const int e = errno;
    throw BindError(
        "cannot listen on " + where + ": " + std::strerror(e) +
        (e == EADDRINUSE ? " (another idm-web, or another server, has that port)" : ""));
  }
  sockaddr_storage addr{};
  socklen_t len = sizeof addr;
  getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len);
  bound_loopback = is_loopback_address(reinterpret_cast<const sockaddr*>(&addr));
  bound_port = addr.ss_family == AF_INET
                   ? ntohs(reinterpret_cast<const sockaddr_in*>(&addr)->sin_port)
                   : ntohs(reinterpret_cast<const sockaddr_in6*>(&addr)->sin6_port);
}

void HttpServer::Impl::close_connection(int fd) {
  const auto it = connections.find(fd);
  if (it == connections.end()) return;
  const Connection& c = *it->second;
  if (c.phase == Phase::Draining)
    --draining;
  else
    --open;
  if (c.phase == Phase::Writing) pending_bytes -= c.reply_left();
  close(fd);  // also leaves the epoll set
  connections.erase(it);
}

// A refusal of the server itself: answered at once (it is short: the socket's buffer takes it),
// then the connection's further bytes are read and dropped for a moment before it is closed, so
// that the client reads the answer rather than a reset.
void HttpServer::Impl::refuse(Connection& c, const Refusal& r) {
  HttpResponse res;
  res.status = r.status;
  res.body = "HTTP " + std::to_string(r.status) + ": " + r.why + "\n";
  if (r.status == 503) res.headers.emplace_back("Retry-After", "1");
  const std::string out = reply_head(res, defaults, false) + res.body;
  ++answered;
  (void)!send(c.fd, out.data(), out.size(), MSG_NOSIGNAL | MSG_DONTWAIT);
  shutdown(c.fd, SHUT_WR);
  if (c.phase != Phase::Draining) {
    --open;
    ++draining;
  }
  c.phase = Phase::Draining;
  c.in.clear();
  c.in.shrink_to_fit();
  c.deadline = after(kDrainS);
}

// The oldest kept-alive connection with nothing of a request in it, to make room for a new one.
Connection* HttpServer::Impl::evictable() const {
  Connection* oldest = nullptr;
  for (const auto& [fd, c] : connections)
    if (c->phase == Phase::Idle && c->in.empty() && (!oldest || c->since < oldest->since))
      oldest = c.get();
  return oldest;
}

void HttpServer::Impl::accept_all() {
  for (;;) {
    const int fd = accept4(listen_fd, nullptr, nullptr, SOCK_NONBLOCK | SOCK_CLOEXEC);
    if (fd < 0) {
      if (errno == EINTR || errno == ECONNABORTED) continue;
      if (errno == EMFILE || errno == ENFILE || errno == ENOBUFS || errno == ENOMEM) {
        // Out of descriptors: stop accepting for a moment rather than spin on the listener.
        accept_paused_until = after(0.1);
        epoll_ctl(epoll_fd, EPOLL_CTL_DEL, listen_fd, nullptr);
      }
      return;
    }
    auto c = std::make_unique<Connection>(limits);
    c->fd = fd;
    c->since = Clock::now();
    c->deadline = after(limits.request_timeout_s);
    if (open >= limits.max_connections) {
      if (Connection* idle = evictable()) close_connection(idle->fd);
    }
    const bool full = open >= limits.max_connections;
    if (full && draining >= limits.max_connections) {
      close(fd);  // refusing costs a slot too: past twice the limit, just closed
      continue;
    }
    if (!watch(fd, EPOLL_CTL_ADD)) {
      close(fd);
      continue;
    }
    Connection& ref = *c;
    connections.emplace(fd, std::move(c));
    ++open;
    if (full)
      refuse(ref, {503, "too many connections (at most " + std::to_string(limits.max_connections) +
                            " at once); try again"});
  }
}

void HttpServer::Impl::on_readable(Connection& c) {
  char buf[kReadChunk];
  for (;;) {
    if (c.phase == Phase::Draining) {
      const ssize_t n = recv(c.fd, buf, sizeof buf, 0);
      if (n > 0 && (c.drained += static_cast<std::size_t>(n)) <= kMaxDrainBytes) continue;
      if (n < 0 && errno == EINTR) continue;
      if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) return;
      close_connection(c.fd);  // the client is done (or sent too much): closed
      return;
    }
    const std::size_t cap = limits.max_request_bytes();
    const std::size_t room = cap > c.in.size() ? std::min(cap - c.in.size(), sizeof buf) : 0;
    if (room == 0) break;
    const ssize_t n = recv(c.fd, buf, room, 0);
    if (n > 0) {
      if (c.phase == Phase::Idle) {
        c.phase = Phase::Reading;
        c.deadline = after(limits.request_timeout_s);
      }
      c.in.append(buf, static_cast<std::size_t>(n));
      continue;
    }
    if (n < 0 && errno == EINTR) continue;
    if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) break;
    c.peer_closed = true;  // EOF, or an error: what is whole is still answered
    break;
  }
  advance(c);
}

// A request whole in c.in goes to a worker; a bad one is refused; a closed client with nothing
// whole is closed.
void HttpServer::Impl::advance(Connection& c) {
  if (c.phase != Phase::Idle && c.phase != Phase::Reading) return;
  switch (c.reader.read(c.in)) {
    case RequestReader::Step::kRefused:
      return refuse(c, c.reader.refusal());
    case RequestReader::Step::kMore:
      if (c.peer_closed) close_connection(c.fd);
      return;
    case RequestReader::Step::kWhole:
      break;
  }
  c.phase = Phase::Busy;
  epoll_ctl(epoll_fd, EPOLL_CTL_DEL, c.fd, nullptr);
  Lane& lane = urgent && urgent(c.reader.request()) ? urgent_lane : normal_lane;
  {
    std::lock_guard<std::mutex> lock(lane.mutex);
    lane.queue.push_back(&c);
  }
  lane.ready.notify_one();
}

// Replies back from the workers: sent as far as their sockets take them now; the rest waits for
// room (Writing), within the write timeout and the budget of waiting replies.
void HttpServer::Impl::take_returned() {
  std::vector<Connection*> back;
  {
    std::lock_guard<std::mutex> lock(returned_mutex);
    back.swap(returned);
  }
  for (Connection* c : back) {
    const Sent sent = stopping ? Sent::kFailed : send_reply(*c);
    if (sent == Sent::kAll) {
      reply_sent(*c);
      continue;
    }
    const bool fits = pending_bytes + c->reply_left() <= limits.max_pending_reply_bytes;
    if (sent == Sent::kFailed || !fits || !watch(c->fd, EPOLL_CTL_ADD, EPOLLOUT)) {
      close_connection(c->fd);
      continue;
    }
    c->phase = Phase::Writing;
    c->deadline = after(limits.write_timeout_s);
    pending_bytes += c->reply_left();
  }
}

void HttpServer::Impl::on_writable(Connection& c) {
  const std::size_t left = c.reply_left();
  const Sent sent = send_reply(c);
  pending_bytes -= left - c.reply_left();
  if (sent == Sent::kFailed) return close_connection(c.fd);
  if (sent == Sent::kPart) return;
  epoll_ctl(epoll_fd, EPOLL_CTL_DEL, c.fd, nullptr);
  reply_sent(c);
}

// A reply all sent (the connection out of the epoll set): the connection ends, or waits for the
// next request, which may be in c.in already (pipelined).
void HttpServer::Impl::reply_sent(Connection& c) {
  c.phase = Phase::Idle;
  if (c.close_after) return close_connection(c.fd);
  c.next_request(limits);
  if (c.peer_closed && c.in.empty()) return close_connection(c.fd);
  c.since = Clock::now();
  c.deadline = after(limits.idle_timeout_s);
  if (!watch(c.fd, EPOLL_CTL_ADD)) return close_connection(c.fd);
  if (!c.in.empty()) {  // the next request came with the last one
    c.phase = Phase::Reading;
    c.deadline = after(limits.request_timeout_s);
    advance(c);
  }
}

// Connections past their phase's deadline: a request still coming is answered 408; an idle one,
// a reply not taken and a draining one are closed.
void HttpServer::Impl::expire() {
  const auto now = Clock::now();
  std::vector<int> late;
  for (const auto& [fd, c] : connections)
    if (c->phase != Phase::Busy && c->deadline <= now) late.push_back(fd);
  for (const int fd : late) {
    Connection& c = *connections.at(fd);
    if (c.phase == Phase::Reading)
      refuse(c, {408, "the request did not come whole within " +
                          std::to_string(static_cast<int>(limits.request_timeout_s)) + " s"});
    else
      close_connection(fd);
  }
  if (accept_paused_until != Clock::time_point{} && accept_paused_until <= now) {
    accept_paused_until = {};
    watch(listen_fd, EPOLL_CTL_ADD);
  }
}

int HttpServer::Impl::wait_ms() const {
  auto next = Clock::now() + std::chrono::seconds(1);
  for (const auto& [fd, c] : connections)
    if (c->phase != Phase::Busy) next = std::min(next, c->deadline);
  if (accept_paused_until != Clock::time_point{}) next = std::min(next, accept_paused_until);
  const auto ms =
      std::chrono::duration_cast<std::chrono::milliseconds>(next - Clock::now()).count() + 1;
  return static_cast<int>(std::clamp<long long>(ms, 0, 1000));
}

bool HttpServer::Impl::loop() {
  if (!watch(listen_fd, EPOLL_CTL_ADD) || !watch(wake_fd, EPOLL_CTL_ADD)) return false;
  epoll_event events[64];
  while (!stopping) {
    const int n = epoll_wait(epoll_fd, events, 64, wait_ms());
    if (n < 0 && errno != EINTR) {
      std::perror("idm-web: epoll_wait");
      return false;
    }
    for (int k = 0; k < n; ++k) {
      const int fd = events[k].data.fd;
      if (fd == listen_fd) {
        accept_all();
      } else if (fd == wake_fd) {
        std::uint64_t count = 0;
        (void)!read(wake_fd, &count, sizeof count);
        take_returned();
      } else if (const auto it = connections.find(fd); it != connections.end()) {
        Connection& c = *it->second;
        if (c.phase == Phase::Writing)
          on_writable(c);
        else if (c.phase != Phase::Busy)  // an event fetched before it went to a worker
          on_readable(c);
      }
    }
    expire();
  }
  return true;
}

// The handler's reply, made ready to send; the loop sends it (take_returned).
void HttpServer::Impl::serve(Connection& c) const {
  const HttpRequest& req = c.reader.request();
  HttpResponse res;
  try {
    res = handler(req);
  } catch (const std::exception& e) {
    res = HttpResponse{
        500, "text/plain; charset=utf-8", std::string("internal error: ") + e.what() + "\n", {}};
  } catch (...) {
    res = HttpResponse{500, "text/plain; charset=utf-8", "internal error\n", {}};
  }
  const bool keep = req.keep_alive() && c.served + 1 < limits.max_requests_per_connection;
  c.reply_head = reply_head(res, defaults, keep);
  c.reply_body = req.method == "HEAD" ? std::string() : std::move(res.body);
  c.reply_sent = 0;
  ++c.served;
  c.close_after = !keep;
}

void HttpServer::Impl::work(Lane& lane) {
  for (;;) {
    Connection* c = nullptr;
    {
      std::unique_lock<std::mutex> lock(lane.mutex);
      lane.ready.wait(lock, [&] { return lane.stop || !lane.queue.empty(); });
      if (lane.stop) return;
      c = lane.queue.front();
      lane.queue.pop_front();
    }
    serve(*c);
    ++answered;
    {
      std::lock_guard<std::mutex> lock(returned_mutex);
      returned.push_back(c);
    }
    wake();
  }
}

void HttpServer::Impl::start_workers() {
  urgent_lane.threads.emplace_back([this] { work(urgent_lane); });
  for (int k = 0; k < std::max(1, limits.workers); ++k)
    normal_lane.threads.emplace_back([this] { work(normal_lane); });
}

void HttpServer::Impl::stop_workers() {
  for (Lane* lane : {&urgent_lane, &normal_lane}) {
    {
      std::lock_guard<std::mutex> lock(lane->mutex);
      lane->stop = true;
    }
    lane->ready.notify_all();
    for (std::thread& t : lane->threads) t.join();
    lane->threads.clear();
  }
}

// ---- the public face ---------------------------------------------------------------------------

HttpServer::HttpServer(HttpLimits limits, Handler handler, Urgent urgent,
                       HeaderList default_headers)
    : impl_(std::make_unique<Impl>(limits, std::move(handler), std::move(urgent),
                                   std::move(default_headers))) {
  impl_->wake_fd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
  impl_->epoll_fd = epoll_create1(EPOLL_CLOEXEC);
  if (impl_->wake_fd < 0 || impl_->epoll_fd < 0)
    throw std::runtime_error(std::string("idm-web: epoll/eventfd: ") + std::strerror(errno));
}

HttpServer::~HttpServer() = default;

void HttpServer::bind(const std::string& host, int port) {
  impl_->bind_to(host, port);
}

int HttpServer::port() const {
  return impl_->bound_port;
}

bool HttpServer::loopback() const {
  return impl_->bound_loopback;
}

bool HttpServer::run() {
  impl_->start_workers();
  const bool ok = impl_->loop();
  impl_->stop_workers();
  return ok;
}

void HttpServer::stop() {
  impl_->stopping = true;
  impl_->wake();
}

std::uint64_t HttpServer::open_connections() const {
  return impl_->open;
}

std::uint64_t HttpServer::requests() const {
  return impl_->answered;
}

}  // namespace idm::web
