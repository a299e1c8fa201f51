// A client's connection to idmd (docs/command-protocol.md): TCP or the Unix socket,
// one line out, one reply line in, every wait bounded by a timeout.
#pragma once

#include <chrono>
#include <functional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

namespace idm::client {

// Where idmd listens: a Unix socket path, or TCP host and port.
struct Address {
  std::string host = "127.0.0.1";
  int port = 5025;
  std::string unix_path;  // when set, host and port are not used
  // "unix socket /run/idmd/idmd.sock", "127.0.0.1:5025", "[::1]:5025"
  std::string text() const;
};

// Bad input from a user or the environment (an address that does not parse).
struct AddressError : std::invalid_argument {
  using std::invalid_argument::invalid_argument;
};

// "host:port", "[v6 address]:port", or "host" alone (port `default_port`). The port 1..65535
// (0 too when `allow_port_zero`: a listener's "any free port").
Address parse_host_port(std::string_view text, int default_port = 5025,
                        bool allow_port_zero = false);

// From the environment: IDMD_SOCKET=path, else IDMD_ADDRESS=host:port, else 127.0.0.1:5025.
// Both set is an error (AddressError), as is an address that does not parse.
Address address_from_environment();

// Thrown by read_line when the caller's `interrupted` answers true while it waits.
struct Interrupted {};

class Connection {
 public:
  // Connects at once; std::runtime_error "cannot connect to <address>: <why>".
  Connection(const Address& address, double timeout_s);
  ~Connection();
  Connection(const Connection&) = delete;
  Connection& operator=(const Connection&) = delete;

  void send_line(const std::string& line);
  // One reply line (without its CR LF). Throws std::runtime_error on a timeout (timeout_s > 0)
  // or a lost connection; Interrupted when `interrupted` answers true while waiting.
  std::string read_line(const std::function<bool()>& interrupted = {});
  std::string query(const std::string& line, const std::function<bool()>& interrupted = {}) {
    send_line(line);
    return read_line(interrupted);
  }

  double timeout_s() const { return timeout_s_; }
  const std::string& address() const { return address_; }

  static double seconds_since(std::chrono::steady_clock::time_point t) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
  }

 private:
  [[noreturn]] void fail_connect(const std::string& why);

  int fd_ = -1;
  std::string address_;
  std::string buffer_;
  double timeout_s_;
};

// An error from the daemon's queue: SYSTem:ERRor? answered `<code>,"<text>"`.
struct DaemonError : std::runtime_error {
  DaemonError(int code_, std::string text_)
      : std::runtime_error(std::to_string(code_) + ",\"" + text_ + "\""),
        code(code_),
        text(std::move(text_)) {}
  int code;
  std::string text;
};

// A connection used the way a program (not a person) uses it: every line followed by the
// session's error queue, so that an error is an exception and never goes unnoticed.
class Client {
 public:
  Client(const Address& address, double timeout_s) : connection_(address, timeout_s) {}

  // Sends a query, reads its reply, then drains the error queue: the first error queued is
  // thrown as DaemonError (an empty reply always comes with one).
  std::string query(const std::string& line);
  // Sends a command (no reply), then drains the error queue as query() does.
  void command(const std::string& line);
  // Every error in the session's queue, oldest first (the queue is left empty).
  std::vector<DaemonError> drain_errors();

  Connection& connection() { return connection_; }

 private:
  void throw_first_error(const std::string& line, bool reply_empty);
  Connection connection_;
};

}  // namespace idm::client
