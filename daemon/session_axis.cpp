// A client's session, the axis commands: position, moves, steps, the region query, limits,
// status, sweeps and the simulated stage's commands (the rest: session.cpp).
#include <cmath>

#include "daemon/protocol.h"
#include "daemon/session_replies.h"
#include "model/yaml_util.h"

namespace idm::daemon {

namespace ec = error_code;
using session_replies::instrument_error;
using session_replies::kUntrusted;
using session_replies::untrusted_position;

namespace {

// A fault in words, for people reading STAT?.
std::string fault_reason(const std::string& fault) {
  static const struct {
    const char* name;
    const char* words;
  } kReasons[] = {
      {"none", "none"},
      {"invalid_sample",
       "the interferometer gave an invalid reading (beam lost, glitch or count continuity lost)"},
      {"stall", "the slider did not move although driven"},
      {"retry_limit", "the target was not reached within the allowed corrections"},
      {"driver", "the output device refused or failed a command"},
      {"no_plan", "no cell of the map moves toward the target"},
      {"capture_overrun", "the interferometer capture overflowed during a burst"},
      {"device_lost", "the device stopped answering"},
      {"window_unreachable",
       "the window is narrower than the stage's finest steps can land in (least_window)"},
  };
  for (const auto& r : kReasons)
    if (fault == r.name) return r.words;
  return fault;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Axis commands

CommandError Session::axis_name(const Args&, std::string& reply) {
  reply = instrument_.axis_name(axis_);
  return {};
}

CommandError Session::resolution(const Args&, std::string& reply) {
  reply = format_value(instrument_.status(axis_).resolution_m);
  return {};
}

CommandError Session::position(const Args&, std::string& reply) {
  const InstrumentStatus s = instrument_.status(axis_);
  if (!s.position_valid) {
    reply = kUntrusted;  // never empty, never the last good value
    return untrusted_position(s.name);
  }
  reply = format_value(s.position_m);
  return {};
}

CommandError Session::position_set(const Args& args, std::string&) {
  double position = 0;
  if (CommandError e = number_arg(args, 0, "POSition:SET position", position); !e.ok()) return e;
  return instrument_error(instrument_.set_position(axis_, position));
}

CommandError Session::offset(const Args& args, std::string&) {
  double offset = 0;
  if (CommandError e = number_arg(args, 0, "POSition:OFFSet", offset); !e.ok()) return e;
  return instrument_error(instrument_.set_user_offset(axis_, offset));
}

CommandError Session::offset_query(const Args&, std::string& reply) {
  reply = format_value(instrument_.status(axis_).user_offset_m);
  return {};
}

CommandError Session::move_absolute(const Args& args, std::string&) {
  return start_move(args, "MOVE:ABSolute target", &Instrument::move_absolute);
}

CommandError Session::move_target(const Args&, std::string& reply) {
  reply = format_value(instrument_.status(axis_).target_m);
  return {};
}

CommandError Session::move_relative(const Args& args, std::string&) {
  return start_move(args, "MOVE:RELative distance", &Instrument::move_relative);
}

CommandError Session::start_move(const Args& args, std::string_view what,
                                 CommandError (Instrument::*move)(int, double)) {
  double value_m = 0;
  if (CommandError e = number_arg(args, 0, what, value_m); !e.ok()) return e;
  CommandError e = instrument_error((instrument_.*move)(axis_, value_m));
  started_motion(e);
  return e;
}

CommandError Session::jog(const Args& args, std::string&) {
  if (args.quoted[0]) return make_error(ec::kDataTypeError, "JOG: a keyword, not a string");
  int sign = 0;
  if (header_matches("POSitive", args[0]))
    sign = 1;
  else if (header_matches("NEGative", args[0]))
    sign = -1;
  else
    return make_error(ec::kDataOutOfRange, "JOG: '" + std::string(args[0]) +
                                               "' is not allowed, allowed POSitive, NEGative");
  // A move to the soft limit that way, less the window (it lands within its window of the
  // target: inside the limits, where the reading-based stop does not take a landing for a
  // runaway): the motion gate, the end of travel and MOVE:VELocity apply as to any move; STOP
  // ends it.
  const InstrumentStatus s = instrument_.status(axis_);
  const double window_m = instrument_.motion_setting(axis_, MotionSetting::Window);
  const double target_m = sign > 0 ? s.soft_upper_m - window_m : s.soft_lower_m + window_m;
  CommandError e = instrument_error(instrument_.move_absolute(axis_, target_m));
  started_motion(e);
  return e;
}

CommandError Session::move_done(const Args&, std::string& reply) {
  reply = instrument_.motion_done(axis_) ? "1" : "0";
  return {};
}

CommandError Session::step(const Args& args, std::string&) {
  if (args.size() == 2)
    return make_error(ec::kMissingParameter, "STEP takes <n> or <n>,<duty>,<freq_hz>[,<stroke_m>]");
  std::int64_t cycles = 0;
  constexpr double kOmitted = std::numeric_limits<double>::quiet_NaN();
  double duty = kOmitted, freq = kOmitted, stroke = kOmitted;
  if (CommandError e = integer_arg(args, 0, "STEP cycles", -1000000000, 1000000000, cycles);
      !e.ok())
    return e;
  if (cycles == 0)
    return make_error(ec::kDataOutOfRange,
                      "STEP cycles: 0 is out of range, allowed a non-zero "
                      "integer in [-1000000000, 1000000000]");
  if (args.size() >= 3) {
    if (CommandError e = number_arg(args, 1, "STEP duty", duty); !e.ok()) return e;
    if (CommandError e = number_arg(args, 2, "STEP freq_hz", freq); !e.ok()) return e;
  }
  if (args.size() == 4)
    if (CommandError e = number_arg(args, 3, "STEP stroke_m", stroke); !e.ok()) return e;
  CommandError e = instrument_error(instrument_.step(axis_, cycles, duty, freq, stroke));
  started_motion(e);
  return e;
}

CommandError Session::region(const Args& args, std::string& reply) {
  double freq = 0, duty = 0, stroke = std::numeric_limits<double>::quiet_NaN();
  if (CommandError e = number_arg(args, 0, "REGion freq_hz", freq); !e.ok()) return e;
  if (CommandError e = number_arg(args, 1, "REGion duty", duty); !e.ok()) return e;
  if (args.size() == 3)
    if (CommandError e = number_arg(args, 2, "REGion stroke_m", stroke); !e.ok()) return e;
  std::string name;
  double step_m = 0;
  if (CommandError e = instrument_.region(axis_, freq, duty, stroke, name, step_m); !e.ok())
    return instrument_error(e);
  reply = name + "," + format_value(step_m);
  return {};
}

CommandError Session::region_range(const Args&, std::string& reply) {
  const Instrument::RegionRange r = instrument_.region_range(axis_);
  reply = format_value(r.min_freq_hz) + "," + format_value(r.max_freq_hz) + "," +
          format_value(r.min_stroke_m) + "," + format_value(r.max_stroke_m);
  return {};
}

CommandError Session::limit_lower(const Args& args, std::string&) {
  double lower = 0;
  if (CommandError e = number_arg(args, 0, "LIMit:LOWer", lower); !e.ok()) return e;
  return instrument_error(
      instrument_.set_soft_limits(axis_, lower, instrument_.status(axis_).soft_upper_m));
}

CommandError Session::limit_upper(const Args& args, std::string&) {
  double upper = 0;
  if (CommandError e = number_arg(args, 0, "LIMit:UPPer", upper); !e.ok()) return e;
  return instrument_error(
      instrument_.set_soft_limits(axis_, instrument_.status(axis_).soft_lower_m, upper));
}

CommandError Session::limit_lower_query(const Args&, std::string& reply) {
  reply = format_value(instrument_.status(axis_).soft_lower_m);
  return {};
}

CommandError Session::limit_upper_query(const Args&, std::string& reply) {
  reply = format_value(instrument_.status(axis_).soft_upper_m);
  return {};
}

CommandError Session::limits(const Args& args, std::string&) {
  double lower = 0, upper = 0;
  if (CommandError e = number_arg(args, 0, "LIMit lower", lower); !e.ok()) return e;
  if (CommandError e = number_arg(args, 1, "LIMit upper", upper); !e.ok()) return e;
  return instrument_error(instrument_.set_soft_limits(axis_, lower, upper));
}

CommandError Session::limits_query(const Args&, std::string& reply) {
  const InstrumentStatus s = instrument_.status(axis_);
  reply = format_value(s.soft_lower_m) + "," + format_value(s.soft_upper_m);
  return {};
}

CommandError Session::status(const Args&, std::string& reply) {
  const InstrumentStatus s = instrument_.status(axis_);
  // key=value words separated by blanks: a value never holds a blank
  const auto word = [](const std::string& w) {
    std::string out = w.empty() ? std::string("none") : w;
    for (char& c : out)
      if (c == ' ' || c == '\t') c = '_';
    return out;
  };
  reply = "state=" + word(s.state) + " done=" + (s.motion_done ? "1" : "0") +
          " position=" + (s.position_valid ? format_value(s.position_m) : std::string(kUntrusted)) +
          " position_valid=" + (s.position_valid ? "1" : "0") +
          " target=" + format_value(s.target_m) + " fault=" + word(s.fault) +
          " lower=" + format_value(s.soft_lower_m) + " upper=" + format_value(s.soft_upper_m) +
          " moves=" + std::to_string(s.moves) + " bursts=" + std::to_string(s.bursts) +
          " cycles=" + std::to_string(s.cycles) + " errors=" + std::to_string(errors_.size()) +
          " last_error=" + std::to_string(errors_.last_code()) +
          " daemon_error=" + word(replace_controls(s.last_error)) + " axis=" + word(s.name) +
          " referenced=" + (s.referenced ? "1" : "0") + " device=" + word(s.device) +
          " result=" + s.result + " eot=" +
          (s.eot < 0   ? "low"
           : s.eot > 0 ? "high"
                       : "none") +
          " in_position=" + (s.in_position ? "1" : "0") + " holding=" + (s.holding ? "1" : "0") +
          " referencing=" + (s.referencing ? "1" : "0") +
          " fault_reason=" + word(fault_reason(s.fault)) +
          " offset=" + format_value(s.user_offset_m) +
          " least_window=" + format_value(s.least_window_m);
  return {};
}

CommandError Session::sweep(const Args& args, std::string&) {
  const std::string& dir = args[0];
  if (dir.empty()) return make_error(ec::kDataOutOfRange, "SWEEP: empty directory");
  std::vector<double> freqs, duties;
  if (CommandError e = list_arg(args, 1, "SWEEP freqs", freqs); !e.ok()) return e;
  if (CommandError e = list_arg(args, 2, "SWEEP duties", duties); !e.ok()) return e;
  std::int64_t trials = 0, cycles = 12;
  if (CommandError e = integer_arg(args, 3, "SWEEP trials", 1, kMaxSweepTrials, trials); !e.ok())
    return e;
  if (args.size() == 5)
    if (CommandError e = integer_arg(args, 4, "SWEEP cycles", 1, kMaxSweepCycles, cycles); !e.ok())
      return e;
  CommandError e = instrument_error(instrument_.sweep(
      axis_, dir, freqs, duties, static_cast<int>(trials), static_cast<int>(cycles)));
  started_sweep_ = started_sweep_ || e.ok();
  return e;
}

CommandError Session::sim_push(const Args& args, std::string&) {
  double distance = 0;
  if (CommandError e = number_arg(args, 0, "SIMulation:PUSH distance", distance); !e.ok()) return e;
  return instrument_error(instrument_.sim_push(axis_, distance));
}

CommandError Session::sim_fault(const Args& args, std::string&) {
  double value = 0;
  if (CommandError e = number_arg(args, 1, "SIMulation:FAULt value", value); !e.ok()) return e;
  std::string name = args[0];
  for (char& c : name) c = static_cast<char>(c >= 'A' && c <= 'Z' ? c - 'A' + 'a' : c);
  return instrument_error(instrument_.sim_fault(axis_, name, value));
}

}  // namespace idm::daemon
