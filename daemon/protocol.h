// The idmd command protocol (docs/command-protocol.md): SCPI-style lines in, one reply
// line per query out, errors in a per-session queue. No sockets here: the pure functions below
// (line splitting, keyword matching, numbers, lists, reply formatting) and Session (one client's
// line framing, error queue and command table over an Instrument) are tested on their own; the
// socket server (server.h) only moves bytes in and out of Sessions.
//
// Rules the whole file keeps (see daemon/README.md for the command list):
//  * A line ends in LF (CR LF accepted). At most kMaxLineBytes bytes before the terminator; a
//  longer
//    line is discarded up to its newline and leaves -363 in the queue.
//  * A line whose first word ends in '?' is a query and gets exactly one reply line, also when it
//    fails (then the line is empty and the error is in the queue). Any other line gets none.
//  * Keywords are case-insensitive; a keyword is accepted in its short form (the upper-case part of
//    the pattern: MOVE:ABS for MOVE:ABSolute) or in full, nothing in between (as SCPI says).
//  * Arguments follow the header after white space, separated by commas; "..." quotes a string
//    (a doubled "" inside stands for one "). Numbers: SI units, plain decimal or exponent, finite.
//  * Nothing here blocks: *OPC? and *WAI hold the session's later lines until the instrument says
//    motion_done(); the server calls Session::poll() while a session waits.
#pragma once

#include <cstddef>
#include <cstdint>
#include <deque>
#include <string>
#include <string_view>
#include <vector>

#include "daemon/instrument.h"

namespace idm::daemon {

inline constexpr std::size_t kMaxLineBytes = 4096;
inline constexpr std::size_t kErrorQueueCapacity = 32;
inline constexpr std::size_t kMaxErrorTextBytes = 255;  // SCPI's limit for an error string
inline constexpr std::size_t kMaxListValues = 10000;    // a SWEEP list
inline constexpr char kScpiVersion[] = "1999.0";        // SYSTem:VERSion? (SCPI-99)

// ---------------------------------------------------------------------------------------------
// Pure functions

// "Data out of range" for -222, "Stall" for 102, "Error" for a code it does not know.
const char* standard_error_text(int code);

// An error with its text as the queue holds it: "<standard text>; <detail>" (the detail alone
// when it already starts with the standard text), ASCII printable only, at most
// kMaxErrorTextBytes.
CommandError make_error(int code, std::string_view detail = {});

// User text echoed in an error: 'text', printable ASCII only, at most 40 characters.
std::string echo(std::string_view text);
// Every byte outside printable ASCII replaced by a blank.
std::string replace_controls(std::string_view text);

// SCPI string: quoted, every " doubled.
std::string quote(std::string_view text);
// "<code>,\"<text>\"" as SYSTem:ERRor? replies.
std::string format_error(const CommandError& error);

// A number in a reply: 12 significant digits, locale-independent ("1.234e-07", "0.001", "-3").
// +-infinity as SCPI's +-9.9e+37 and NaN as 9.91e+37, so that a reply is always a finite number.
std::string format_value(double value);

// Is this line a query (its first word ends in '?' within the first kMaxLineBytes bytes)? Decided
// on the raw bytes so that the server and a client agree also on lines that fail to parse, and on
// lines too long, which the server judges by their first kMaxLineBytes + 2 bytes.
bool looks_like_query(std::string_view line);

// Does this line come from an HTTP client rather than from a client of this protocol: a request
// line (a method browsers send and a blank, or anything ending in " HTTP/<version>") or a request
// header a browser sends ("Host:", "Origin:", "Sec-Fetch-Mode:", ...)? Any web page the lab PC's
// browser opens can POST to 127.0.0.1:5025 (a "no-cors" fetch needs no permission); its body would
// be read as command lines. The session closes such a connection before any line of it runs.
bool looks_like_http(std::string_view line);

struct ParsedLine {
  std::string header;  // as sent, without the leading ':' and the trailing '?'
  bool query = false;
  std::vector<std::string> args;  // trimmed; quoted strings unquoted
  std::vector<bool> quoted;       // per argument: it was a "..." string (not a number)
};
// Splits "[:]HEADER[?][ ARG{,ARG}]" (no line terminator). An empty or all-blank line gives an
// empty header. Errors: -101 (a byte outside printable ASCII and tab), -102 (a malformed header,
// an empty argument, an unterminated string).
CommandError parse_line(std::string_view line, ParsedLine& out);

// One keyword against its pattern ("ABSolute" accepts "abs" and "ABSOLUTE", not "abso").
bool keyword_matches(std::string_view pattern, std::string_view word);
// A whole header ("MOVE:ABS", "syst:err:next") against a pattern ("SYSTem:ERRor[:NEXT]", "*IDN");
// [:KEYword] marks an optional keyword.
bool header_matches(std::string_view pattern, std::string_view header);

// A finite number, "[+|-]digits[.digits][e[+|-]digits]" (or ".5"). -120 otherwise (not a number,
// INF/NAN, out of the range of a double). `what` names the argument in the error.
CommandError parse_number(std::string_view text, std::string_view what, double& value);
// An integral number within [lo, hi] ("100", "1e3"): -120 not a number, -222 not integral or out
// of range.
CommandError parse_integer(std::string_view text, std::string_view what, std::int64_t lo,
                           std::int64_t hi, std::int64_t& value);
// "a:b:step" (from a to b inclusive, step > 0), "a;b;c" or a single number; at most
// kMaxListValues values. -120 for a bad number, -102 for an empty item, -222 for a bad range.
CommandError parse_list(std::string_view text, std::string_view what, std::vector<double>& values);

// ---------------------------------------------------------------------------------------------
// The error queue of one session: oldest first, bounded. When it is full, the newest entry is
// replaced by -350 "Queue overflow" (SCPI-99 21.8) and later errors are dropped until it drains.
class ErrorQueue {
 public:
  explicit ErrorQueue(std::size_t capacity = kErrorQueueCapacity);
  void push(CommandError error);
  // The oldest error, removed; {0, "No error"} when empty.
  CommandError pop();
  std::size_t size() const { return queue_.size(); }
  bool empty() const { return queue_.empty(); }
  void clear();
  // The code of the newest error pushed since the last clear() (0: none), dropped ones included.
  int last_code() const { return last_code_; }

 private:
  std::size_t capacity_;
  std::deque<CommandError> queue_;
  int last_code_ = error_code::kNoError;
};

// Where a command applies: to the whole instrument (an AXIS<n>: prefix is -113), to one axis
// (unprefixed: axis 1), or either (STOP: every axis unprefixed, one with AXIS<n>:).
enum class CommandScope : std::uint8_t { Instrument, Axis, Either };

// The commands a Session knows, as (pattern, query); for tests and documentation.
struct CommandInfo {
  const char* pattern;  // "MOVE:ABSolute", "SYSTem:ERRor[:NEXT]"
  bool query;
  int min_args;
  int max_args;
  const char* arguments;  // "<m>", "<n>[,<duty>,<freq_hz>[,<stroke_m>]]", "" for none
  CommandScope scope;
};
const std::vector<CommandInfo>& command_table();

// "AXIS<n>:REST" -> n (1-based) and REST; false when the header has no such prefix. AXIS:COUNt has
// none (it is an instrument command). n = 0 or a number past int's range gives n = 0.
bool split_axis_prefix(std::string_view header, int& axis, std::string_view& rest);

// ---------------------------------------------------------------------------------------------
// The command server's client table, as SYSTem:CLIents? and SYSTem:CLIents:TABLe? report it.
struct ClientTableStats {
  int connected = 0;       // every connection open now, the asking one included
  int slots = 0;           // of those, the ones holding one of max_clients' slots
  int max_clients = 0;     // server.max_clients
  int stop_only = 0;       // in a stop-only slot (the table was full when they came)
  int overflow_slots = 0;  // server.overflow_slots
  int draining = 0;        // half-closed, still owed a *OPC? reply (they hold no slot)
};
// What knows the table: the command server. Called on the server's thread only, which alone
// touches the table, so it needs no lock (and never concerns the real-time loop).
class ClientTable {
 public:
  virtual ~ClientTable() = default;
  virtual ClientTableStats client_table() const = 0;
};

// ---------------------------------------------------------------------------------------------
// One client's session: line framing, the error queue, the command table. Not thread-safe; the
// server calls it from its one thread. The Instrument must outlive it.
class Session {
 public:
  explicit Session(Instrument& instrument);

  // Bytes as they arrive (any split); replies (each ending in "\n") are appended to `replies`.
  void receive(std::string_view bytes, std::string& replies);
  // The peer will send nothing more. A last line without its newline is discarded, never
  // executed: a line runs only once it is terminated (a client that dies mid-line must not move
  // the stage with half a command).
  void end_of_input(std::string& replies);
  // While waiting() (*OPC? or *WAI): resumes once the instrument's motion is done.
  void poll(std::string& replies);
  bool waiting() const { return wait_ != Wait::None; }
  // All input received has been executed (nothing held, no partial line); after end_of_input()
  // this means the session has nothing more to say.
  bool idle() const { return wait_ == Wait::None && input_.empty(); }
  // Bytes received and not yet executed (held behind *OPC?/*WAI, or a partial line).
  std::size_t held_bytes() const { return input_.size(); }
  // Bytes received since the last newline, including a too-long line's discarded part: the server
  // disconnects a client that streams too much without any newline.
  std::size_t unterminated_bytes() const { return unterminated_; }

  const ErrorQueue& errors() const { return errors_; }
  // A stop-only session (the server's overflow slot): STOP, ABORt, *IDN?, *CLS and the error
  // queries run; every other line is refused with -221 naming why.
  void set_stop_only(bool stop_only) { stop_only_ = stop_only; }
  // The table SYSTem:CLIents? reads (the server's; it must outlive the session). Without one
  // (a session outside the server) those queries are -200.
  void set_client_table(const ClientTable* table) { client_table_ = table; }
  // A session on a listener that wants a token (server.auth_token_file on TCP): until `*AUTH
  // <token>` with exactly this token, every command but the queries, STOP/ABORt, *CLS, *WAI and
  // *AUTH is refused with -203. The token must outlive the session; nullptr: none needed.
  void require_token(const std::string* token) { token_ = token; }
  // The session wants its connection closed (once its replies are written), and why: it sent a
  // line of HTTP (nothing of that input runs), or a wrong token. "" while it does not.
  const std::string& close_reason() const { return close_reason_; }

 private:
  enum class Wait { None, OpcQuery, Wai };
  struct Command;
  struct Args {
    std::vector<std::string> text;
    std::vector<bool> quoted;
    std::size_t size() const { return text.size(); }
    const std::string& operator[](std::size_t i) const { return text[i]; }
  };
  using Handler = CommandError (Session::*)(const Args&, std::string&);
  // A numeric argument: -104 when it was sent as a quoted string, else parse_number/parse_integer.
  static CommandError number_arg(const Args& args, std::size_t i, std::string_view what,
                                 double& value);
  static CommandError integer_arg(const Args& args, std::size_t i, std::string_view what,
                                  std::int64_t lo, std::int64_t hi, std::int64_t& value);
  static CommandError list_arg(const Args& args, std::size_t i, std::string_view what,
                               std::vector<double>& values);

  void process(std::string& replies);
  void execute_line(std::string_view line, std::string& replies);
  // Finds the command and the axis of a parsed line; an error when there is none.
  CommandError resolve(const ParsedLine& parsed, const Command*& command);
  void line_too_long(std::string_view start, std::string& replies);
  // A line of HTTP: sets close_reason_ (true), nothing of it runs.
  bool refuse_http(std::string_view line);
  void push(CommandError error);
  void notice_motion_end();
  void started_motion(const CommandError& result);
  // MOVE:ABSolute / MOVE:RELative: the number argument (`what` in its error), then `move`.
  CommandError start_move(const Args& args, std::string_view what,
                          CommandError (Instrument::*move)(int, double));

  // Instrument commands.
  CommandError idn(const Args&, std::string& reply);
  CommandError rst(const Args&, std::string& reply);
  CommandError cls(const Args&, std::string& reply);
  CommandError opc_query(const Args&, std::string& reply);
  CommandError wai(const Args&, std::string& reply);
  CommandError tst(const Args&, std::string& reply);
  CommandError error_next(const Args&, std::string& reply);
  CommandError error_count(const Args&, std::string& reply);
  CommandError error_all(const Args&, std::string& reply);
  CommandError version(const Args&, std::string& reply);
  CommandError loop(const Args&, std::string& reply);
  CommandError clients(const Args&, std::string& reply);
  CommandError client_table(const Args&, std::string& reply);
  CommandError read_client_table(ClientTableStats& stats) const;
  CommandError axis_count(const Args&, std::string& reply);
  CommandError positions(const Args&, std::string& reply);
  CommandError sweep_query(const Args&, std::string& reply);
  CommandError stop(const Args&, std::string& reply);
  CommandError auth(const Args&, std::string& reply);
  CommandError auth_query(const Args&, std::string& reply);
  // Refuses a command the token protects (require_token) while this session has not sent it.
  CommandError check_token(const Command& command) const;
  // Axis commands (axis_: the line's axis).
  CommandError axis_name(const Args&, std::string& reply);
  CommandError resolution(const Args&, std::string& reply);
  CommandError position(const Args&, std::string& reply);
  CommandError position_set(const Args&, std::string& reply);
  CommandError offset(const Args&, std::string& reply);
  CommandError offset_query(const Args&, std::string& reply);
  CommandError move_absolute(const Args&, std::string& reply);
  CommandError move_target(const Args&, std::string& reply);
  CommandError move_relative(const Args&, std::string& reply);
  CommandError move_done(const Args&, std::string& reply);
  CommandError step(const Args&, std::string& reply);
  CommandError region(const Args&, std::string& reply);
  CommandError region_range(const Args&, std::string& reply);
  CommandError limit_lower(const Args&, std::string& reply);
  CommandError limit_upper(const Args&, std::string& reply);
  CommandError limit_lower_query(const Args&, std::string& reply);
  CommandError limit_upper_query(const Args&, std::string& reply);
  CommandError limits(const Args&, std::string& reply);
  CommandError limits_query(const Args&, std::string& reply);
  CommandError status(const Args&, std::string& reply);
  CommandError sweep(const Args&, std::string& reply);
  CommandError sim_push(const Args&, std::string& reply);
  CommandError sim_fault(const Args&, std::string& reply);
  CommandError stb(const Args&, std::string& reply);
  CommandError esr(const Args&, std::string& reply);
  CommandError ese(const Args&, std::string& reply);
  CommandError ese_query(const Args&, std::string& reply);
  CommandError operation(const Args&, std::string& reply);
  CommandError move_result(const Args&, std::string& reply);
  CommandError set_setting(MotionSetting which, const Args&, const char* what);
  CommandError window(const Args& a, std::string&) {
    return set_setting(MotionSetting::Window, a, "MOVE:WINDow");
  }
  CommandError dwell(const Args& a, std::string&) {
    return set_setting(MotionSetting::Dwell, a, "MOVE:DWELl");
  }
  CommandError speed(const Args& a, std::string&) {
    return set_setting(MotionSetting::MaxSpeed, a, "MOVE:VELocity");
  }
  CommandError speed_query(const Args&, std::string& r) {
    return setting_query(MotionSetting::MaxSpeed, r);
  }
  // JOG POSitive|NEGative: a move to that soft limit at the speed limit (MOVE:VELocity), ended
  // by STOP or there.
  CommandError jog(const Args& a, std::string&);
  CommandError eot_step(const Args& a, std::string&) {
    return set_setting(MotionSetting::EotStep, a, "EOT:STEP");
  }
  CommandError eot_cycles(const Args& a, std::string&) {
    return set_setting(MotionSetting::EotCycles, a, "EOT:CYCLes");
  }
  CommandError hold(const Args& a, std::string&) {
    return set_setting(MotionSetting::Hold, a, "HOLD");
  }
  CommandError hold_window(const Args& a, std::string&) {
    return set_setting(MotionSetting::HoldWindow, a, "HOLD:WINDow");
  }
  CommandError window_query(const Args&, std::string& r) {
    return setting_query(MotionSetting::Window, r);
  }
  CommandError dwell_query(const Args&, std::string& r) {
    return setting_query(MotionSetting::Dwell, r);
  }
  CommandError eot_step_query(const Args&, std::string& r) {
    return setting_query(MotionSetting::EotStep, r);
  }
  CommandError eot_cycles_query(const Args&, std::string& r) {
    return setting_query(MotionSetting::EotCycles, r);
  }
  CommandError hold_query(const Args&, std::string& r) {
    return setting_query(MotionSetting::Hold, r);
  }
  CommandError hold_window_query(const Args&, std::string& r) {
    return setting_query(MotionSetting::HoldWindow, r);
  }
  CommandError setting_query(MotionSetting which, std::string& reply);
  CommandError reference(const Args&, std::string& reply);
  CommandError reference_query(const Args&, std::string& reply);
  // STATus:OPERation? of one axis (bits: the spec's extension).
  int operation_bits(int axis);

  static const std::vector<Command>& commands();
  friend const std::vector<CommandInfo>& command_table();

  Instrument& instrument_;
  ErrorQueue errors_;
  std::string input_;  // received, not yet executed
  std::size_t unterminated_ = 0;
  bool discarding_ = false;  // inside a too-long line: drop up to the next newline
  bool end_of_input_ = false;
  Wait wait_ = Wait::None;
  int axis_ = 0;             // the axis of the line being executed (0-based)
  bool axis_given_ = false;  // it came with an AXIS<n>: prefix
  std::uint64_t started_axes_ =
      0;                        // axes (bits) whose motion this session started, not yet seen end
  bool started_sweep_ = false;  // a SWEEP this session started, not yet seen end
  std::uint64_t stopped_axes_ = 0;  // axes (bits) this session sent STOP to since its motion began
  bool stop_only_ = false;
  const ClientTable* client_table_ = nullptr;
  const std::string* token_ = nullptr;
  bool authorised_ = false;
  std::string close_reason_;
  // IEEE 488.2 standard event status register and its enable mask (*ESR?, *ESE).
  std::uint8_t esr_ = 0;
  std::uint8_t ese_ = 0xFF;
};

// The device fault a status reports ("stall", ...) as an error with its positive code
// (kFaultStall, ...); "none" or "" -> kNoError; an unknown name -> kExecutionError.
CommandError fault_error(const std::string& fault_name);

}  // namespace idm::daemon
