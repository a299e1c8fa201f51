// idmctl: the command-line client of idmd (../shared/specs/command-protocol.md).
//
//   idmctl [--host H] [--port N] [--unix PATH] [--axis NAME|N] [--timeout S] [--no-wait]
//          [COMMAND [ARG...]]
//
// One-shot verbs send one protocol line each, then drain the session's error queue
// (SYSTem:ERRor?): every error is printed on stderr and the exit status is 1. Moves (move, rel,
// step) wait until the motion is done (polling MOVE:DONE?) unless --no-wait, so a fault the motion
// ended in shows too; Ctrl-C while waiting sends STOP. Without a COMMAND: interactive, lines from
// stdin are sent as they are and the reply of every query is printed.
// Exit status: 0 ok, 1 an error from the daemon / a timeout / no connection, 2 bad usage,
// 130 interrupted.
#include <netdb.h>
#include <poll.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <stdexcept>
#include <string>
#include <vector>

#include "daemon/protocol.h"
#include "model/stage.h"
#include "model/yaml_util.h"
#include "tools/cli.h"

using idm::model::InputError;

namespace {

const char* kUsage =
    "usage: idmctl [--host H] [--port N] [--unix PATH] [--axis NAME|N] [--timeout S] [--no-wait]\n"
    "              [COMMAND [ARG...]]\n"
    "connects to idmd (default TCP 127.0.0.1:5025; --unix PATH for its Unix socket)\n"
    "--axis: the axis the commands below address, by name (x) or number (1 = the first);\n"
    "        default axis 1 (stop without --axis stops every axis)\n"
    "commands (lengths in m, frequencies in Hz):\n"
    "  pos                         the position\n"
    "  move X                      closed-loop move to X (absolute); waits, prints the position\n"
    "  rel X  (or moverel X)       closed-loop move by X (relative); waits, prints the position\n"
    "  step N [DUTY FREQ [STROKE]] open-loop burst of N cycles (negative: the other way); waits\n"
    "  stop                        stop now\n"
    "  wait                        wait until the motion is done\n"
    "  status                      state, position, target, fault, errors (key=value)\n"
    "  region FREQ DUTY [STROKE]   CUTOFF, ONESTEP or MULTISTEP and the predicted step\n"
    "  limits [LOWER UPPER]        show or set the soft limits\n"
    "  loop                        real-time loop statistics\n"
    "  reset                       *RST: stop, clear the fault and the errors, reload settings; waits\n"
    "  idn                         *IDN?\n"
    "  raw LINE...                 send one protocol line (the arguments joined by spaces)\n"
    "  (none)                      interactive: send stdin's lines, print the replies of queries\n"
    "--timeout S: longest wait for a reply or a motion (default 60, 0: no limit); --no-wait: do "
    "not\n"
    "wait for moves. Exit status: 0 ok, 1 error (printed), 2 bad usage, 130 interrupted.\n";

volatile sig_atomic_t g_interrupted = 0;
// "AXIS<n>:" for the per-axis verbs ("" without --axis).
std::string g_axis;
void on_sigint(int) {
  g_interrupted = 1;
}

struct Interrupted {};

// One connection to the daemon, line by line, every read bounded by the timeout.
class Connection {
 public:
  Connection(const std::string& host, int port, const std::string& unix_path, double timeout_s)
      : timeout_s_(timeout_s) {
    if (!unix_path.empty()) {
      address_ = "unix socket " + unix_path;
      sockaddr_un a{};
      a.sun_family = AF_UNIX;
      if (unix_path.size() >= sizeof a.sun_path)
        throw std::runtime_error(address_ + ": path too long");
      std::memcpy(a.sun_path, unix_path.c_str(), unix_path.size() + 1);
      fd_ = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
      if (fd_ < 0 || connect(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0)
        fail_connect(std::strerror(errno));
      return;
    }
    address_ = (host.find(':') != std::string::npos ? "[" + host + "]" : host) + ":" +
               std::to_string(port);
    addrinfo hints{};
    hints.ai_family = AF_UNSPEC;
    hints.ai_socktype = SOCK_STREAM;
    hints.ai_flags = AI_NUMERICSERV;
    addrinfo* list = nullptr;
    if (const int rc = getaddrinfo(host.c_str(), std::to_string(port).c_str(), &hints, &list);
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
  ~Connection() {
    if (fd_ >= 0) close(fd_);
  }
  Connection(const Connection&) = delete;
  Connection& operator=(const Connection&) = delete;

  void send_line(const std::string& line) {
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

  // One reply line. Ctrl-C while waiting throws Interrupted when `interruptible`.
  std::string read_line(bool interruptible = false) {
    const auto start = std::chrono::steady_clock::now();
    for (;;) {
      if (const std::size_t nl = buffer_.find('\n'); nl != std::string::npos) {
        std::string line = buffer_.substr(0, nl);
        buffer_.erase(0, nl + 1);
        if (!line.empty() && line.back() == '\r') line.pop_back();
        return line;
      }
      if (interruptible && g_interrupted) throw Interrupted{};
      int wait_ms = 200;
      if (timeout_s_ > 0) {
        const double left = timeout_s_ - seconds_since(start);
        if (left <= 0)
          throw std::runtime_error(address_ + ": no reply within " +
                                   idm::model::format_number(timeout_s_) + " s (--timeout)");
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
      buffer_.append(buf, static_cast<std::size_t>(n));
    }
  }

  std::string query(const std::string& line, bool interruptible = false) {
    send_line(line);
    return read_line(interruptible);
  }

  double timeout_s() const { return timeout_s_; }

  static double seconds_since(std::chrono::steady_clock::time_point t) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
  }

 private:
  [[noreturn]] void fail_connect(const std::string& why) {
    if (fd_ >= 0) close(fd_);
    fd_ = -1;
    throw std::runtime_error("cannot connect to " + address_ + ": " + why);
  }

  int fd_ = -1;
  std::string address_;
  std::string buffer_;
  double timeout_s_;
};

// Prints and removes every error in the session's queue; returns how many there were.
int drain_errors(Connection& c) {
  int n = 0;
  for (int k = 0; k < 1000; ++k) {
    const std::string reply = c.query("SYST:ERR?");
    if (reply.rfind("0,", 0) == 0) break;
    std::fprintf(stderr, "idmctl: error %s\n", reply.c_str());
    ++n;
  }
  return n;
}

// Polls MOVE:DONE? until 1. When `stop_on_interrupt`, Ctrl-C sends STOP (the motion is ours).
void wait_done(Connection& c, bool stop_on_interrupt) {
  const auto start = std::chrono::steady_clock::now();
  for (;;) {
    std::string done;
    try {
      done = c.query(g_axis + "MOVE:DONE?", true);
    } catch (const Interrupted&) {
      done = c.read_line();
    }
    if (done == "1") return;
    if (done != "0") throw std::runtime_error("MOVE:DONE? answered '" + done + "'");
    if (g_interrupted) {
      if (stop_on_interrupt) {
        c.send_line(g_axis + "STOP");
        std::fprintf(stderr, "idmctl: interrupted, sent %sSTOP\n", g_axis.c_str());
      }
      throw Interrupted{};
    }
    if (c.timeout_s() > 0 && Connection::seconds_since(start) > c.timeout_s())
      throw std::runtime_error("the motion did not end within " +
                               idm::model::format_number(c.timeout_s()) +
                               " s (--timeout); it goes on (idmctl stop to stop it)");
    usleep(20000);
  }
}

std::string join(const std::vector<std::string>& args, std::size_t first, const std::string& sep) {
  std::string out;
  for (std::size_t k = first; k < args.size(); ++k) out += (k > first ? sep : "") + args[k];
  return out;
}

struct Verb {
  const char* name;
  std::size_t min_args, max_args;
  const char* usage;
};
const Verb kVerbs[] = {
    {"pos", 0, 0, "pos"},
    {"move", 1, 1, "move X"},
    {"rel", 1, 1, "rel X"},
    {"moverel", 1, 1, "moverel X"},
    {"step", 1, 4, "step N [DUTY FREQ [STROKE]]"},
    {"stop", 0, 0, "stop"},
    {"wait", 0, 0, "wait"},
    {"status", 0, 0, "status"},
    {"region", 2, 3, "region FREQ DUTY [STROKE]"},
    {"limits", 0, 2, "limits [LOWER UPPER]"},
    {"loop", 0, 0, "loop"},
    {"reset", 0, 0, "reset"},
    {"idn", 0, 0, "idn"},
    {"raw", 1, 1000000, "raw LINE..."},
};

// Before connecting: the verb and its argument count.
void check_usage(const std::vector<std::string>& a) {
  const Verb* verb = nullptr;
  for (const Verb& v : kVerbs)
    if (a[0] == v.name) verb = &v;
  if (!verb) {
    std::string names;
    for (const Verb& v : kVerbs) names += (names.empty() ? "" : ", ") + std::string(v.name);
    throw InputError("unknown command '" + a[0] + "', allowed " + names + " (idmctl --help)");
  }
  const std::size_t n = a.size() - 1;
  if (n < verb->min_args || n > verb->max_args || (a[0] == "step" && n == 2) ||
      (a[0] == "limits" && n == 1))
    throw InputError(a[0] + ": usage: idmctl " + verb->usage);
}

// A query verb: print the reply; errors (and an empty reply) -> 1.
int print_query(Connection& c, const std::string& line) {
  const std::string reply = c.query(line);
  const int errors = drain_errors(c);
  if (!reply.empty()) std::printf("%s\n", reply.c_str());
  return errors > 0 || reply.empty() ? 1 : 0;
}

int command(Connection& c, const std::string& line) {
  c.send_line(line);
  return drain_errors(c) > 0 ? 1 : 0;
}

int motion(Connection& c, const std::string& line, bool wait, bool print_position) {
  c.send_line(line);
  if (!wait) return drain_errors(c) > 0 ? 1 : 0;
  wait_done(c, true);
  if (drain_errors(c) > 0) return 1;
  return print_position ? print_query(c, g_axis + "POS?") : 0;
}

int interactive(Connection& c) {
  const bool tty = isatty(STDIN_FILENO);
  std::string line;
  for (;;) {
    if (tty) std::fputs("idm> ", stderr);
    if (!std::getline(std::cin, line)) break;
    c.send_line(line);
    if (idm::daemon::looks_like_query(line)) {
      std::printf("%s\n", c.read_line().c_str());
      std::fflush(stdout);
    }
  }
  if (tty) std::fputs("\n", stderr);
  return 0;
}

// --axis: a number is taken as it is (the daemon checks it: -114); a name is looked up with
// AXIS:COUNt? and AXIS<n>:NAME?.
int resolve_axis(Connection& c, const std::string& axis) {
  if (axis.find_first_not_of("0123456789") == std::string::npos) {
    const double n = idm::tools::parse_number(axis, "--axis");
    if (n < 1 || n > 1e6) throw InputError("--axis: " + axis + " is out of range, allowed 1 and up");
    return static_cast<int>(n);
  }
  const std::string count = c.query("AXIS:COUNt?");
  if (drain_errors(c) > 0 || count.empty()) throw std::runtime_error("the daemon does not know axes");
  const int n = static_cast<int>(idm::tools::parse_number(count, "AXIS:COUNt?"));
  std::string names;
  for (int k = 1; k <= n; ++k) {
    const std::string name = c.query("AXIS" + std::to_string(k) + ":NAME?");
    if (name == axis) return k;
    names += (names.empty() ? "" : ", ") + name;
  }
  throw InputError("--axis: no axis '" + axis + "', the daemon has " + names);
}

int run(const std::vector<std::string>& a, Connection& c, bool wait) {
  const std::string& verb = a[0];
  if (verb == "pos") {
    return print_query(c, g_axis + "POS?");
  }
  if (verb == "move") {
    return motion(c, g_axis + "MOVE:ABS " + a[1], wait, true);
  }
  if (verb == "rel" || verb == "moverel") {
    return motion(c, g_axis + "MOVE:REL " + a[1], wait, true);
  }
  if (verb == "step") {
    return motion(c, g_axis + "STEP " + join(a, 1, ","), wait, false);
  }
  if (verb == "stop") {
    return command(c, g_axis + "STOP");
  }
  if (verb == "wait") {
    wait_done(c, false);
    return drain_errors(c) > 0 ? 1 : 0;
  }
  if (verb == "status") {
    return print_query(c, g_axis + "STAT?");
  }
  if (verb == "region") {
    return print_query(c, g_axis + "REG? " + join(a, 1, ","));
  }
  if (verb == "limits") {
    return a.size() == 1 ? print_query(c, g_axis + "LIM?") : command(c, g_axis + "LIM " + join(a, 1, ","));
  }
  if (verb == "loop") {
    return print_query(c, "SYST:LOOP?");
  }
  if (verb == "reset") {
    // *RST during a sweep completes in the background (MOVE:DONE? is 0 until then): wait for it,
    // so that the next command finds the daemon reset.
    return motion(c, "*RST", wait, false);
  }
  if (verb == "idn") {
    return print_query(c, "*IDN?");
  }
  if (verb == "raw") {
    const std::string line = join(a, 1, " ");
    if (idm::daemon::looks_like_query(line)) {
      const std::string reply = c.query(line);
      std::printf("%s\n", reply.c_str());
      std::fflush(stdout);
    } else {
      c.send_line(line);
    }
    return drain_errors(c) > 0 ? 1 : 0;
  }
  throw InputError("unknown command '" + verb + "'");  // check_usage() knows every verb
}

}  // namespace

int main(int argc, char** argv) {
  std::string host = "127.0.0.1", unix_path;
  int port = 5025;
  double timeout_s = 60;
  bool wait = true;
  std::vector<std::string> args;
  std::string axis;
  try {
    int i = 1;
    bool host_given = false, port_given = false;
    for (; i < argc && std::strncmp(argv[i], "--", 2) == 0; ++i) {
      const std::string flag = argv[i];
      if (flag == "--help") {
        std::fputs(kUsage, stdout);
        return 0;
      }
      if (flag == "--no-wait") {
        wait = false;
        continue;
      }
      if (flag != "--host" && flag != "--port" && flag != "--unix" && flag != "--timeout" &&
          flag != "--axis")
        throw InputError(flag + ": unknown flag, allowed --host, --port, --unix, --axis, --timeout, "
                                "--no-wait, --help");
      if (i + 1 >= argc) throw InputError(flag + ": missing value");
      const std::string value = argv[++i];
      if (flag == "--host") {
        host = value;
        host_given = true;
      } else if (flag == "--unix") {
        unix_path = value;
      } else if (flag == "--axis") {
        if (value.empty() || value.find_first_of(" \t:;,?") != std::string::npos)
          throw InputError("--axis: '" + value + "' is not an axis name or number");
        axis = value;
      } else if (flag == "--port") {
        const double p = idm::tools::parse_number(value, "--port");
        if (p != static_cast<int>(p) || p < 1 || p > 65535)
          throw InputError("--port: " + value + " is out of range, allowed 1..65535");
        port = static_cast<int>(p);
        port_given = true;
      } else {
        timeout_s = idm::tools::parse_number(value, "--timeout");
        if (timeout_s < 0) throw InputError("--timeout: must be >= 0 (0: no limit)");
      }
    }
    if (!unix_path.empty() && (host_given || port_given))
      throw InputError("--unix: give either --unix or --host/--port");
    for (; i < argc; ++i) {
      const std::string arg = argv[i];
      if (arg.find_first_of("\r\n") != std::string::npos)
        throw InputError("arguments must not hold line breaks (one protocol line per command)");
      args.push_back(arg);
    }
    if (!args.empty()) check_usage(args);
  } catch (const InputError& e) {
    std::fprintf(stderr, "idmctl: %s\n", e.what());
    return 2;
  }

  struct sigaction sa {};
  sa.sa_handler = on_sigint;
  sigemptyset(&sa.sa_mask);
  sigaction(SIGINT, &sa, nullptr);  // no SA_RESTART: a wait sees EINTR
  signal(SIGPIPE, SIG_IGN);

  try {
    Connection c(host, port, unix_path, timeout_s);
    if (!axis.empty()) g_axis = "AXIS" + std::to_string(resolve_axis(c, axis)) + ":";
    return args.empty() ? interactive(c) : run(args, c, wait);
  } catch (const InputError& e) {
    std::fprintf(stderr, "idmctl: %s\n", e.what());
    return 2;
  } catch (const Interrupted&) {
    return 130;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "idmctl: %s\n", e.what());
    return 1;
  }
}
