// The command server: one thread, epoll over a TCP listener, a Unix-socket listener and every
// client, all non-blocking. Each client has its own protocol Session (protocol.h), a bounded
// input (a too-long line is the Session's -363; streaming more than max_unterminated_bytes with no
// newline at all gets the client disconnected) and a bounded output (a client that does not read
// its replies is disconnected once max_output_bytes are waiting). No client can block the thread.
//
// Threading: start() and stop() from the owner's thread; the Instrument is called from the
// server thread only, one call at a time (instrument.h's contract). stop() wakes the thread
// through an eventfd, closes every client and the listeners, and unlinks the Unix socket.
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <string>
#include <string_view>
#include <thread>

#include "daemon/instrument.h"
#include "drivers/thread.h"

namespace idm::daemon {

using drivers::kLoopStackBytes;
using drivers::kRecorderStackBytes;
using drivers::kServerStackBytes;
using drivers::kSmallStackBytes;
using drivers::StackThread;

// Is `host` (as server.tcp_address gives it) an address of this machine only: 127.0.0.0/8, ::1,
// ::ffff:127.x, "localhost"? A name that would need a lookup, 0.0.0.0 and :: are not.
bool is_loopback_address(std::string_view host);

struct ServerConfig {
  // TCP listener; an empty host: none. Port 0 picks a free port (tcp_port() says which).
  std::string tcp_host = "127.0.0.1";
  int tcp_port = 5025;
  // Unix-socket listener; empty: none. A stale socket file is removed at start (a live one, or a
  // path that is not a socket, is an error); the file is unlinked at stop.
  std::string unix_path;
  unsigned unix_mode = 0660;
  // Clients that may send any command. A client that has closed its sending side while it waits
  // for a reply (*OPC?) no longer counts: it is draining (at most max_clients of those; past that
  // the oldest is closed).
  int max_clients = 16;
  // With the table full, a new client still gets one of these stop-only slots: it may send
  // STOP/ABORt (and read the error queue) for overflow_linger_s, then it is closed; any other
  // command is refused with -221. Past overflow_slots the oldest such client is closed, so that
  // a STOP always gets through.
  int overflow_slots = 4;
  double overflow_linger_s = 2.0;
  // Bytes a client may send without any newline before it is disconnected.
  std::size_t max_unterminated_bytes = std::size_t{1} << 20;
  // Replies a client has not read; more and it is disconnected.
  std::size_t max_output_bytes = std::size_t{1} << 20;
  // While a session waits (*OPC?, *WAI) its later input is held; past this the server stops
  // reading from that client (TCP back-pressure) until the wait ends.
  std::size_t max_held_bytes = std::size_t{64} << 10;
  // How often motion_done() is polled for sessions that wait.
  double wait_poll_s = 0.005;
  // TCP clients must send `*AUTH <token>` before any command that moves or changes a setting
  // (Session::require_token); "": none needed. The Unix socket's file mode is its permission.
  std::string tcp_token;
  // Connections, disconnections and why, one line each (called on the server thread); optional.
  std::function<void(std::string_view)> log;
  // Connections closed because they sent HTTP or a wrong token: one line, then at most one a
  // minute saying how many more (a web page can send many); optional (then `log` gets them).
  std::function<void(std::string_view)> warn;
};

struct ServerCounters {
  std::uint64_t accepted = 0;
  std::uint64_t rejected_max_clients = 0;  // served in a stop-only slot (table full)
  std::uint64_t closed_by_peer = 0;
  std::uint64_t dropped_no_newline = 0;   // streamed past max_unterminated_bytes
  std::uint64_t dropped_slow_reader = 0;  // output past max_output_bytes
  std::uint64_t dropped_error = 0;        // a socket error
  std::uint64_t refused = 0;              // closed: it sent HTTP, or a wrong *AUTH token
};

class Server {
 public:
  Server(Instrument& instrument, ServerConfig config);
  ~Server();  // stop()
  Server(const Server&) = delete;
  Server& operator=(const Server&) = delete;

  // Opens the listeners and starts the thread (listen() first, when it has not been called).
  // Returns "" on success, otherwise what failed ("TCP 127.0.0.1:5025: bind: Address already in
  // use"); then nothing is left open. May be called again after stop().
  [[nodiscard]] std::string start();
  // Binds and listens without serving: clients that connect wait in the backlog until start().
  // idmd binds before it opens a device, so that a second idmd on the same sockets fails before
  // it touches the hardware the first one drives. "" or what failed (nothing left open then).
  [[nodiscard]] std::string listen();
  // Idempotent; returns after the thread has ended and every socket is closed.
  void stop();

  bool running() const { return thread_.joinable(); }
  int tcp_port() const { return tcp_port_; }  // the bound port (after start), -1 without TCP
  const std::string& unix_path() const { return config_.unix_path; }
  int clients() const { return clients_.load(); }
  ServerCounters counters() const;

 private:
  struct Impl;
  void run();
  void close_listeners();

  Instrument& instrument_;
  ServerConfig config_;
  int tcp_fd_ = -1;
  int unix_fd_ = -1;
  int wake_fd_ = -1;
  int epoll_fd_ = -1;
  int tcp_port_ = -1;
  bool unix_bound_ = false;
  std::uint64_t unix_dev_ = 0, unix_ino_ = 0;  // the file we bound, so stop() unlinks only it
  std::atomic<int> clients_{0};
  std::atomic<std::uint64_t> counters_[7] = {};
  StackThread thread_;
};

}  // namespace idm::daemon
