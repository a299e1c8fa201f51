#include "daemon/server.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <sys/epoll.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <map>
#include <memory>
#include <vector>

#include "daemon/protocol.h"

namespace idm::daemon {

namespace {

enum Counter {
  kAccepted,
  kRejected,
  kClosedByPeer,
  kNoNewline,
  kSlowReader,
  kSocketError,
  kRefused,
  kCounters
};

std::string error_text(const char* call, int error) {
  return std::string(call) + ": " + std::strerror(error);
}

std::string host_port(const std::string& host, int port) {
  const bool v6 = host.find(':') != std::string::npos;
  return (v6 ? "[" + host + "]" : host) + ":" + std::to_string(port);
}

struct Client {
  Client(int fd_, std::string peer_, Instrument& instrument)
      : fd(fd_), peer(std::move(peer_)), session(instrument) {}
  int fd;
  std::string peer;
  Session session;
  std::string out;  // replies not yet written, from out_offset on
  std::size_t out_offset = 0;
  bool end_of_input = false;
  bool overflow = false;  // a stop-only slot (the table was full when it came)
  std::chrono::steady_clock::time_point since;  // accepted (overflow), or started draining
  std::uint32_t events = 0;                     // current epoll interest
  // Half-closed while it waits for a reply: it no longer holds a slot.
  bool draining() const { return end_of_input && session.waiting(); }
  std::size_t pending_output() const { return out.size() - out_offset; }
};

}  // namespace

// The thread's state: lives in run() only. It is also the sessions' ClientTable: they ask it on
// this thread, the only one that touches `clients`.
struct Server::Impl final : ClientTable {
  explicit Impl(Server& s) : server(s) {}
  Server& server;
  std::map<int, std::unique_ptr<Client>> clients;
  bool listeners_paused = false;
  std::chrono::steady_clock::time_point resume_listeners_at;
  // Refusals logged: the first at once, then at most one a minute with the count in between.
  std::chrono::steady_clock::time_point refusal_logged_at;
  std::uint64_t refusals_unlogged = 0;
  bool refusal_logged = false;

  ClientTableStats client_table() const override {
    ClientTableStats t;
    t.connected = static_cast<int>(clients.size());
    t.slots = live_clients();
    t.max_clients = server.config_.max_clients;
    t.stop_only = count_if([](const Client& c) { return c.overflow; });
    t.overflow_slots = server.config_.overflow_slots;
    t.draining = count_if([](const Client& c) { return c.draining(); });
    return t;
  }

  void log(const std::string& line) const {
    if (server.config_.log) server.config_.log(line);
  }
  void count(Counter c) const { server.counters_[c].fetch_add(1); }

  // A session asked to be closed (it sent HTTP, or a wrong token): its last replies are written
  // as far as the socket takes them, then it is closed and the refusal logged (rate-limited).
  void refuse(Client& c) {
    const std::string text = "client " + c.peer + " " + c.session.close_reason();
    count(kRefused);
    const auto now = std::chrono::steady_clock::now();
    if (!refusal_logged || now - refusal_logged_at >= std::chrono::minutes(1)) {
      std::string line = "command server: " + text;
      if (refusals_unlogged > 0)
        line += " (and " + std::to_string(refusals_unlogged) + " more refused since the last line)";
      if (server.config_.warn)
        server.config_.warn(line);
      else
        log(line);
      refusal_logged = true;
      refusal_logged_at = now;
      refusals_unlogged = 0;
    } else {
      ++refusals_unlogged;
    }
    epoll_ctl(server.epoll_fd_, EPOLL_CTL_DEL, c.fd, nullptr);
    ::close(c.fd);
    const int fd = c.fd;
    clients.erase(fd);
    server.clients_.store(static_cast<int>(clients.size()));
  }

  void accept_all(int listener) {
    for (;;) {
      const int fd = accept4(listener, nullptr, nullptr, SOCK_NONBLOCK | SOCK_CLOEXEC);
      if (fd < 0) {
        if (errno == EINTR || errno == ECONNABORTED || errno == EPROTO) continue;
        if (errno == EMFILE || errno == ENFILE || errno == ENOBUFS || errno == ENOMEM) {
          // Level-triggered: an accept that keeps failing would spin. Pause the listeners.
          log("command server: accept: " + std::string(std::strerror(errno)) +
              "; not accepting for 100 ms");
          pause_listeners();
        }
        return;
      }
      const bool overflow = live_clients() >= server.config_.max_clients;
      if (overflow) {
        count(kRejected);
        if (count_if([](const Client& c) { return c.overflow; }) >= server.config_.overflow_slots)
          drop_oldest([](const Client& c) { return c.overflow; }, kRejected,
                      "closed: its stop-only slot went to a newer client");
      }
      std::string peer = "unix socket";
      if (listener == server.tcp_fd_) {
        const int one = 1;
        setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
        sockaddr_storage addr{};
        socklen_t len = sizeof addr;
        char host[NI_MAXHOST] = "?", port[NI_MAXSERV] = "?";
        if (getpeername(fd, reinterpret_cast<sockaddr*>(&addr), &len) == 0)
          getnameinfo(reinterpret_cast<sockaddr*>(&addr), len, host, sizeof host, port, sizeof port,
                      NI_NUMERICHOST | NI_NUMERICSERV);
        peer = "tcp " + host_port(host, std::atoi(port));
      }
      auto client = std::make_unique<Client>(fd, peer, server.instrument_);
      client->overflow = overflow;
      client->since = std::chrono::steady_clock::now();
      client->session.set_stop_only(overflow);
      client->session.set_client_table(this);
      if (listener == server.tcp_fd_ && !server.config_.tcp_token.empty())
        client->session.require_token(&server.config_.tcp_token);
      epoll_event ev{};
      ev.events = EPOLLIN;
      ev.data.fd = fd;
      if (epoll_ctl(server.epoll_fd_, EPOLL_CTL_ADD, fd, &ev) != 0) {
        ::close(fd);
        count(kSocketError);
        continue;
      }
      client->events = EPOLLIN;
      clients.emplace(fd, std::move(client));
      server.clients_.store(static_cast<int>(clients.size()));
      count(kAccepted);
      if (overflow)
        log("command server: client connected (" + peer +
            ") in a stop-only slot: " + std::to_string(server.config_.max_clients) +
            " clients already connected (server.max_clients)");
      else
        log("command server: client connected (" + peer + ")");
    }
  }

  template <typename Pred>
  int count_if(Pred pred) const {
    int n = 0;
    for (const auto& [fd, c] : clients) n += pred(*c) ? 1 : 0;
    return n;
  }
  int live_clients() const {
    return count_if([](const Client& c) { return !c.overflow && !c.draining(); });
  }
  template <typename Pred>
  void drop_oldest(Pred pred, Counter why, const std::string& text) {
    Client* oldest = nullptr;
    for (const auto& [fd, c] : clients)
      if (pred(*c) && (!oldest || c->since < oldest->since)) oldest = c.get();
    if (oldest) drop(*oldest, why, text);
  }

  // Stop-only clients past their linger time are closed (their last replies flushed first, as
  // far as the socket takes them). Returns the ms until the next one is due, -1: none.
  int expire_overflow() {
    const auto now = std::chrono::steady_clock::now();
    const auto linger = std::chrono::duration_cast<std::chrono::steady_clock::duration>(
        std::chrono::duration<double>(server.config_.overflow_linger_s));
    std::vector<int> due;
    auto next = std::chrono::steady_clock::time_point::max();
    for (const auto& [fd, c] : clients) {
      if (!c->overflow) continue;
      if (now - c->since >= linger)
        due.push_back(fd);
      else
        next = std::min(next, c->since + linger);
    }
    for (int fd : due) {
      auto it = clients.find(fd);
      if (it == clients.end()) continue;
      flush(*it->second);
      if (clients.count(fd)) drop(*it->second, kClosedByPeer, "closed: its stop-only time is over");
    }
    if (next == std::chrono::steady_clock::time_point::max()) return -1;
    return static_cast<int>(
        std::chrono::duration_cast<std::chrono::milliseconds>(next - now).count() + 1);
  }

  void set_listener_events(std::uint32_t events) {
    for (int fd : {server.tcp_fd_, server.unix_fd_}) {
      if (fd < 0) continue;
      epoll_event ev{};
      ev.events = events;
      ev.data.fd = fd;
      epoll_ctl(server.epoll_fd_, EPOLL_CTL_MOD, fd, &ev);
    }
  }
  void pause_listeners() {
    set_listener_events(0);
    listeners_paused = true;
    resume_listeners_at = std::chrono::steady_clock::now() + std::chrono::milliseconds(100);
  }
  void maybe_resume_listeners() {
    if (listeners_paused && std::chrono::steady_clock::now() >= resume_listeners_at) {
      set_listener_events(EPOLLIN);
      listeners_paused = false;
    }
  }

  void drop(Client& c, Counter why, const std::string& text) {
    count(why);
    log("command server: client " + c.peer + " " + text);
    epoll_ctl(server.epoll_fd_, EPOLL_CTL_DEL, c.fd, nullptr);
    ::close(c.fd);
    const int fd = c.fd;
    clients.erase(fd);  // c is gone from here on
    server.clients_.store(static_cast<int>(clients.size()));
  }

  // Returns false when the client was dropped.
  bool read_some(Client& c) {
    char buf[16384];
    // At most 4 reads per wake-up, so that a client that streams cannot starve the others. A
    // short read took everything the socket held: stop there rather than spend a read() on
    // EAGAIN (epoll is level-triggered, so whatever arrives meanwhile wakes us again). This is one
    // system call less per request in the usual one-query-one-reply exchange.
    for (int k = 0; k < 4 && !c.end_of_input; ++k) {
      if (c.session.held_bytes() > server.config_.max_held_bytes) break;
      const ssize_t n = ::read(c.fd, buf, sizeof buf);
      if (n > 0) {
        c.session.receive(std::string_view(buf, static_cast<std::size_t>(n)), c.out);
        if (c.session.unterminated_bytes() > server.config_.max_unterminated_bytes) {
          drop(c, kNoNewline,
               "disconnected: sent more than " +
                   std::to_string(server.config_.max_unterminated_bytes) +
                   " bytes without a newline");
          return false;
        }
        if (static_cast<std::size_t>(n) < sizeof buf) break;
      } else if (n == 0) {
        c.end_of_input = true;
        c.session.end_of_input(c.out);
        if (c.draining()) {
          c.since = std::chrono::steady_clock::now();
          if (count_if([](const Client& x) { return x.draining(); }) > server.config_.max_clients) {
            const int self = c.fd;
            drop_oldest([self](const Client& x) { return x.draining() && x.fd != self; },
                        kClosedByPeer, "closed: too many half-closed clients waiting for *OPC?");
          }
        }
      } else if (errno == EINTR) {
        continue;
      } else if (errno == EAGAIN || errno == EWOULDBLOCK) {
        break;
      } else {
        drop(c, kSocketError, "disconnected: " + error_text("read", errno));
        return false;
      }
    }
    return true;
  }

  bool flush(Client& c) {
    while (c.pending_output() > 0) {
      const ssize_t n = ::send(c.fd, c.out.data() + c.out_offset, c.pending_output(), MSG_NOSIGNAL);
      if (n > 0) {
        c.out_offset += static_cast<std::size_t>(n);
      } else if (n < 0 && errno == EINTR) {
        continue;
      } else if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
        break;
      } else {
        drop(c, kSocketError, "disconnected: " + error_text("send", errno));
        return false;
      }
    }
    if (c.out_offset == c.out.size()) {
      c.out.clear();
      c.out_offset = 0;
    } else if (c.out_offset > c.out.size() / 2) {
      c.out.erase(0, c.out_offset);
      c.out_offset = 0;
    }
    return true;
  }

  // After anything happened to a client: write what can be written, enforce the output bound,
  // close a finished client, set the epoll interest. Returns false when the client was dropped.
  bool settle(Client& c) {
    if (!flush(c)) return false;
    if (!c.session.close_reason().empty()) {
      refuse(c);
      return false;
    }
    if (c.pending_output() > server.config_.max_output_bytes) {
      drop(c, kSlowReader,
           "disconnected: does not read its replies (more than " +
               std::to_string(server.config_.max_output_bytes) + " bytes waiting)");
      return false;
    }
    if (c.end_of_input && c.session.idle() && c.pending_output() == 0) {
      drop(c, kClosedByPeer, "disconnected");
      return false;
    }
    std::uint32_t want = 0;
    if (!c.end_of_input && c.session.held_bytes() <= server.config_.max_held_bytes) want |= EPOLLIN;
    if (c.pending_output() > 0) want |= EPOLLOUT;
    if (want != c.events) {
      epoll_event ev{};
      ev.events = want;
      ev.data.fd = c.fd;
      epoll_ctl(server.epoll_fd_, EPOLL_CTL_MOD, c.fd, &ev);
      c.events = want;
    }
    return true;
  }

  void on_client(Client& c, std::uint32_t events) {
    if (events & EPOLLERR) {
      int error = 0;
      socklen_t len = sizeof error;
      getsockopt(c.fd, SOL_SOCKET, SO_ERROR, &error, &len);
      drop(c, kSocketError, "disconnected: " + error_text("socket", error));
      return;
    }
    if (events & (EPOLLIN | EPOLLHUP)) {
      if (c.events & EPOLLIN) {
        if (!read_some(c)) return;
      }
      // Hang-up: the peer can neither send nor receive (both directions shut, or reset). Nobody
      // is left to read a reply, so a waiting session does not keep its slot until the motion
      // ends.
      if ((events & EPOLLHUP) && (!(c.events & EPOLLIN) || c.end_of_input)) {
        drop(c, kClosedByPeer, "disconnected (hang-up)");
        return;
      }
    }
    settle(c);
  }

  void poll_waiting() {
    std::vector<int> waiting;
    for (const auto& [fd, c] : clients)
      if (c->session.waiting()) waiting.push_back(fd);
    for (int fd : waiting) {
      auto it = clients.find(fd);
      if (it == clients.end()) continue;
      Client& c = *it->second;
      c.session.poll(c.out);
      if (!settle(c)) continue;
      // Input held behind the wait may already be in the socket; settle() re-enabled reading.
    }
  }

  bool any_waiting() const {
    for (const auto& [fd, c] : clients)
      if (c->session.waiting()) return true;
    return false;
  }

  void run() {
    epoll_event events[64];
    const int poll_ms =
        std::max(1, static_cast<int>(std::lround(server.config_.wait_poll_s * 1000)));
    for (;;) {
      int timeout = expire_overflow();
      if (any_waiting()) timeout = timeout < 0 ? poll_ms : std::min(timeout, poll_ms);
      if (listeners_paused) timeout = timeout < 0 ? 100 : std::min(timeout, 100);
      const int n = epoll_wait(server.epoll_fd_, events, 64, timeout);
      if (n < 0 && errno != EINTR) {
        log("command server: " + error_text("epoll_wait", errno) + "; stopping");
        break;
      }
      bool stop = false;
      for (int k = 0; k < n; ++k) {
        const int fd = events[k].data.fd;
        if (fd == server.wake_fd_) {
          stop = true;
        } else if (fd == server.tcp_fd_ || fd == server.unix_fd_) {
          accept_all(fd);
        } else if (auto it = clients.find(fd); it != clients.end()) {
          on_client(*it->second, events[k].events);
        }
      }
      if (stop) break;
      if (any_waiting()) poll_waiting();
      maybe_resume_listeners();
    }
    for (auto& [fd, c] : clients) {
      epoll_ctl(server.epoll_fd_, EPOLL_CTL_DEL, fd, nullptr);
      ::close(fd);
    }
    clients.clear();
    server.clients_.store(0);
  }
};

bool is_loopback_address(std::string_view host) {
  if (host == "localhost") return true;
  const std::string text(host);
  in_addr v4{};
  if (inet_pton(AF_INET, text.c_str(), &v4) == 1) return (ntohl(v4.s_addr) >> 24) == 127;
  in6_addr v6{};
  if (inet_pton(AF_INET6, text.c_str(), &v6) == 1) {
    if (IN6_IS_ADDR_LOOPBACK(&v6)) return true;
    return IN6_IS_ADDR_V4MAPPED(&v6) && v6.s6_addr[12] == 127;
  }
  return false;
}

Server::Server(Instrument& instrument, ServerConfig config)
    : instrument_(instrument), config_(std::move(config)) {}

Server::~Server() {
  stop();
}

ServerCounters Server::counters() const {
  ServerCounters c;
  c.accepted = counters_[kAccepted].load();
  c.rejected_max_clients = counters_[kRejected].load();
  c.closed_by_peer = counters_[kClosedByPeer].load();
  c.dropped_no_newline = counters_[kNoNewline].load();
  c.dropped_slow_reader = counters_[kSlowReader].load();
  c.dropped_error = counters_[kSocketError].load();
  c.refused = counters_[kRefused].load();
  return c;
}

namespace {

// Returns the listening socket or -1 with `error` set.
int open_tcp(const std::string& host, int port, int& bound_port, std::string& error) {
  const std::string where = "TCP " + host_port(host, port);
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = AI_PASSIVE | AI_NUMERICSERV;
  addrinfo* list = nullptr;
  if (const int rc = getaddrinfo(host.c_str(), std::to_string(port).c_str(), &hints, &list);
      rc != 0) {
    error = where + ": cannot resolve the host: " + gai_strerror(rc);
    return -1;
  }
  int fd = -1;
  for (addrinfo* ai = list; ai && fd < 0; ai = ai->ai_next) {
    fd = socket(ai->ai_family, ai->ai_socktype | SOCK_NONBLOCK | SOCK_CLOEXEC, ai->ai_protocol);
    if (fd < 0) {
      error = where + ": " + error_text("socket", errno);
      continue;
    }
    const int one = 1;
    setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    if (bind(fd, ai->ai_addr, ai->ai_addrlen) != 0) {
      error = where + ": " + error_text("bind", errno);
      if (errno == EADDRINUSE)
        error += " (another program listens there; choose another port, or 0 for a free one)";
      ::close(fd);
      fd = -1;
    } else if (::listen(fd, 64) != 0) {
      error = where + ": " + error_text("listen", errno);
      ::close(fd);
      fd = -1;
    }
  }
  freeaddrinfo(list);
  if (fd < 0) return -1;
  sockaddr_storage addr{};
  socklen_t len = sizeof addr;
  getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len);
  bound_port = addr.ss_family == AF_INET6 ? ntohs(reinterpret_cast<sockaddr_in6*>(&addr)->sin6_port)
                                          : ntohs(reinterpret_cast<sockaddr_in*>(&addr)->sin_port);
  error.clear();
  return fd;
}

int open_unix(const std::string& path, unsigned mode, std::string& error) {
  const std::string where = "Unix socket " + path;
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  if (path.size() >= sizeof addr.sun_path) {
    error = where + ": path longer than " + std::to_string(sizeof addr.sun_path - 1) + " bytes";
    return -1;
  }
  std::memcpy(addr.sun_path, path.c_str(), path.size() + 1);
  struct stat st {};
  if (lstat(path.c_str(), &st) == 0) {
    if (!S_ISSOCK(st.st_mode)) {
      error = where + ": exists and is not a socket (not removing it)";
      return -1;
    }
    // A socket file: stale (left by a crash) unless someone still listens on it.
    const int probe = socket(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    if (probe >= 0) {
      const int rc = connect(probe, reinterpret_cast<sockaddr*>(&addr), sizeof addr);
      const int probe_errno = errno;
      ::close(probe);
      if (rc == 0 || probe_errno == EAGAIN) {
        error = where + ": another server is listening on it";
        return -1;
      }
    }
    if (unlink(path.c_str()) != 0 && errno != ENOENT) {
      error = where + ": cannot remove the stale socket: " + std::strerror(errno);
      return -1;
    }
  }
  const int fd = socket(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (fd < 0) {
    error = where + ": " + error_text("socket", errno);
    return -1;
  }
  if (bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
    error = where + ": " + error_text("bind", errno);
    ::close(fd);
    return -1;
  }
  // Before listen(): nobody can connect while the mode is still the umask's.
  if (chmod(path.c_str(), static_cast<mode_t>(mode)) != 0 || ::listen(fd, 64) != 0) {
    error = where + ": " + error_text("chmod/listen", errno);
    ::close(fd);
    unlink(path.c_str());
    return -1;
  }
  return fd;
}

}  // namespace

std::string Server::start() {
  if (thread_.joinable()) return "command server: already started";
  if (epoll_fd_ < 0)
    if (std::string error = listen(); !error.empty()) return error;
  thread_ = StackThread("idmd-server", kServerStackBytes, [this] { run(); });
  return {};
}

std::string Server::listen() {
  if (thread_.joinable() || epoll_fd_ >= 0) return "command server: already listening";
  if (config_.tcp_host.empty() && config_.unix_path.empty())
    return "command server: neither a TCP host nor a Unix socket path is configured";
  if (config_.tcp_port < 0 || config_.tcp_port > 65535)
    return "command server: TCP port " + std::to_string(config_.tcp_port) +
           " out of range, allowed [0, 65535]";
  if (config_.max_clients < 1) return "command server: max_clients must be at least 1";
  std::string error;
  epoll_fd_ = epoll_create1(EPOLL_CLOEXEC);
  wake_fd_ = eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
  if (epoll_fd_ < 0 || wake_fd_ < 0) {
    error = "command server: " + error_text("epoll/eventfd", errno);
    close_listeners();
    return error;
  }
  if (!config_.tcp_host.empty()) {
    tcp_fd_ = open_tcp(config_.tcp_host, config_.tcp_port, tcp_port_, error);
    if (tcp_fd_ < 0) {
      close_listeners();
      return error;
    }
  }
  if (!config_.unix_path.empty()) {
    unix_fd_ = open_unix(config_.unix_path, config_.unix_mode, error);
    if (unix_fd_ < 0) {
      close_listeners();
      return error;
    }
    struct stat st {};
    if (lstat(config_.unix_path.c_str(), &st) == 0) {
      unix_bound_ = true;
      unix_dev_ = st.st_dev;
      unix_ino_ = st.st_ino;
    }
  }
  for (int fd : {wake_fd_, tcp_fd_, unix_fd_}) {
    if (fd < 0) continue;
    epoll_event ev{};
    ev.events = EPOLLIN;
    ev.data.fd = fd;
    if (epoll_ctl(epoll_fd_, EPOLL_CTL_ADD, fd, &ev) != 0) {
      error = "command server: " + error_text("epoll_ctl", errno);
      close_listeners();
      return error;
    }
  }
  return {};
}

void Server::run() {
  Impl impl(*this);
  impl.run();
}

void Server::stop() {
  if (thread_.joinable()) {
    const std::uint64_t one = 1;
    while (::write(wake_fd_, &one, sizeof one) < 0 && errno == EINTR) {
    }
    thread_.join();
  }
  close_listeners();
}

void Server::close_listeners() {
  for (int* fd : {&tcp_fd_, &unix_fd_, &wake_fd_, &epoll_fd_}) {
    if (*fd >= 0) ::close(*fd);
    *fd = -1;
  }
  if (unix_bound_) {
    struct stat st {};
    if (lstat(config_.unix_path.c_str(), &st) == 0 && st.st_dev == unix_dev_ &&
        st.st_ino == unix_ino_)
      unlink(config_.unix_path.c_str());
    unix_bound_ = false;
  }
}

}  // namespace idm::daemon
