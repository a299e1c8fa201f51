// A client's session: line framing, the AXIS<n>: prefix, the command table and the instrument's
// handlers (the axis commands: session_axis.cpp).
#include <algorithm>
#include <cmath>
#include <exception>
#include <limits>

#include "daemon/protocol.h"
#include "daemon/session_replies.h"
#include "model/yaml_util.h"

namespace idm::daemon {

namespace ec = error_code;
using session_replies::instrument_error;
using session_replies::kUntrusted;
using session_replies::untrusted_position;

namespace {

CommandError quoted_number(std::string_view what) {
  return make_error(ec::kDataTypeError,
                    std::string(what) + ": a quoted string where a number belongs (send it bare)");
}

char upper(char c) {
  return (c >= 'a' && c <= 'z') ? static_cast<char>(c - 'a' + 'A') : c;
}

}  // namespace

bool split_axis_prefix(std::string_view header, int& axis, std::string_view& rest) {
  if (header.size() < 6) return false;
  for (std::size_t i = 0; i < 4; ++i)
    if (upper(header[i]) != "AXIS"[i]) return false;
  std::size_t i = 4;
  long long n = 0;
  while (i < header.size() && header[i] >= '0' && header[i] <= '9') {
    if (n < 1000000) n = n * 10 + (header[i] - '0');
    ++i;
  }
  if (i == 4 || i >= header.size() || header[i] != ':') return false;
  axis = n > 1000000 ? 0 : static_cast<int>(n);
  rest = header.substr(i + 1);
  return true;
}

// ---------------------------------------------------------------------------------------------
// The command table

struct Session::Command {
  CommandInfo info;
  Handler handler;
};

const std::vector<Session::Command>& Session::commands() {
  using S = CommandScope;
  static const std::vector<Command> kCommands = {
      {{"*IDN", true, 0, 0, "", S::Instrument}, &Session::idn},
      {{"*RST", false, 0, 0, "", S::Instrument}, &Session::rst},
      {{"*CLS", false, 0, 0, "", S::Instrument}, &Session::cls},
      {{"*OPC", true, 0, 0, "", S::Instrument}, &Session::opc_query},
      {{"*WAI", false, 0, 0, "", S::Instrument}, &Session::wai},
      {{"*TST", true, 0, 0, "", S::Instrument}, &Session::tst},
      {{"*AUTH", false, 1, 1, "<token>", S::Instrument}, &Session::auth},
      {{"*AUTH", true, 0, 0, "", S::Instrument}, &Session::auth_query},
      {{"*STB", true, 0, 0, "", S::Instrument}, &Session::stb},
      {{"*ESR", true, 0, 0, "", S::Instrument}, &Session::esr},
      {{"*ESE", false, 1, 1, "<mask 0-255>", S::Instrument}, &Session::ese},
      {{"*ESE", true, 0, 0, "", S::Instrument}, &Session::ese_query},
      {{"SYSTem:ERRor[:NEXT]", true, 0, 0, "", S::Instrument}, &Session::error_next},
      {{"SYSTem:ERRor:COUNt", true, 0, 0, "", S::Instrument}, &Session::error_count},
      {{"SYSTem:ERRor:ALL", true, 0, 0, "", S::Instrument}, &Session::error_all},
      {{"SYSTem:VERSion", true, 0, 0, "", S::Instrument}, &Session::version},
      {{"SYSTem:LOOP", true, 0, 0, "", S::Instrument}, &Session::loop},
      {{"SYSTem:CLIents[:COUNt]", true, 0, 0, "", S::Instrument}, &Session::clients},
      {{"SYSTem:CLIents:TABLe", true, 0, 0, "", S::Instrument}, &Session::client_table},
      {{"AXIS:COUNt", true, 0, 0, "", S::Instrument}, &Session::axis_count},
      {{"POSition:ALL", true, 0, 0, "", S::Instrument}, &Session::positions},
      {{"SWEEP", true, 0, 0, "", S::Instrument}, &Session::sweep_query},
      {{"STOP", false, 0, 0, "", S::Either}, &Session::stop},
      {{"ABORt", false, 0, 0, "", S::Either}, &Session::stop},
      {{"NAME", true, 0, 0, "", S::Axis}, &Session::axis_name},
      {{"RESolution", true, 0, 0, "", S::Axis}, &Session::resolution},
      {{"POSition", true, 0, 0, "", S::Axis}, &Session::position},
      {{"POSition:SET", false, 1, 1, "<m>", S::Axis}, &Session::position_set},
      {{"POSition:OFFSet", false, 1, 1, "<m>", S::Axis}, &Session::offset},
      {{"POSition:OFFSet", true, 0, 0, "", S::Axis}, &Session::offset_query},
      {{"MOVE[:ABSolute]", false, 1, 1, "<m>", S::Axis}, &Session::move_absolute},
      {{"MOVE[:ABSolute]", true, 0, 0, "", S::Axis}, &Session::move_target},
      {{"MOVE:RELative", false, 1, 1, "<m>", S::Axis}, &Session::move_relative},
      {{"MOVE:DONE", true, 0, 0, "", S::Axis}, &Session::move_done},
      {{"MOVE:RESult", true, 0, 0, "", S::Axis}, &Session::move_result},
      {{"MOVE:WINDow", false, 1, 1, "<m>", S::Axis}, &Session::window},
      {{"MOVE:WINDow", true, 0, 0, "", S::Axis}, &Session::window_query},
      {{"MOVE:DWELl", false, 1, 1, "<s>", S::Axis}, &Session::dwell},
      {{"MOVE:DWELl", true, 0, 0, "", S::Axis}, &Session::dwell_query},
      {{"MOVE:VELocity", false, 1, 1, "<m/s>", S::Axis}, &Session::speed},
      {{"MOVE:VELocity", true, 0, 0, "", S::Axis}, &Session::speed_query},
      {{"JOG", false, 1, 1, "POSitive|NEGative", S::Axis}, &Session::jog},
      {{"HOLD", false, 1, 1, "<s>", S::Axis}, &Session::hold},
      {{"HOLD", true, 0, 0, "", S::Axis}, &Session::hold_query},
      {{"HOLD:WINDow", false, 1, 1, "<m>", S::Axis}, &Session::hold_window},
      {{"HOLD:WINDow", true, 0, 0, "", S::Axis}, &Session::hold_window_query},
      {{"EOT:STEP", false, 1, 1, "<m>", S::Axis}, &Session::eot_step},
      {{"EOT:STEP", true, 0, 0, "", S::Axis}, &Session::eot_step_query},
      {{"EOT:CYCLes", false, 1, 1, "<n>", S::Axis}, &Session::eot_cycles},
      {{"EOT:CYCLes", true, 0, 0, "", S::Axis}, &Session::eot_cycles_query},
      {{"REFerence[:STARt]", false, 0, 1, "[NEGative|POSitive|MARK]", S::Axis},
       &Session::reference},
      {{"REFerence", true, 0, 0, "", S::Axis}, &Session::reference_query},
      {{"STATus:OPERation[:CONDition]", true, 0, 0, "", S::Axis}, &Session::operation},
      {{"STEP", false, 1, 4, "<n>[,<duty>,<freq_hz>[,<stroke_m>]]", S::Axis}, &Session::step},
      {{"REGion", true, 2, 3, "<freq_hz>,<duty>[,<stroke_m>]", S::Axis}, &Session::region},
      {{"REGion:RANGe", true, 0, 0, "", S::Axis}, &Session::region_range},
      {{"LIMit:LOWer", false, 1, 1, "<m>", S::Axis}, &Session::limit_lower},
      {{"LIMit:UPPer", false, 1, 1, "<m>", S::Axis}, &Session::limit_upper},
      {{"LIMit:LOWer", true, 0, 0, "", S::Axis}, &Session::limit_lower_query},
      {{"LIMit:UPPer", true, 0, 0, "", S::Axis}, &Session::limit_upper_query},
      {{"LIMit", false, 2, 2, "<lower_m>,<upper_m>", S::Axis}, &Session::limits},
      {{"LIMit", true, 0, 0, "", S::Axis}, &Session::limits_query},
      {{"STATus", true, 0, 0, "", S::Axis}, &Session::status},
      {{"SWEEP", false, 4, 5, "<dir>,<freqs>,<duties>,<trials>[,<cycles>]", S::Axis},
       &Session::sweep},
      {{"SIMulation:PUSH", false, 1, 1, "<m>", S::Axis}, &Session::sim_push},
      {{"SIMulation:FAULt", false, 2, 2, "<name>,<value>", S::Axis}, &Session::sim_fault},
  };
  return kCommands;
}

const std::vector<CommandInfo>& command_table() {
  static const std::vector<CommandInfo> kTable = [] {
    std::vector<CommandInfo> out;
    for (const auto& c : Session::commands()) out.push_back(c.info);
    return out;
  }();
  return kTable;
}

// ---------------------------------------------------------------------------------------------
// Framing

Session::Session(Instrument& instrument) : instrument_(instrument) {}

void Session::receive(std::string_view bytes, std::string& replies) {
  const std::size_t newline = bytes.rfind('\n');
  unterminated_ =
      newline == std::string_view::npos ? unterminated_ + bytes.size() : bytes.size() - newline - 1;
  if (discarding_ && wait_ == Wait::None && newline == std::string_view::npos) return;
  input_.append(bytes);
  process(replies);
}

void Session::end_of_input(std::string& replies) {
  end_of_input_ = true;
  process(replies);
}

void Session::poll(std::string& replies) {
  if (wait_ == Wait::None) return;
  std::string reply = "1";
  try {
    if (!instrument_.motion_done()) return;
  } catch (const std::exception& e) {  // end the wait with the error rather than wait forever
    push(make_error(ec::kExecutionError, e.what()));
    reply.clear();
  }
  if (wait_ == Wait::OpcQuery) replies += reply + "\n";
  wait_ = Wait::None;
  process(replies);
}

void Session::process(std::string& replies) {
  std::size_t pos = 0;
  while (wait_ == Wait::None && close_reason_.empty()) {
    const std::size_t newline = input_.find('\n', pos);
    if (newline == std::string::npos) {
      const std::size_t pending = input_.size() - pos;
      // + 1: a CR may still come before the LF
      if (!discarding_ && pending > kMaxLineBytes + 1) {
        line_too_long(std::string_view(input_).substr(pos), replies);
        discarding_ = true;
      }
      // A line being discarded is dropped as it comes; an unterminated last line never runs.
      if (discarding_ || end_of_input_) pos = input_.size();
      break;
    }
    std::string_view line = std::string_view(input_).substr(pos, newline - pos);
    pos = newline + 1;
    if (discarding_) {  // the end of a too-long line, already reported
      discarding_ = false;
      continue;
    }
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    if (refuse_http(line)) break;
    if (line.size() > kMaxLineBytes)
      line_too_long(line, replies);
    else
      execute_line(line, replies);
  }
  if (!close_reason_.empty()) pos = input_.size();  // nothing more of this input runs
  input_.erase(0, pos);
}

bool Session::refuse_http(std::string_view line) {
  if (!looks_like_http(line)) return false;
  close_reason_ = "sent HTTP ('" + replace_controls(line.substr(0, 40)) +
                  "'), not command lines: a web page's request? Closed before any line of it ran";
  return true;
}

void Session::line_too_long(std::string_view start, std::string& replies) {
  if (refuse_http(start.substr(0, kMaxLineBytes))) return;
  push(make_error(ec::kInputBufferOverrun,
                  "line longer than " + std::to_string(kMaxLineBytes) + " bytes, discarded"));
  if (looks_like_query(start)) replies += "\n";
}

void Session::push(CommandError error) {
  // The standard event status register (IEEE 488.2): command errors (-100..-199) bit 5,
  // execution errors (-200..-299) bit 4, device-dependent errors (-300..-399 and the device's
  // positive codes) bit 3, query errors (-400..-499) bit 2.
  const int c = error.code;
  if (c <= -100 && c > -200)
    esr_ |= 1u << 5;
  else if (c <= -200 && c > -300)
    esr_ |= 1u << 4;
  else if ((c <= -300 && c > -400) || c > 0)
    esr_ |= 1u << 3;
  else if (c <= -400 && c > -500)
    esr_ |= 1u << 2;
  errors_.push(std::move(error));
}

void Session::started_motion(const CommandError& result) {
  if (!result.ok() || axis_ >= 64) return;
  started_axes_ |= std::uint64_t{1} << axis_;
  stopped_axes_ &= ~(std::uint64_t{1} << axis_);
}

// A motion this session started has ended: a fault it ended in goes to this session's queue; so
// does the error that ended a sweep it started.
void Session::notice_motion_end() {
  if (started_sweep_) {
    const SweepStatus s = instrument_.sweep_status();
    if (s.state != "RUNNING") {
      started_sweep_ = false;
      if (s.state == "FAILED")
        push(make_error(ec::kExecutionError,
                        "SWEEP " + s.directory + " failed: " +
                            (s.error.empty() ? std::string("no trial was written") : s.error)));
    }
  }
  for (int a = 0; started_axes_ != 0 && a < 64; ++a) {
    const std::uint64_t bit = std::uint64_t{1} << a;
    if (!(started_axes_ & bit) || !instrument_.motion_done(a)) continue;
    started_axes_ &= ~bit;
    const InstrumentStatus s = instrument_.status(a);
    if (s.fault != "none" && !s.fault.empty()) {
      CommandError e = fault_error(s.fault);
      if (s.least_window_m > 0)
        e.text += ": axis " + s.name + " cannot meet a window narrower than " +
                  format_value(s.least_window_m) + " m (*RST, then MOVE:WINDow)";
      push(e);
      continue;
    }
    // Stopped, and not by this client: another client's STOP or *RST ended it.
    if (s.result == "STOPPED" && !(stopped_axes_ & bit)) {
      push(make_error(ec::kMoveStoppedByOther, "axis " + s.name + ": " + s.motion +
                                                   " stopped by another client's STOP or *RST, " +
                                                   format_value(s.result_distance_m) +
                                                   " m from its target"));
      continue;
    }
    // Not in its window: never reported as success. A STEP has no window: only where it was cut
    // short by the travel or the limits.
    const bool step = s.motion == "step";
    for (const MoveResultCode& r : kMoveResults) {
      if (s.result != r.word) continue;
      if (step && r.code != ec::kMoveEndOfTravel && r.code != ec::kMoveLimit) continue;
      push(make_error(r.code, "axis " + s.name + ": " + s.motion + " ended " + s.result + ", " +
                                  format_value(s.result_distance_m) + " m from its target"));
    }
  }
}

// ---------------------------------------------------------------------------------------------
// Dispatch

CommandError Session::resolve(const ParsedLine& parsed, const Command*& command) {
  std::string_view header = parsed.header;
  int axis = 0;
  std::string_view rest;
  axis_given_ = split_axis_prefix(header, axis, rest);
  if (axis_given_) header = rest;
  axis_ = 0;
  command = nullptr;
  for (const Command& c : commands())
    if (c.info.query == parsed.query && header_matches(c.info.pattern, header)) {
      command = &c;
      break;
    }
  if (!command || (axis_given_ && command->info.scope == CommandScope::Instrument)) {
    command = nullptr;
    return make_error(ec::kUndefinedHeader, echo(parsed.header + (parsed.query ? "?" : "")));
  }
  if (axis_given_) {
    const int count = instrument_.axis_count();
    if (axis < 1 || axis > count)
      return make_error(ec::kHeaderSuffixOutOfRange, "AXIS" + std::to_string(axis) +
                                                         ": no such axis, allowed AXIS1 to AXIS" +
                                                         std::to_string(count));
    axis_ = axis - 1;
  }
  if (CommandError e = check_token(*command); !e.ok()) return e;
  if (stop_only_ && command->handler != &Session::stop && command->handler != &Session::idn &&
      command->handler != &Session::cls && command->handler != &Session::error_next &&
      command->handler != &Session::error_count && command->handler != &Session::error_all)
    return make_error(ec::kSettingsConflict,
                      "the client table is full (server.max_clients): this connection only "
                      "accepts STOP and closes soon");
  const int n = static_cast<int>(parsed.args.size());
  const auto usage = [command] {
    return std::string("usage: ") + command->info.pattern + (command->info.query ? "?" : "") +
           (command->info.max_args > 0 ? " " : "") + command->info.arguments;
  };
  if (n > command->info.max_args) return make_error(ec::kParameterNotAllowed, usage());
  if (n < command->info.min_args) return make_error(ec::kMissingParameter, usage());
  return {};
}

void Session::execute_line(std::string_view line, std::string& replies) {
  try {
    notice_motion_end();
  } catch (const std::exception& e) {
    push(make_error(ec::kExecutionError, e.what()));
  }
  const bool query = looks_like_query(line);
  ParsedLine parsed;
  CommandError error = parse_line(line, parsed);
  if (error.ok() && parsed.header.empty()) return;  // a blank line
  const Command* command = nullptr;
  if (error.ok()) error = resolve(parsed, command);
  std::string reply;
  if (error.ok()) {
    try {
      error = (this->*command->handler)(Args{parsed.args, parsed.quoted}, reply);
    } catch (const std::exception& e) {  // an Instrument that throws must not end the server
      error = make_error(ec::kExecutionError, e.what());
    }
    if (wait_ == Wait::OpcQuery) return;  // the reply comes from poll()
  }
  if (!error.ok()) {
    push(std::move(error));
    if (reply != kUntrusted) reply.clear();
  }
  if (query) replies += replace_controls(reply) + "\n";
}

// ---------------------------------------------------------------------------------------------
// Arguments

CommandError Session::number_arg(const Args& args, std::size_t i, std::string_view what,
                                 double& value) {
  if (args.quoted[i]) return quoted_number(what);
  return parse_number(args[i], what, value);
}

CommandError Session::integer_arg(const Args& args, std::size_t i, std::string_view what,
                                  std::int64_t lo, std::int64_t hi, std::int64_t& value) {
  if (args.quoted[i]) return quoted_number(what);
  return parse_integer(args[i], what, lo, hi, value);
}

CommandError Session::list_arg(const Args& args, std::size_t i, std::string_view what,
                               std::vector<double>& values) {
  if (args.quoted[i]) return quoted_number(what);
  return parse_list(args[i], what, values);
}

// ---------------------------------------------------------------------------------------------
// Instrument commands

CommandError Session::idn(const Args&, std::string& reply) {
  reply = instrument_.identity();
  return {};
}

CommandError Session::rst(const Args&, std::string&) {
  errors_.clear();
  started_axes_ = 0;
  started_sweep_ = false;
  return instrument_error(instrument_.reset());
}

CommandError Session::cls(const Args&, std::string&) {
  errors_.clear();
  esr_ = 0;
  return {};
}

int Session::operation_bits(int axis) {
  const InstrumentStatus s = instrument_.status(axis);
  const double window = instrument_.motion_setting(axis, MotionSetting::Window);
  int bits = 0;
  if (!s.motion_done) bits |= 1 << 0;
  if (s.in_position) bits |= 1 << 1;
  if (s.holding) bits |= 1 << 2;
  if (s.referenced) bits |= 1 << 3;
  if (s.position_valid && s.position_m <= s.soft_lower_m + window) bits |= 1 << 4;
  if (s.position_valid && s.position_m >= s.soft_upper_m - window) bits |= 1 << 5;
  if (s.eot != 0) bits |= 1 << 6;
  if (!s.fault.empty() && s.fault != "none") bits |= 1 << 7;
  if (s.position_valid) bits |= 1 << 8;
  if (s.referencing) bits |= 1 << 9;
  return bits;
}

CommandError Session::stb(const Args&, std::string& reply) {
  int stb = 0;
  if (!errors_.empty()) stb |= 1 << 2;  // error/event queue not empty
  if (esr_ & ese_) stb |= 1 << 5;       // event status summary
  bool operating = false;               // operation summary: an axis moving or referencing
  for (int a = 0; a < instrument_.axis_count(); ++a)
    operating = operating || (operation_bits(a) & ((1 << 0) | (1 << 9))) != 0;
  if (operating) stb |= 1 << 7;
  reply = std::to_string(stb);
  return {};
}

CommandError Session::esr(const Args&, std::string& reply) {
  reply = std::to_string(esr_);
  esr_ = 0;  // reading clears it
  return {};
}

CommandError Session::ese(const Args& args, std::string&) {
  std::int64_t mask = 0;
  if (CommandError e = integer_arg(args, 0, "*ESE mask", 0, 255, mask); !e.ok()) return e;
  ese_ = static_cast<std::uint8_t>(mask);
  return {};
}

CommandError Session::ese_query(const Args&, std::string& reply) {
  reply = std::to_string(ese_);
  return {};
}

CommandError Session::operation(const Args&, std::string& reply) {
  reply = std::to_string(operation_bits(axis_));
  return {};
}

CommandError Session::move_result(const Args&, std::string& reply) {
  const InstrumentStatus s = instrument_.status(axis_);
  reply = s.result + "," + format_value(s.result == "NONE" ? 0.0 : s.result_distance_m);
  return {};
}

CommandError Session::set_setting(MotionSetting which, const Args& args, const char* what) {
  double value = 0;
  if (CommandError e = number_arg(args, 0, what, value); !e.ok()) return e;
  return instrument_error(instrument_.set_motion_setting(axis_, which, value));
}

CommandError Session::setting_query(MotionSetting which, std::string& reply) {
  reply = format_value(instrument_.motion_setting(axis_, which));
  return {};
}

CommandError Session::reference(const Args& args, std::string&) {
  ReferenceMethod method = ReferenceMethod::Default;
  if (args.size() == 1) {
    if (args.quoted[0]) return make_error(ec::kDataTypeError, "REFerence: a keyword, not a string");
    if (header_matches("NEGative", args[0]))
      method = ReferenceMethod::Negative;
    else if (header_matches("POSitive", args[0]))
      method = ReferenceMethod::Positive;
    else if (header_matches("MARK", args[0]))
      method = ReferenceMethod::Mark;
    else
      return make_error(ec::kDataOutOfRange,
                        "REFerence: '" + std::string(args[0]) +
                            "' is not allowed, allowed NEGative, POSitive, MARK");
  }
  CommandError e = instrument_error(instrument_.reference(axis_, method));
  started_motion(e);
  return e;
}

CommandError Session::reference_query(const Args&, std::string& reply) {
  reply = instrument_.status(axis_).referenced ? "1" : "0";
  return {};
}

CommandError Session::opc_query(const Args&, std::string& reply) {
  if (instrument_.motion_done())
    reply = "1";
  else
    wait_ = Wait::OpcQuery;
  return {};
}

CommandError Session::wai(const Args&, std::string&) {
  if (!instrument_.motion_done()) wait_ = Wait::Wai;
  return {};
}

CommandError Session::tst(const Args&, std::string& reply) {
  bool ok = true;
  for (int a = 0; a < instrument_.axis_count(); ++a) {
    const InstrumentStatus s = instrument_.status(a);
    ok = ok && s.position_valid && (s.fault.empty() || s.fault == "none");
  }
  reply = ok ? "0" : "1";
  return {};
}

CommandError Session::error_next(const Args&, std::string& reply) {
  reply = format_error(errors_.pop());
  return {};
}

CommandError Session::error_count(const Args&, std::string& reply) {
  reply = std::to_string(errors_.size());
  return {};
}

CommandError Session::error_all(const Args&, std::string& reply) {
  reply.clear();
  do {
    if (!reply.empty()) reply += ",";
    reply += format_error(errors_.pop());
  } while (!errors_.empty());
  return {};
}

CommandError Session::version(const Args&, std::string& reply) {
  reply = kScpiVersion;
  return {};
}

CommandError Session::loop(const Args&, std::string& reply) {
  const LoopStats s = instrument_.loop_stats();
  reply = "period=" + format_value(s.period_s) + " wakeups=" + std::to_string(s.wakeups) +
          " misses=" + std::to_string(s.deadline_misses) + " min=" + format_value(s.latency_min_s) +
          " avg=" + format_value(s.latency_avg_s) + " max=" + format_value(s.latency_max_s) +
          " bin_width=" + format_value(s.bin_width_s) + " hist=";
  for (std::size_t k = 0; k < std::size(s.bins); ++k) {
    if (k) reply += ";";
    reply += std::to_string(s.bins[k]);
  }
  return {};
}

CommandError Session::read_client_table(ClientTableStats& stats) const {
  if (!client_table_)
    return make_error(ec::kExecutionError, "no client table: this session is not on the server");
  stats = client_table_->client_table();
  return {};
}

CommandError Session::clients(const Args&, std::string& reply) {
  ClientTableStats t;
  if (CommandError e = read_client_table(t); !e.ok()) return e;
  reply = std::to_string(t.connected);
  return {};
}

CommandError Session::client_table(const Args&, std::string& reply) {
  ClientTableStats t;
  if (CommandError e = read_client_table(t); !e.ok()) return e;
  reply = "connected=" + std::to_string(t.connected) + " slots=" + std::to_string(t.slots) +
          " max_clients=" + std::to_string(t.max_clients) +
          " stop_only=" + std::to_string(t.stop_only) +
          " overflow_slots=" + std::to_string(t.overflow_slots) +
          " draining=" + std::to_string(t.draining);
  return {};
}

CommandError Session::axis_count(const Args&, std::string& reply) {
  reply = std::to_string(instrument_.axis_count());
  return {};
}

CommandError Session::positions(const Args&, std::string& reply) {
  const std::vector<double> p = instrument_.positions();
  CommandError error;
  for (std::size_t a = 0; a < p.size(); ++a) {
    if (a) reply += ",";
    if (std::isnan(p[a])) {
      reply += kUntrusted;
      if (error.ok()) error = untrusted_position(instrument_.axis_name(static_cast<int>(a)));
    } else {
      reply += format_value(p[a]);
    }
  }
  if (!error.ok()) push(error);  // the reply stands: every trusted position is in it
  return {};
}

CommandError Session::sweep_query(const Args&, std::string& reply) {
  const SweepStatus s = instrument_.sweep_status();
  reply = s.state + "," + std::to_string(s.axis + 1) + "," + std::to_string(s.written) + "," +
          std::to_string(s.failed) + "," + std::to_string(s.planned) + "," + quote(s.directory);
  return {};
}

namespace {

// Equal, in a time that depends on the lengths only (a token is not guessed byte by byte).
bool same_secret(std::string_view a, std::string_view b) {
  unsigned char diff = a.size() == b.size() ? 0 : 1;
  const std::size_t n = std::max(a.size(), b.size());
  for (std::size_t i = 0; i < n; ++i)
    diff |= static_cast<unsigned char>((i < a.size() ? a[i] : 0) ^ (i < b.size() ? b[i] : 0));
  return diff == 0;
}

}  // namespace

CommandError Session::check_token(const Command& command) const {
  if (!token_ || authorised_ || command.info.query) return {};
  const Handler h = command.handler;
  if (h == &Session::stop || h == &Session::cls || h == &Session::wai || h == &Session::auth)
    return {};
  return make_error(ec::kCommandProtected,
                    "this listener needs *AUTH <token> before commands that move or change "
                    "settings (server.auth_token_file); queries and STOP need none");
}

CommandError Session::auth(const Args& args, std::string&) {
  if (!token_ || same_secret(args[0], *token_)) {
    authorised_ = true;
    return {};
  }
  close_reason_ = "sent a wrong *AUTH token";
  return make_error(ec::kCommandProtected, "*AUTH: wrong token; the connection is closed");
}

CommandError Session::auth_query(const Args&, std::string& reply) {
  reply = (!token_ || authorised_) ? "1" : "0";
  return {};
}

CommandError Session::stop(const Args&, std::string&) {
  if (!axis_given_)
    stopped_axes_ = ~std::uint64_t{0};
  else if (axis_ < 64)
    stopped_axes_ |= std::uint64_t{1} << axis_;
  return instrument_error(axis_given_ ? instrument_.stop(axis_) : instrument_.stop());
}

}  // namespace idm::daemon
