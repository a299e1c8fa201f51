#include "web/http_server.h"

#include <arpa/inet.h>
#include <netdb.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/epoll.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
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

char lower(char c) {
  return c >= 'A' && c <= 'Z' ? static_cast<char>(c - 'A' + 'a') : c;
}

std::string lower(std::string_view s) {
  std::string out(s);
  for (char& c : out) c = lower(c);
  return out;
}

bool token_char(char c) {
  const auto u = static_cast<unsigned char>(c);
  if (u <= 0x20 || u >= 0x7f) return false;
  return std::string_view("\"(),/:;<=>?@[\\]{}").find(c) == kNone;
}

bool is_token(std::string_view s) {
  return !s.empty() && std::all_of(s.begin(), s.end(), token_char);
}

std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
  return s;
}

int hex_value(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  c = lower(c);
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  return -1;
}

// "%41b+c" -> "Ab c" (plus as a blank, as forms encode it); a '%' without two hex digits is kept.
std::string percent_decode(std::string_view text) {
  std::string out;
  out.reserve(text.size());
  for (std::size_t i = 0; i < text.size(); ++i) {
    const char c = text[i];
    if (c == '+') {
      out += ' ';
    } else if (c == '%' && i + 2 < text.size() && hex_value(text[i + 1]) >= 0 &&
               hex_value(text[i + 2]) >= 0) {
      out += static_cast<char>(hex_value(text[i + 1]) * 16 + hex_value(text[i + 2]));
      i += 2;
    } else {
      out += c;
    }
  }
  return out;
}

// The first `name=value` of an a=b&c=d list, decoded.
std::optional<std::string> find_param(std::string_view list, std::string_view name) {
  while (!list.empty()) {
    const std::size_t amp = list.find('&');
    const std::string_view item = list.substr(0, amp);
    const std::size_t eq = item.find('=');
    if (percent_decode(item.substr(0, eq)) == name)
      return eq == kNone ? std::string() : percent_decode(item.substr(eq + 1));
    if (amp == kNone) break;
    list.remove_prefix(amp + 1);
  }
  return std::nullopt;
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

std::string serialize(const HttpResponse& res, const HeaderList& defaults, bool head_only,
                      bool keep_alive) {
  std::string out = "HTTP/1.1 " + std::to_string(res.status) + " " + reason(res.status) + "\r\n";
  out += "Date: " + http_date() + "\r\n";
  out += "Content-Type: " + res.content_type + "\r\n";
  out += "Content-Length: " + std::to_string(res.body.size()) + "\r\n";
  for (const auto& [name, value] : defaults) out += name + ": " + value + "\r\n";
  for (const auto& [name, value] : res.headers) out += name + ": " + value + "\r\n";
  out += keep_alive ? "Connection: keep-alive\r\n\r\n" : "Connection: close\r\n\r\n";
  if (!head_only) out += res.body;
  return out;
}

// Writes all of `data` to a non-blocking socket, waiting for room until `deadline`.
bool write_all(int fd, std::string_view data, Clock::time_point deadline) {
  while (!data.empty()) {
    const ssize_t n = send(fd, data.data(), data.size(), MSG_NOSIGNAL);
    if (n > 0) {
      data.remove_prefix(static_cast<std::size_t>(n));
      continue;
    }
    if (n < 0 && errno == EINTR) continue;
    if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
      const auto left =
          std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now()).count();
      if (left <= 0) return false;
      pollfd p{fd, POLLOUT, 0};
      if (poll(&p, 1, static_cast<int>(std::min<long long>(left, 60000))) < 0 && errno != EINTR)
        return false;
      continue;
    }
    return false;
  }
  return true;
}

bool has_token(const std::string* list, std::string_view token) {
  if (!list) return false;
  std::string_view rest = *list;
  while (!rest.empty()) {
    const std::size_t comma = rest.find(',');
    if (lower(trim(rest.substr(0, comma))) == token) return true;
    if (comma == kNone) break;
    rest.remove_prefix(comma + 1);
  }
  return false;
}

bool keep_alive_asked(const HttpRequest& r) {
  const std::string* c = r.header("connection");
  return r.version == "HTTP/1.1" ? !has_token(c, "close") : has_token(c, "keep-alive");
}

// A refusal of the server itself: the status and why, in words.
struct Refusal {
  int status = 0;
  std::string why;
};

// The request line: METHOD SP origin-form SP HTTP/1.x.
std::optional<Refusal> parse_request_line(std::string_view line, HttpRequest& r) {
  const std::size_t a = line.find(' ');
  const std::size_t b = a == kNone ? kNone : line.find(' ', a + 1);
  if (b == kNone || line.find(' ', b + 1) != kNone)
    return Refusal{400, "a request line is METHOD /path HTTP/1.1"};
  r.method = std::string(line.substr(0, a));
  r.target = std::string(line.substr(a + 1, b - a - 1));
  r.version = std::string(line.substr(b + 1));
  if (!is_token(r.method) || r.method.size() > 32) return Refusal{400, "a malformed method"};
  if (r.target.empty() || r.target[0] != '/' ||
      !std::all_of(r.target.begin(), r.target.end(), [](char c) {
        const auto u = static_cast<unsigned char>(c);
        return u > 0x20 && u < 0x7f;
      }))
    return Refusal{400, "the target must be a path starting with / (printable ASCII)"};
  if (r.version != "HTTP/1.1" && r.version != "HTTP/1.0") {
    const bool http = r.version.size() == 8 && r.version.compare(0, 5, "HTTP/") == 0;
    return http ? Refusal{505, "HTTP/1.1 and HTTP/1.0 only"} : Refusal{400, "not HTTP"};
  }
  const std::size_t q = r.target.find('?');
  r.path = r.target.substr(0, q);
  r.query = q == kNone ? "" : r.target.substr(q + 1);
  return std::nullopt;
}

// One header field line (without its line end) into r.headers.
std::optional<Refusal> parse_field(std::string_view line, HttpRequest& r) {
  if (line.front() == ' ' || line.front() == '\t')
    return Refusal{400, "a folded header line (obsolete line folding is not accepted)"};
  const std::size_t colon = line.find(':');
  if (colon == kNone || !is_token(line.substr(0, colon)))
    return Refusal{400, "a header line is Name: value"};
  const std::string_view value = trim(line.substr(colon + 1));
  for (const char c : value) {
    const auto u = static_cast<unsigned char>(c);
    if ((u < 0x20 && c != '\t') || u == 0x7f)
      return Refusal{400, "a control character in a header value"};
  }
  r.headers.emplace_back(lower(line.substr(0, colon)), std::string(value));
  return std::nullopt;
}

// What the head says of the body: its length (Content-Length), within the limit.
std::optional<Refusal> body_length(const HttpRequest& r, const HttpLimits& lim, std::size_t& n) {
  n = 0;
  if (r.header("transfer-encoding"))
    return Refusal{411,
                   "a body in chunks (Transfer-Encoding) is not accepted: send Content-Length"};
  const std::string* first = r.header("content-length");
  if (!first) return std::nullopt;
  for (const auto& [name, value] : r.headers)
    if (name == "content-length" && value != *first)
      return Refusal{400, "Content-Length given twice, differently"};
  if (first->empty() || first->size() > 18 ||
      first->find_first_not_of("0123456789") != std::string::npos)
    return Refusal{400, "Content-Length: a decimal number of bytes"};
  n = static_cast<std::size_t>(std::stoull(*first));
  if (n > lim.max_body_bytes)
    return Refusal{413, "the body is " + *first + " bytes, at most " +
                            std::to_string(lim.max_body_bytes) + " are accepted"};
  return std::nullopt;
}

enum class Phase { Idle, Reading, Busy, Draining };

}  // namespace

const std::string* HttpRequest::header(std::string_view name) const {
  for (const auto& [n, v] : headers)
    if (n == name) return &v;
  return nullptr;
}

std::size_t HttpRequest::header_count(std::string_view name) const {
  return static_cast<std::size_t>(std::count_if(headers.begin(), headers.end(),
                                                [name](const auto& h) { return h.first == name; }));
}

std::optional<std::string> HttpRequest::param(std::string_view name) const {
  if (auto v = find_param(query, name)) return v;
  const std::string* type = header("content-type");
  if (type && lower(*type).rfind("application/x-www-form-urlencoded", 0) == 0)
    return find_param(body, name);
  return std::nullopt;
}

namespace {

// One client connection. The event loop owns it; while Busy a worker alone touches it.
struct Connection {
  int fd = -1;
  std::string in;  // bytes received and not yet taken by a request
  Phase phase = Phase::Idle;
  Clock::time_point deadline{};  // of the phase (Idle, Reading, Draining)
  Clock::time_point since{};     // entered Idle: the oldest idle one makes room first
  std::size_t served = 0;
  bool peer_closed = false;  // the client shut its side: what is whole is answered, then closed
  // The head being read: scanned up to `scanned`; the request line ends at `line_end` (kNone:
  // not yet), the current line starts at `line_start`; `fields` header lines so far; `head_end`
  // past the blank line once it came (kNone: not yet), then `body` bytes after it.
  std::size_t scanned = 0, line_start = 0, line_end = kNone, fields = 0, head_end = kNone;
  std::size_t body = 0;
  HttpRequest request;  // the whole request, while Busy
  bool close_after = false;
  std::size_t drained = 0;

  void next_request() {
    in.erase(0, head_end + body);
    scanned = line_start = fields = body = 0;
    line_end = head_end = kNone;
    request = HttpRequest{};
  }
};

// Scans the new bytes of c.in for the end of the head, counting lines; a limit passed is a
// refusal (414, 431). Leaves c.head_end set once the blank line came.
std::optional<Refusal> scan_head(Connection& c, const HttpLimits& lim) {
  const auto too_many = [&] {
    return Refusal{431, "the request's header fields are too large: at most " +
                            std::to_string(lim.max_header_fields) + " fields and " +
                            std::to_string(lim.max_header_bytes) + " bytes"};
  };
  for (; c.scanned < c.in.size() && c.head_end == kNone; ++c.scanned) {
    if (c.in[c.scanned] != '\n') continue;
    const std::size_t len = c.scanned - c.line_start;
    const bool blank = len == 0 || (len == 1 && c.in[c.line_start] == '\r');
    if (c.line_end == kNone) {
      if (!blank) c.line_end = c.scanned;  // blank lines before the request line are skipped
      if (c.scanned > lim.max_request_line_bytes) break;
    } else if (blank) {
      c.head_end = c.scanned + 1;
    } else if (++c.fields > lim.max_header_fields) {
      return too_many();
    }
    c.line_start = c.scanned + 1;
  }
  if (c.line_end == kNone || c.line_end > lim.max_request_line_bytes) {
    if (std::min(c.line_end, c.in.size()) > lim.max_request_line_bytes)
      return Refusal{414, "the request line is longer than " +
                              std::to_string(lim.max_request_line_bytes) + " bytes"};
    return std::nullopt;
  }
  const std::size_t end = c.head_end == kNone ? c.in.size() : c.head_end;
  if (end - c.line_end - 1 > lim.max_header_bytes) return too_many();
  return std::nullopt;
}

// The whole head (request line and fields) into c.request, and the body's length.
std::optional<Refusal> parse_head(Connection& c, const HttpLimits& lim) {
  const std::string_view in = c.in;
  std::size_t start = 0;
  while (in[start] == '\r' || in[start] == '\n') ++start;
  std::string_view line = in.substr(start, c.line_end - start);
  if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
  if (auto r = parse_request_line(line, c.request)) return r;
  std::size_t pos = c.line_end + 1;
  while (pos < c.head_end) {
    const std::size_t nl = in.find('\n', pos);
    line = in.substr(pos, nl - pos);
    pos = nl + 1;
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    if (line.empty()) break;
    if (auto r = parse_field(line, c.request)) return r;
  }
  if (c.request.header_count("host") != 1)
    return Refusal{400, "a request needs exactly one Host header"};
  return body_length(c.request, lim, c.body);
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
  std::size_t draining = 0;
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

  bool watch(int fd, int op) const {
    epoll_event ev{};
    ev.events = EPOLLIN | EPOLLRDHUP;
    ev.data.fd = fd;
    return epoll_ctl(epoll_fd, op, fd, &ev) == 0;
  }

  // The most a connection's buffer holds: a request at every limit, and its line ends.
  std::size_t read_cap() const {
    return limits.max_request_line_bytes + limits.max_header_bytes + limits.max_body_bytes + 64;
  }
  void bind_to(const std::string& host, int port);
  bool loop();
  void accept_all();
  void on_readable(Connection& c);
  void advance(Connection& c);
  void refuse(Connection& c, const Refusal& r);
  void close_connection(int fd);
  void take_returned();
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
  if (it->second->phase == Phase::Draining)
    --draining;
  else
    --open;
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
  const std::string out = serialize(res, defaults, false, false);
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
    auto c = std::make_unique<Connection>();
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
    const std::size_t cap = read_cap();
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
  if (c.phase == Phase::Draining || c.phase == Phase::Busy) return;
  std::optional<Refusal> refusal;
  if (c.head_end == kNone) {
    refusal = scan_head(c, limits);
    if (!refusal && c.head_end != kNone) refusal = parse_head(c, limits);
  }
  if (refusal) return refuse(c, *refusal);
  const bool whole = c.head_end != kNone && c.in.size() >= c.head_end + c.body;
  if (!whole) {
    if (c.peer_closed)
      close_connection(c.fd);
    else if (c.in.size() >= read_cap())  // not reached within the limits; never waits unread
      refuse(c, {413, "the request is larger than its limits"});
    return;
  }
  c.request.body = c.in.substr(c.head_end, c.body);
  c.phase = Phase::Busy;
  epoll_ctl(epoll_fd, EPOLL_CTL_DEL, c.fd, nullptr);
  Lane& lane = urgent && urgent(c.request) ? urgent_lane : normal_lane;
  {
    std::lock_guard<std::mutex> lock(lane.mutex);
    lane.queue.push_back(&c);
  }
  lane.ready.notify_one();
}

void HttpServer::Impl::take_returned() {
  std::vector<Connection*> back;
  {
    std::lock_guard<std::mutex> lock(returned_mutex);
    back.swap(returned);
  }
  for (Connection* c : back) {
    if (c->close_after || stopping) {
      close_connection(c->fd);
      continue;
    }
    c->next_request();
    c->phase = Phase::Idle;
    c->since = Clock::now();
    c->deadline = after(limits.idle_timeout_s);
    if (!watch(c->fd, EPOLL_CTL_ADD)) {
      close_connection(c->fd);
      continue;
    }
    if (!c->in.empty()) {  // the next request came with the last one
      c->phase = Phase::Reading;
      c->deadline = after(limits.request_timeout_s);
      advance(*c);
    }
  }
}

// Connections past their phase's deadline: a request still coming is answered 408, an idle or
// draining one closed.
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
        on_readable(*it->second);
      }
    }
    expire();
  }
  return true;
}

void HttpServer::Impl::serve(Connection& c) const {
  HttpResponse res;
  try {
    res = handler(c.request);
  } catch (const std::exception& e) {
    res = HttpResponse{
        500, "text/plain; charset=utf-8", std::string("internal error: ") + e.what() + "\n", {}};
  } catch (...) {
    res = HttpResponse{500, "text/plain; charset=utf-8", "internal error\n", {}};
  }
  const bool keep = keep_alive_asked(c.request) && !c.peer_closed &&
                    c.served + 1 < limits.max_requests_per_connection;
  const std::string out = serialize(res, defaults, c.request.method == "HEAD", keep);
  const bool written = write_all(c.fd, out, after(limits.write_timeout_s));
  ++c.served;
  c.close_after = !keep || !written;
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
