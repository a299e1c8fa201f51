// idmctl: the command-line client of idmd (docs/command-protocol.md).
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
#include <signal.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <map>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "client/connection.h"
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
    "  show                        the axis's status in words: state, result of the last move,\n"
    "                              operation bits, status byte, fault reason, end of travel\n"
    "  ref [NEG|POS|MARK]          find the reference (end stop or mark); waits\n"
    "  region FREQ DUTY [STROKE]   CUTOFF, ONESTEP or MULTISTEP and the predicted step\n"
    "  limits [LOWER UPPER]        show or set the soft limits\n"
    "  loop                        real-time loop statistics\n"
    "  reset                       *RST: stop, clear the fault and the errors, reload settings;\n"
    "                              waits\n"
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

using idm::client::Connection;
using idm::client::Interrupted;

bool interrupted() {
  return g_interrupted != 0;
}

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
      done = c.query(g_axis + "MOVE:DONE?", interrupted);
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
    {"show", 0, 0, "show"},
    {"ref", 0, 1, "ref [NEG|POS|MARK]"},
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

// STAT?, STAT:OPER?, *STB? and MOVE:RES? in words, one line each.
int show_status(Connection& c) {
  const std::string stat = c.query(g_axis + "STAT?");
  const std::string oper = c.query(g_axis + "STAT:OPER?");
  const std::string result = c.query(g_axis + "MOVE:RES?");
  const std::string stb = c.query("*STB?");
  if (stat.empty() || oper.empty() || result.empty() || stb.empty()) {
    drain_errors(c);
    return 1;
  }
  std::map<std::string, std::string> kv;
  std::istringstream words(stat);
  for (std::string w; words >> w;)
    if (const std::size_t eq = w.find('='); eq != std::string::npos)
      kv[w.substr(0, eq)] = w.substr(eq + 1);
  const auto spaced = [](std::string t) {
    for (char& ch : t)
      if (ch == '_') ch = ' ';
    return t;
  };
  static const char* const kOper[] = {"moving",
                                      "in position",
                                      "holding",
                                      "referenced",
                                      "at the lower soft limit",
                                      "at the upper soft limit",
                                      "end of travel",
                                      "fault",
                                      "position valid",
                                      "referencing"};
  const long bits = std::strtol(oper.c_str(), nullptr, 10);
  std::string on;
  for (int b = 0; b < 10; ++b)
    if (bits & (1L << b)) on += (on.empty() ? "" : ", ") + std::string(kOper[b]);
  const long sb = std::strtol(stb.c_str(), nullptr, 10);
  std::string sbw;
  if (sb & (1 << 2)) sbw += "errors queued";
  if (sb & (1 << 5)) sbw += std::string(sbw.empty() ? "" : ", ") + "standard event (*ESR?)";
  if (sb & (1 << 7)) sbw += std::string(sbw.empty() ? "" : ", ") + "an axis is moving";
  const std::size_t comma = result.find(',');
  std::printf("axis:        %s (%s)\n", kv["axis"].c_str(), kv["state"].c_str());
  std::printf("position:    %s m, target %s m\n", kv["position"].c_str(), kv["target"].c_str());
  std::printf("last motion: %s, %s m from its target\n", result.substr(0, comma).c_str(),
              comma == std::string::npos ? "?" : result.substr(comma + 1).c_str());
  std::printf("operation:   %ld: %s\n", bits, on.empty() ? "nothing set" : on.c_str());
  std::printf("status byte: %ld: %s\n", sb, sbw.empty() ? "nothing to report" : sbw.c_str());
  std::printf("fault:       %s\n", kv["fault"] == "none"
                                       ? "none"
                                       : (kv["fault"] + ": " + spaced(kv["fault_reason"])).c_str());
  std::printf("end travel:  %s\n", kv["eot"].c_str());
  std::printf("referenced:  %s\n", kv["referenced"] == "1" ? "yes" : "no");
  if (kv["daemon_error"] != "none")
    std::printf("last error:  %s\n", spaced(kv["daemon_error"]).c_str());
  return drain_errors(c) > 0 ? 1 : 0;
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
    if (n < 1 || n > 1e6)
      throw InputError("--axis: " + axis + " is out of range, allowed 1 and up");
    return static_cast<int>(n);
  }
  const std::string count = c.query("AXIS:COUNt?");
  if (drain_errors(c) > 0 || count.empty())
    throw std::runtime_error("the daemon does not know axes");
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
  if (verb == "show") return show_status(c);
  if (verb == "ref")
    return motion(c, g_axis + "REF" + (a.size() > 1 ? " " + a[1] : std::string()), wait, true);
  if (verb == "region") {
    return print_query(c, g_axis + "REG? " + join(a, 1, ","));
  }
  if (verb == "limits") {
    return a.size() == 1 ? print_query(c, g_axis + "LIM?")
                         : command(c, g_axis + "LIM " + join(a, 1, ","));
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

// What the command line asks for.
struct Options {
  idm::client::Address address;  // 127.0.0.1:5025 unless --host, --port or --unix
  double timeout_s = 60;
  bool wait = true;
  std::string axis;               // --axis: a name or number ("" none)
  std::vector<std::string> args;  // the command and its arguments (none: interactive)
  bool help = false;              // --help: print the usage and do nothing else
};

// The command line; InputError for a bad one.
Options parse_options(int argc, char** argv) {
  Options o;
  o.address.host = "127.0.0.1";
  o.address.port = 5025;
  int i = 1;
  bool host_given = false, port_given = false;
  for (; i < argc && std::strncmp(argv[i], "--", 2) == 0; ++i) {
    const std::string flag = argv[i];
    if (flag == "--help") {
      o.help = true;
      return o;
    }
    if (flag == "--no-wait") {
      o.wait = false;
      continue;
    }
    if (flag != "--host" && flag != "--port" && flag != "--unix" && flag != "--timeout" &&
        flag != "--axis")
      throw InputError(flag +
                       ": unknown flag, allowed --host, --port, --unix, --axis, --timeout, "
                       "--no-wait, --help");
    if (i + 1 >= argc) throw InputError(flag + ": missing value");
    const std::string value = argv[++i];
    if (flag == "--host") {
      o.address.host = value;
      host_given = true;
    } else if (flag == "--unix") {
      o.address.unix_path = value;
    } else if (flag == "--axis") {
      if (value.empty() || value.find_first_of(" \t:;,?") != std::string::npos)
        throw InputError("--axis: '" + value + "' is not an axis name or number");
      o.axis = value;
    } else if (flag == "--port") {
      const double p = idm::tools::parse_number(value, "--port");
      if (p != static_cast<int>(p) || p < 1 || p > 65535)
        throw InputError("--port: " + value + " is out of range, allowed 1..65535");
      o.address.port = static_cast<int>(p);
      port_given = true;
    } else {
      o.timeout_s = idm::tools::parse_number(value, "--timeout");
      if (o.timeout_s < 0) throw InputError("--timeout: must be >= 0 (0: no limit)");
    }
  }
  if (!o.address.unix_path.empty() && (host_given || port_given))
    throw InputError("--unix: give either --unix or --host/--port");
  for (; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg.find_first_of("\r\n") != std::string::npos)
      throw InputError("arguments must not hold line breaks (one protocol line per command)");
    o.args.push_back(arg);
  }
  if (!o.args.empty()) check_usage(o.args);
  return o;
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  try {
    o = parse_options(argc, argv);
  } catch (const InputError& e) {
    std::fprintf(stderr, "idmctl: %s\n", e.what());
    return 2;
  }
  if (o.help) {
    std::fputs(kUsage, stdout);
    return 0;
  }

  struct sigaction sa {};
  sa.sa_handler = on_sigint;
  sigemptyset(&sa.sa_mask);
  sigaction(SIGINT, &sa, nullptr);  // no SA_RESTART: a wait sees EINTR
  signal(SIGPIPE, SIG_IGN);

  try {
    Connection c(o.address, o.timeout_s);
    if (!o.axis.empty()) g_axis = "AXIS" + std::to_string(resolve_axis(c, o.axis)) + ":";
    return o.args.empty() ? interactive(c) : run(o.args, c, o.wait);
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
