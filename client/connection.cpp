#include "client/connection.h"

#include <netdb.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstdlib>
#include <cstring>

#include "client/replies.h"
#include "model/yaml_util.h"

namespace idm::client {

std::string Address::text() const {
  if (!unix_path.empty()) return "unix socket " + unix_path;
  return (host.find(':') != std::string::npos ? "[" + host + "]" : host) + ":" +
         std::to_string(port);
}

Address parse_host_port(std::string_view text, int default_port, bool allow_port_zero) {
  const std::string shown(text.substr(0, 200));
  Address a;
  std::string_view host = text, port;
  if (!text.empty() && text.front() == '[') {
    const std::size_t close = text.find(']');
    if (close == std::string_view::npos)
      throw AddressError("'" + shown + "': a '[' without its ']'");
    host = text.substr(1, close - 1);
    const std::string_view rest = text.substr(close + 1);
    if (!rest.empty()) {
      if (rest.front() != ':') throw AddressError("'" + shown + "': expected ':PORT' after ']'");
      port = rest.substr(1);
      if (port.empty()) throw AddressError("'" + shown + "': an empty port");
    }
  } else if (const std::size_t colon = text.rfind(':'); colon != std::string_view::npos) {
    if (text.find(':') != colon)
      throw AddressError("'" + shown + "': an IPv6 address goes in brackets: [ADDRESS]:PORT");
    host = text.substr(0, colon);
    port = text.substr(colon + 1);
    if (port.empty()) throw AddressError("'" + shown + "': an empty port");
  }
  if (host.empty()) throw AddressError("'" + shown + "': an empty host");
  for (const char c : host)
    if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '-' || c == '_' ||
          c == ':' || c == '%'))
      throw AddressError("'" + shown + "': the host holds a character a host name cannot");
  a.host = std::string(host);
  a.port = default_port;
  if (!port.empty()) {
    if (port.size() > 5 || port.find_first_not_of("0123456789") != std::string_view::npos)
      throw AddressError("'" + shown + "': the port is not a number in 1..65535");
    a.port = std::atoi(std::string(port).c_str());
    if ((a.port < 1 && !(allow_port_zero && a.port == 0)) || a.port > 65535)
      throw AddressError("'" + shown + "': the port is out of range, allowed 1..65535");
  }
  return a;
}

Address address_from_environment() {
  const char* socket_path = std::getenv("IDMD_SOCKET");
  const char* address = std::getenv("IDMD_ADDRESS");
  const bool has_socket = socket_path && *socket_path, has_address = address && *address;
  if (has_socket && has_address)
    throw AddressError("IDMD_SOCKET and IDMD_ADDRESS are both set: set one");
  if (has_socket) {
    Address a;
    a.unix_path = socket_path;
    return a;
  }
  if (has_address) {
    try {
      return parse_host_port(address);
    } catch (const AddressError& e) {
      throw AddressError(std::string("IDMD_ADDRESS: ") + e.what());
    }
  }
  return Address{};
}

Connection::Connection(const Address& address, double timeout_s) : timeout_s_(timeout_s) {
  address_ = address.text();
  if (!address.unix_path.empty()) {
    sockaddr_un a{};
    a.sun_family = AF_UNIX;
    if (address.unix_path.size() >= sizeof a.sun_path)
      throw std::runtime_error(address_ + ": path too long");
    std::memcpy(a.sun_path, address.unix_path.c_str(), address.unix_path.size() + 1);
    fd_ = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd_ < 0 || connect(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0)
      fail_connect(std::strerror(errno));
    return;
  }
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = AI_NUMERICSERV;
  addrinfo* list = nullptr;
  if (const int rc =
          getaddrinfo(address.host.c_str(), std::to_string(address.port).c_str(), &hints, &list);
      rc != 0)
    fail_connect(gai_strerror(rc));
  std::string why = "no address";
  for (addrinfo* ai = list; ai && fd_ < 0; ai = ai->ai_next) {
    fd_ = socket(ai->ai_family, ai->ai_socktype | SOCK_CLOEXEC, ai->ai_protocol);
    if (fd_ >= 0 && connect(fd_, ai->ai_addr, ai->ai_addrlen) != 0) {
      why = std::strerror(errno);
      close(fd_);
      fd_ = -1;
    }
  }
  freeaddrinfo(list);
  if (fd_ < 0) fail_connect(why);
}

Connection::~Connection() {
  if (fd_ >= 0) close(fd_);
}

void Connection::fail_connect(const std::string& why) {
  if (fd_ >= 0) close(fd_);
  fd_ = -1;
  throw std::runtime_error("cannot connect to " + address_ + ": " + why);
}

void Connection::send_line(const std::string& line) {
  const std::string bytes = line + "\n";
  std::size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = send(fd_, bytes.data() + done, bytes.size() - done, MSG_NOSIGNAL);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0)
      throw std::runtime_error(address_ + ": connection lost (" + std::strerror(errno) + ")");
    done += static_cast<std::size_t>(n);
  }
}

std::string Connection::read_line(const std::function<bool()>& interrupted) {
  const auto start = std::chrono::steady_clock::now();
  for (;;) {
    if (const std::size_t nl = buffer_.find('\n'); nl != std::string::npos) {
      std::string line = buffer_.substr(0, nl);
      buffer_.erase(0, nl + 1);
      if (!line.empty() && line.back() == '\r') line.pop_back();
      return line;
    }
    if (interrupted && interrupted()) throw Interrupted{};
    int wait_ms = 200;
    if (timeout_s_ > 0) {
      const double left = timeout_s_ - seconds_since(start);
      if (left <= 0)
        throw std::runtime_error(address_ + ": no reply within " +
                                 idm::model::format_number(timeout_s_) + " s");
      wait_ms = std::min(wait_ms, static_cast<int>(left * 1000) + 1);
    }
    pollfd p{fd_, POLLIN, 0};
    const int rc = poll(&p, 1, wait_ms);
    if (rc <= 0) continue;  // timeout slice or EINTR: check again
    char buf[4096];
    const ssize_t n = recv(fd_, buf, sizeof buf, 0);
    if (n < 0 && errno == EINTR) continue;
    if (n == 0) throw std::runtime_error(address_ + ": the daemon closed the connection");
    if (n < 0)
      throw std::runtime_error(address_ + ": connection lost (" + std::strerror(errno) + ")");
    // A reply line is short; a peer that sends megabytes without a newline is not idmd.
    if (buffer_.size() + static_cast<std::size_t>(n) > kMaxReplyBytes)
      throw std::runtime_error(address_ + ": a reply line longer than " +
                               std::to_string(kMaxReplyBytes) + " bytes");
    buffer_.append(buf, static_cast<std::size_t>(n));
  }
}

std::vector<DaemonError> Client::drain_errors() {
  std::vector<DaemonError> errors;
  // The queue holds at most 32 entries (and -350); more means the peer is not idmd.
  for (int k = 0; k < 64; ++k) {
    const ErrorReply e = parse_error(connection_.query("SYST:ERR?"));
    if (e.code == 0) return errors;
    errors.emplace_back(e.code, e.text);
  }
  throw std::runtime_error(connection_.address() + ": the error queue does not empty");
}

void Client::throw_first_error(const std::string& line, bool reply_empty) {
  std::vector<DaemonError> errors = drain_errors();
  if (!errors.empty()) throw errors.front();
  if (reply_empty)
    throw std::runtime_error(connection_.address() + ": an empty reply to '" + line +
                             "' and no error queued");
}

std::string Client::query(const std::string& line) {
  std::string reply = connection_.query(line);
  throw_first_error(line, reply.empty());
  return reply;
}

void Client::command(const std::string& line) {
  connection_.send_line(line);
  throw_first_error(line, false);
}

}  // namespace idm::client
