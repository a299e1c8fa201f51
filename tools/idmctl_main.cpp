// idmctl: the command-line client of idmd (docs/command-protocol.md).
//
//   idmctl [--host H] [--port N] [--unix PATH] [--axis NAME|N] [--unit U] [--timeout S]
//          [--no-wait] [COMMAND [ARG...]]
//
// One-shot verbs send one protocol line each, then drain the session's error queue
// (SYSTem:ERRor?): every error is printed on stderr and the exit status is 1. Moves (move, rel,
// step, jog) wait until the motion is done (polling MOVE:DONE?) unless --no-wait, so a fault the
// motion ended in shows too; Ctrl-C while waiting sends STOP. Without a COMMAND, lines from stdin:
// a line whose first word is one of the verbs runs it, any other is sent as a protocol line; after
// each line the error queue is drained, each error printed naming the line. Exit status: 0 ok, 1 an
// error from the daemon / a timeout / no connection / a failed line, 2 bad usage, 130 interrupted.
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <limits>
#include <map>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "client/connection.h"
#include "client/replies.h"
#include "daemon/protocol.h"
#include "model/stage.h"
#include "model/yaml_util.h"
#include "tools/cli.h"

#ifndef IDM_VERSION
#define IDM_VERSION "0"
#endif

using idm::model::InputError;
using idm::tools::LengthUnit;

namespace {

const char* kUsage =
    "usage: idmctl [--host H] [--port N] [--unix PATH] [--axis NAME|N] [--unit nm|um|mm|m]\n"
    "              [--timeout S] [--no-wait] [COMMAND [ARG...]]\n"
    "       idmctl --help | --version\n"
    "connects to idmd: --unix PATH (its Unix socket) or --host/--port (TCP); without these,\n"
    "IDMD_SOCKET=PATH or IDMD_ADDRESS=HOST:PORT from the environment, else 127.0.0.1:5025\n"
    "--axis: the axis the commands below address, by name (x) or number (1 = the first);\n"
    "        default axis 1 (stop without --axis stops every axis)\n"
    "--unit: lengths printed in nm, um, mm or m (default: metres as idmd sends them)\n"
    "lengths (X, LOWER, UPPER, STROKE) take a unit: 250nm, 1.5um, 2mm, 2e-6m; a bare number is\n"
    "metres (refused with --unit nm, um or mm: ambiguous); a SPEED a unit per second: 400um/s,\n"
    "0.5mm/s, 4e-4m/s (a bare number is m/s, refused likewise); frequencies in Hz\n"
    "commands:\n"
    "  pos                         the position (an error instead when it is not valid)\n"
    "  move X                      closed-loop move to X (absolute); waits, prints the position\n"
    "  rel X  (or moverel X)       closed-loop move by X (relative); waits, prints the position\n"
    "  step N [DUTY FREQ [STROKE]] open-loop burst of |N| cycles; the sign of N alone picks the\n"
    "                              direction (positive N: the positive direction); DUTY is given\n"
    "                              as for the positive direction (mirrored for negative N); waits\n"
    "  jog +|-                     (or positive|negative) a continuous move that way at the\n"
    "                              speed limit, to the soft limit; waits (Ctrl-C: STOP), prints\n"
    "                              the position\n"
    "  velocity [SPEED]            show or set the speed limit of moves and jogs (MOVE:VELocity,\n"
    "                              0: no limit), in --unit per second\n"
    "  setpos X                    the current position becomes X: nothing moves, the user\n"
    "                              offset changes (POSition:SET; at rest); prints the position\n"
    "  offset [X]                  show or set the user offset (POSition:OFFSet): every position\n"
    "                              shown or given is the axis's own plus it\n"
    "  stop                        stop now\n"
    "  wait                        wait until the motion is done\n"
    "  status                      state, position, target, fault, errors (idmd's key=value)\n"
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
    "  (none)                      lines from stdin: a line whose first word is one of the\n"
    "                              commands above runs it (arguments split at blanks or commas);\n"
    "                              any other line is sent as a protocol line and a query's reply\n"
    "                              printed; after each line every error queued is printed on\n"
    "                              stderr with the line's number\n"
    "--timeout S: longest wait for a reply or a motion (default 60, 0: no limit); --no-wait: do\n"
    "not wait for moves. Exit status: 0 ok, 1 error (printed; from stdin: a line failed), 2 bad\n"
    "usage, 130 interrupted.\n";

volatile sig_atomic_t g_interrupted = 0;
void on_sigint(int) {
  g_interrupted = 1;
}

using idm::client::Connection;
using idm::client::Interrupted;

bool interrupted() {
  return g_interrupted != 0;
}

// What the verbs run with: the connection and how the user asked for things.
struct Ctl {
  Connection& c;
  std::string axis;        // "AXIS<n>:" for the per-axis verbs ("" without --axis)
  const LengthUnit* unit;  // --unit (nullptr: lengths printed as idmd sent them)
  bool wait = true;        // not --no-wait
  std::string where;       // "line 3 (move 1um): " for a line from stdin, else ""
};

// Prints and removes every error in the session's queue; returns how many there were.
int drain_errors(Ctl& ctl) {
  int n = 0;
  for (int k = 0; k < 1000; ++k) {
    const std::string reply = ctl.c.query("SYST:ERR?");
    if (reply.rfind("0,", 0) == 0) break;
    std::fprintf(stderr, "idmctl: %serror %s\n", ctl.where.c_str(), reply.c_str());
    ++n;
  }
  return n;
}

// Polls MOVE:DONE? until 1. When `stop_on_interrupt`, Ctrl-C sends STOP (the motion is ours).
void wait_done(Ctl& ctl, bool stop_on_interrupt) {
  Connection& c = ctl.c;
  const auto start = std::chrono::steady_clock::now();
  for (;;) {
    std::string done;
    try {
      done = c.query(ctl.axis + "MOVE:DONE?", interrupted);
    } catch (const Interrupted&) {
      done = c.read_line();
    }
    if (done == "1") return;
    if (done != "0") throw std::runtime_error("MOVE:DONE? answered '" + done + "'");
    if (g_interrupted) {
      if (stop_on_interrupt) {
        c.send_line(ctl.axis + "STOP");
        std::fprintf(stderr, "idmctl: interrupted, sent %sSTOP\n", ctl.axis.c_str());
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
    {"jog", 1, 1, "jog +|-|positive|negative"},
    {"velocity", 0, 1, "velocity [SPEED]"},
    {"setpos", 1, 1, "setpos X"},
    {"offset", 0, 1, "offset [X]"},
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

const Verb* find_verb(const std::string& word) {
  for (const Verb& v : kVerbs)
    if (word == v.name) return &v;
  return nullptr;
}

// The verb and its argument count.
void check_usage(const std::vector<std::string>& a) {
  const Verb* verb = find_verb(a[0]);
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

// A verb and its protocol line (without the axis prefix), checked before anything is sent.
struct Request {
  std::string verb;
  std::string line;
};

// jog's direction: +, -, positive, negative (pos, neg; any case) as the protocol's keyword.
std::string jog_direction(const std::string& word) {
  std::string w = word;
  for (char& ch : w) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
  if (w == "+" || w == "pos" || w == "positive") return "POSitive";
  if (w == "-" || w == "neg" || w == "negative") return "NEGative";
  throw InputError("jog: '" + word + "' is not a direction, allowed +, -, positive, negative");
}

// The protocol line of a verb: lengths read with their units and sent in metres, every other
// argument as it was given (step's N keeps its sign as typed). InputError for bad usage.
Request request_for(const std::vector<std::string>& a, const LengthUnit* bare) {
  check_usage(a);
  const std::string& verb = a[0];
  const auto length = [&](std::size_t k, const char* what) {
    return idm::tools::exact_number(idm::tools::parse_length(a[k], verb + " " + what, bare));
  };
  if (verb == "move") return {verb, "MOVE:ABS " + length(1, "X")};
  if (verb == "rel" || verb == "moverel") return {verb, "MOVE:REL " + length(1, "X")};
  if (verb == "step")
    return {verb, "STEP " + a[1] + (a.size() > 2 ? "," + a[2] + "," + a[3] : "") +
                      (a.size() > 4 ? "," + length(4, "STROKE") : "")};
  if (verb == "region")
    return {verb, "REG? " + a[1] + "," + a[2] + (a.size() > 3 ? "," + length(3, "STROKE") : "")};
  if (verb == "limits")
    return {verb, a.size() == 1 ? "LIM?" : "LIM " + length(1, "LOWER") + "," + length(2, "UPPER")};
  if (verb == "setpos") return {verb, "POS:SET " + length(1, "X")};
  if (verb == "offset") return {verb, a.size() == 1 ? "POS:OFFS?" : "POS:OFFS " + length(1, "X")};
  if (verb == "ref") return {verb, "REF" + (a.size() > 1 ? " " + a[1] : std::string())};
  if (verb == "jog") return {verb, "JOG " + jog_direction(a[1])};
  if (verb == "velocity")
    return {verb, a.size() == 1 ? "MOVE:VEL?"
                                : "MOVE:VEL " + idm::tools::exact_number(idm::tools::parse_speed(
                                                    a[1], "velocity SPEED", bare))};
  if (verb == "raw") return {verb, join(a, 1, " ")};
  static const std::map<std::string, std::string> kFixed = {
      {"pos", "POS?"}, {"stop", "STOP"},       {"wait", ""},      {"status", "STAT?"},
      {"show", ""},    {"loop", "SYST:LOOP?"}, {"reset", "*RST"}, {"idn", "*IDN?"}};
  return {verb, kFixed.at(verb)};
}

// A length from idmd (a number as it sent it) as the user asked for it: unchanged, or in --unit.
std::string in_unit(const Ctl& ctl, const std::string& number) {
  if (!ctl.unit) return number;
  return idm::tools::format_length(idm::client::parse_reply_number(number), *ctl.unit);
}

std::string unit_name(const Ctl& ctl) {
  return ctl.unit ? std::string(ctl.unit->name) : "m";
}

// A query verb: print the reply; errors (and an empty reply) -> 1.
int print_query(Ctl& ctl, const std::string& line) {
  const std::string reply = ctl.c.query(line);
  const int errors = drain_errors(ctl);
  if (!reply.empty()) std::printf("%s\n", reply.c_str());
  std::fflush(stdout);
  return errors > 0 || reply.empty() ? 1 : 0;
}

// POS?: the position, in --unit. One that is not valid (idmd's 9.91E37, SCPI's not-a-number,
// with -230 queued) is never printed as a number: its error is, on stderr, and the status is 1.
int print_position(Ctl& ctl, const std::string& line) {
  const std::string reply = ctl.c.query(line);
  const int errors = drain_errors(ctl);
  double position_m = std::numeric_limits<double>::quiet_NaN();
  try {
    position_m = idm::client::parse_reply_number(reply);
  } catch (const idm::client::ReplyError&) {
  }
  if (!std::isfinite(position_m)) {
    if (errors == 0)
      std::fprintf(stderr, "idmctl: %s%s answered '%s': not a valid position\n", ctl.where.c_str(),
                   line.c_str(), reply.substr(0, 80).c_str());
    return 1;
  }
  std::printf("%s\n", in_unit(ctl, reply).c_str());
  std::fflush(stdout);
  return errors > 0 ? 1 : 0;
}

// One length (POS:OFFS?) or speed (MOVE:VEL?: --unit per second, 0 none) in --unit, as idmd sent
// it without --unit.
int print_length(Ctl& ctl, const std::string& line) {
  const std::string reply = ctl.c.query(line);
  const int errors = drain_errors(ctl);
  if (reply.empty()) return 1;
  std::printf("%s\n", in_unit(ctl, reply).c_str());
  std::fflush(stdout);
  return errors > 0 ? 1 : 0;
}

// LIM? (LOWER,UPPER) and REG? (REGION,STEP): their lengths in --unit.
int print_lengths(Ctl& ctl, const std::string& line, bool first_is_word) {
  const std::string reply = ctl.c.query(line);
  const int errors = drain_errors(ctl);
  if (reply.empty()) return 1;
  std::string shown = reply;
  if (ctl.unit) {
    const std::size_t comma = reply.find(',');
    if (comma == std::string::npos)
      throw idm::client::ReplyError(line + " answered '" + reply + "'");
    const std::string first = reply.substr(0, comma), second = reply.substr(comma + 1);
    shown = (first_is_word ? first : in_unit(ctl, first)) + "," + in_unit(ctl, second);
  }
  std::printf("%s\n", shown.c_str());
  std::fflush(stdout);
  return errors > 0 ? 1 : 0;
}

// STAT?, STAT:OPER?, *STB? and MOVE:RES? in words, one line each.
int show_status(Ctl& ctl) {
  Connection& c = ctl.c;
  const std::string stat = c.query(ctl.axis + "STAT?");
  const std::string oper = c.query(ctl.axis + "STAT:OPER?");
  const std::string result = c.query(ctl.axis + "MOVE:RES?");
  const std::string stb = c.query("*STB?");
  if (stat.empty() || oper.empty() || result.empty() || stb.empty()) {
    drain_errors(ctl);
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
  const auto bits = static_cast<std::uint32_t>(std::strtoul(oper.c_str(), nullptr, 10));
  std::string on;
  for (const std::string& w : idm::client::operation_bit_words(bits))
    on += (on.empty() ? "" : ", ") + w;
  const long sb = std::strtol(stb.c_str(), nullptr, 10);
  std::string sbw;
  if (sb & (1 << 2)) sbw += "errors queued";
  if (sb & (1 << 5)) sbw += std::string(sbw.empty() ? "" : ", ") + "standard event (*ESR?)";
  if (sb & (1 << 7)) sbw += std::string(sbw.empty() ? "" : ", ") + "an axis is moving";
  const std::size_t comma = result.find(',');
  const std::string u = unit_name(ctl);
  const std::string position = kv["position_valid"] == "0" ? std::string("not valid")
                                                           : in_unit(ctl, kv["position"]) + " " + u;
  std::printf("axis:        %s (%s)\n", kv["axis"].c_str(), kv["state"].c_str());
  std::printf("position:    %s, target %s %s\n", position.c_str(),
              in_unit(ctl, kv["target"]).c_str(), u.c_str());
  if (kv.count("offset") && kv["offset"] != "0")
    std::printf("user offset: %s %s (positions are the axis's own plus it)\n",
                in_unit(ctl, kv["offset"]).c_str(), u.c_str());
  std::printf("last motion: %s, %s %s from its target\n", result.substr(0, comma).c_str(),
              comma == std::string::npos ? "?" : in_unit(ctl, result.substr(comma + 1)).c_str(),
              u.c_str());
  std::printf("operation:   %u: %s\n", bits, on.empty() ? "nothing set" : on.c_str());
  std::printf("status byte: %ld: %s\n", sb, sbw.empty() ? "nothing to report" : sbw.c_str());
  std::printf("fault:       %s\n", kv["fault"] == "none"
                                       ? "none"
                                       : (kv["fault"] + ": " + spaced(kv["fault_reason"])).c_str());
  std::printf("end travel:  %s\n", kv["eot"].c_str());
  std::printf("referenced:  %s\n", kv["referenced"] == "1" ? "yes" : "no");
  if (kv["daemon_error"] != "none")
    std::printf("last error:  %s\n", spaced(kv["daemon_error"]).c_str());
  std::fflush(stdout);
  return drain_errors(ctl) > 0 ? 1 : 0;
}

int command(Ctl& ctl, const std::string& line) {
  ctl.c.send_line(line);
  return drain_errors(ctl) > 0 ? 1 : 0;
}

int motion(Ctl& ctl, const std::string& line, bool print_position_after) {
  ctl.c.send_line(line);
  if (!ctl.wait) return drain_errors(ctl) > 0 ? 1 : 0;
  wait_done(ctl, true);
  if (drain_errors(ctl) > 0) return 1;
  return print_position_after ? print_position(ctl, ctl.axis + "POS?") : 0;
}

// A protocol line as it is: the reply of a query printed (even an empty one: one line per
// query), then every error queued.
int protocol_line(Ctl& ctl, const std::string& line) {
  if (idm::daemon::looks_like_query(line)) {
    const std::string reply = ctl.c.query(line);
    std::printf("%s\n", reply.c_str());
    std::fflush(stdout);
  } else {
    ctl.c.send_line(line);
  }
  return drain_errors(ctl) > 0 ? 1 : 0;
}

int run(const Request& r, Ctl& ctl) {
  const std::string& verb = r.verb;
  const std::string line = ctl.axis + r.line;  // the per-axis verbs
  if (verb == "pos") return print_position(ctl, line);
  if (verb == "move" || verb == "rel" || verb == "moverel" || verb == "ref" || verb == "jog")
    return motion(ctl, line, true);
  if (verb == "step") return motion(ctl, line, false);
  if (verb == "stop") return command(ctl, line);
  if (verb == "wait") {
    wait_done(ctl, false);
    return drain_errors(ctl) > 0 ? 1 : 0;
  }
  if (verb == "status") return print_query(ctl, line);
  if (verb == "show") return show_status(ctl);
  if (verb == "region") return print_lengths(ctl, line, true);
  if (verb == "velocity")
    return r.line == "MOVE:VEL?" ? print_length(ctl, line) : command(ctl, line);
  if (verb == "offset") return r.line == "POS:OFFS?" ? print_length(ctl, line) : command(ctl, line);
  if (verb == "setpos") {
    if (command(ctl, line) != 0) return 1;
    return print_position(ctl, ctl.axis + "POS?");
  }
  if (verb == "limits")
    return r.line == "LIM?" ? print_lengths(ctl, line, false) : command(ctl, line);
  // *RST during a sweep completes in the background (MOVE:DONE? is 0 until then): wait for it,
  // so that the next command finds the daemon reset.
  if (verb == "reset") return motion(ctl, r.line, false);
  if (verb == "loop" || verb == "idn") return print_query(ctl, r.line);
  if (verb == "raw") return protocol_line(ctl, r.line);
  throw InputError("unknown command '" + verb + "'");  // request_for() knows every verb
}

// A line from stdin split for a verb: words at blanks, each word at commas (so `step 10,0.1,200`
// reads as `step 10 0.1 200`); raw keeps the rest of the line as it is.
std::vector<std::string> verb_words(const std::string& line) {
  std::istringstream in(line);
  std::vector<std::string> words;
  std::string word;
  in >> word;
  words.push_back(word);
  if (word == "raw") {
    std::string rest;
    std::getline(in, rest);
    const std::size_t first = rest.find_first_not_of(" \t");
    if (first != std::string::npos) words.push_back(rest.substr(first));
    return words;
  }
  while (in >> word) {
    std::istringstream parts(word);
    for (std::string part; std::getline(parts, part, ',');) {
      if (part.empty()) throw InputError("an empty argument in '" + word + "'");
      words.push_back(part);
    }
    if (word.back() == ',') throw InputError("an empty argument in '" + word + "'");
  }
  return words;
}

// One line from stdin; false when it failed (its errors printed).
bool run_line(Ctl& ctl, const std::string& line, const LengthUnit* bare) {
  const std::size_t first = line.find_first_not_of(" \t");
  const std::string head = line.substr(first, line.find_first_of(" \t", first) - first);
  if (!find_verb(head)) return protocol_line(ctl, line) == 0;
  try {
    return run(request_for(verb_words(line.substr(first)), bare), ctl) == 0;
  } catch (const InputError& e) {
    std::fprintf(stderr, "idmctl: %s%s\n", ctl.where.c_str(), e.what());
    return false;
  }
}

// Lines from stdin (a prompt on a terminal). Blank lines are skipped. 1 when a line failed.
int run_lines(Ctl& ctl, const LengthUnit* bare) {
  const bool tty = isatty(STDIN_FILENO);
  int number = 0, lines = 0, failed = 0;
  std::string line;
  for (;;) {
    if (tty) std::fputs("idm> ", stderr);
    if (!std::getline(std::cin, line)) break;
    ++number;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.find_first_not_of(" \t") == std::string::npos) continue;
    ++lines;
    ctl.where = "line " + std::to_string(number) + " (" +
                (line.size() > 60 ? line.substr(0, 60) + "..." : line) + "): ";
    if (!run_line(ctl, line, bare)) ++failed;
  }
  if (tty) std::fputs("\n", stderr);
  if (failed > 0) std::fprintf(stderr, "idmctl: %d of %d lines failed\n", failed, lines);
  return failed > 0 ? 1 : 0;
}

// --axis: a number is taken as it is (the daemon checks it: -114); a name is looked up with
// AXIS:COUNt? and AXIS<n>:NAME?.
int resolve_axis(Ctl& ctl, const std::string& axis) {
  if (axis.find_first_not_of("0123456789") == std::string::npos) {
    const double n = idm::tools::parse_number(axis, "--axis");
    if (n < 1 || n > 1e6)
      throw InputError("--axis: " + axis + " is out of range, allowed 1 and up");
    return static_cast<int>(n);
  }
  const std::string count = ctl.c.query("AXIS:COUNt?");
  if (drain_errors(ctl) > 0 || count.empty())
    throw std::runtime_error("the daemon does not know axes");
  const int n = static_cast<int>(idm::tools::parse_number(count, "AXIS:COUNt?"));
  std::string names;
  for (int k = 1; k <= n; ++k) {
    const std::string name = ctl.c.query("AXIS" + std::to_string(k) + ":NAME?");
    if (name == axis) return k;
    names += (names.empty() ? "" : ", ") + name;
  }
  throw InputError("--axis: no axis '" + axis + "', the daemon has " + names);
}

// What the command line asks for.
struct Options {
  idm::client::Address address;  // the flags', else the environment's, else 127.0.0.1:5025
  double timeout_s = 60;
  bool wait = true;
  std::string axis;                  // --axis: a name or number ("" none)
  const LengthUnit* unit = nullptr;  // --unit (nullptr: none given)
  const LengthUnit* bare = nullptr;  // a length without a unit: metres, or refused
  std::vector<std::string> args;     // the command and its arguments (none: stdin's lines)
  Request request;                   // what args ask for
  bool help = false;                 // --help: print the usage and do nothing else
  bool version = false;              // --version: likewise, the version
};

const char* const kValueFlags[] = {"--host", "--port", "--unix", "--axis", "--unit", "--timeout"};

// One of kValueFlags and its value; `tcp_given`/`unix_given` note an address flag.
void take_value_flag(Options& o, const std::string& flag, const std::string& value, bool& tcp_given,
                     bool& unix_given) {
  if (flag == "--host") {
    o.address.host = value;
    tcp_given = true;
  } else if (flag == "--port") {
    const double p = idm::tools::parse_number(value, "--port");
    if (p != static_cast<int>(p) || p < 1 || p > 65535)
      throw InputError("--port: " + value + " is out of range, allowed 1..65535");
    o.address.port = static_cast<int>(p);
    tcp_given = true;
  } else if (flag == "--unix") {
    if (value.empty()) throw InputError("--unix: an empty path");
    o.address.unix_path = value;
    unix_given = true;
  } else if (flag == "--axis") {
    if (value.empty() || value.find_first_of(" \t:;,?") != std::string::npos)
      throw InputError("--axis: '" + value + "' is not an axis name or number");
    o.axis = value;
  } else if (flag == "--unit") {
    o.unit = idm::tools::find_length_unit(value);
    if (!o.unit)
      throw InputError("--unit: '" + value + "' is not a unit, allowed " +
                       idm::tools::length_unit_names());
  } else {
    o.timeout_s = idm::tools::parse_number(value, "--timeout");
    if (o.timeout_s < 0) throw InputError("--timeout: must be >= 0 (0: no limit)");
  }
}

// The command line; InputError for a bad one. The address: --unix or --host/--port, else
// IDMD_SOCKET or IDMD_ADDRESS (client::address_from_environment, as idm-web and idm-tango).
Options parse_options(int argc, char** argv) {
  Options o;
  int i = 1;
  bool tcp_given = false, unix_given = false;
  for (; i < argc && std::strncmp(argv[i], "--", 2) == 0; ++i) {
    const std::string flag = argv[i];
    if (flag == "--help" || flag == "--version") {
      (flag == "--help" ? o.help : o.version) = true;
      return o;
    }
    if (flag == "--no-wait") {
      o.wait = false;
      continue;
    }
    if (std::find(std::begin(kValueFlags), std::end(kValueFlags), flag) == std::end(kValueFlags))
      throw InputError(flag +
                       ": unknown flag, allowed --host, --port, --unix, --axis, --unit, "
                       "--timeout, --no-wait, --help, --version");
    if (i + 1 >= argc) throw InputError(flag + ": missing value");
    take_value_flag(o, flag, argv[++i], tcp_given, unix_given);
  }
  if (unix_given && tcp_given) throw InputError("--unix: give either --unix or --host/--port");
  if (!unix_given && !tcp_given) {
    try {
      o.address = idm::client::address_from_environment();
    } catch (const idm::client::AddressError& e) {
      throw InputError(e.what());
    }
  }
  o.bare = (!o.unit || o.unit->name == "m") ? idm::tools::find_length_unit("m") : nullptr;
  for (; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg.find_first_of("\r\n") != std::string::npos)
      throw InputError("arguments must not hold line breaks (one protocol line per command)");
    o.args.push_back(arg);
  }
  if (!o.args.empty()) o.request = request_for(o.args, o.bare);
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
  if (o.help || o.version) {
    std::fputs(o.help ? kUsage : "idmctl " IDM_VERSION "\n", stdout);
    return 0;
  }

  struct sigaction sa {};
  sa.sa_handler = on_sigint;
  sigemptyset(&sa.sa_mask);
  sigaction(SIGINT, &sa, nullptr);  // no SA_RESTART: a wait sees EINTR
  signal(SIGPIPE, SIG_IGN);

  try {
    Connection c(o.address, o.timeout_s);
    Ctl ctl{c, "", o.unit, o.wait, ""};
    if (!o.axis.empty()) ctl.axis = "AXIS" + std::to_string(resolve_axis(ctl, o.axis)) + ":";
    return o.args.empty() ? run_lines(ctl, o.bare) : run(o.request, ctl);
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
