// The Instrument commands of the daemon core (the server thread): argument checks that need the
// axis's settings, the commands through the motion supervisor, and the status snapshots.
#include <sys/statvfs.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>

#include "daemon/daemon.h"
#include "daemon/data_dir.h"
#include "drivers/clock.h"
#include "model/yaml_util.h"

#ifndef IDM_VERSION
#define IDM_VERSION "0"
#endif

namespace idm::daemon {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

std::string num(double v) {
  return model::format_number(v);
}

// A position is trusted while the axis holds it valid and its device is up: the link says a
// device is lost at once, the loop marks the axis's position a tick later, and a client that sees
// device=lost must not read a number in between.
bool position_trusted(const AxisPublished& p, drivers::LinkState device) {
  return p.motion.position_valid && device == drivers::LinkState::Up;
}

// The user offsets allowed (POSition:OFFSet, POSition:SET), as a refusal states them.
std::string offset_range() {
  return "[" + num(-kMaxUserOffsetM) + ", " + num(kMaxUserOffsetM) + "] m";
}

}  // namespace

std::string Daemon::identity() {
  return std::string("idm,idmd,0,") + IDM_VERSION;
}

std::string Daemon::axis_name(int axis) {
  return axes_.at(static_cast<std::size_t>(axis))->config().name;
}

// ---- commands through the loop ----

CommandError Daemon::submit(AxisCommand command) {
  const MotionSupervisor::Ack ack = supervisor_->submit(command, *loop_);
  if (!ack.taken)
    return {error_code::kExecutionError, "the real-time loop did not take the command"};
  return refusal_error(command, ack.refusal, ack.target_m);
}

CommandError Daemon::fault_error(control::MotionFault fault) {
  const char* name = control::motion_fault_name(fault);
  const std::string text = std::string("in FAULT (") + name + "): send *RST to clear it";
  for (const DeviceFault& f : kDeviceFaults)
    if (std::strcmp(f.name, name) == 0) return {f.code, text};
  return {error_code::kSettingsConflict, text};
}

CommandError Daemon::refusal_error(const AxisCommand& command, control::Refusal r, double target) {
  const int axis = command.axis;
  if (r == control::Refusal::None) return {};
  const Axis& a = *axes_.at(static_cast<std::size_t>(std::max(axis, 0)));
  const AxisPublished p = a.published();
  const double off = a.user_offset_m();  // the message speaks the client's frame
  switch (r) {
    case control::Refusal::None:
      return {};
    case control::Refusal::NotFinite:
      return {error_code::kNumericDataError, "the argument is not a finite number"};
    case control::Refusal::OutsideSoftLimits:
      return {error_code::kDataOutOfRange,
              (std::isnan(target) ? std::string("the motion's end")
                                  : "target " + num(target + off) + " m") +
                  " is outside the soft limits [" + num(p.soft_lower_m + off) + ", " +
                  num(p.soft_upper_m + off) + "] m; nothing moved"};
    case control::Refusal::Faulted:
      return fault_error(p.motion.fault);
    case control::Refusal::Busy:
      if (command.is<axis_command::SetLimits>())
        return {error_code::kSettingsConflict, "the motion in progress ends at " +
                                                   num(p.motion.target_m + off) +
                                                   " m, outside the new limits: STOP it first"};
      if (supervisor_->stopping())
        return {error_code::kSettingsConflict, "the daemon is shutting down"};
      if (p.trial_active || (sweeps_ && sweeps_->active()))
        return {error_code::kSettingsConflict, "a sweep is running: STOP it first"};
      return {error_code::kSettingsConflict,
              "a motion is in progress: STOP it or wait for MOVE:DONE? 1"};
    case control::Refusal::OutOfRange:
      if (command.is<axis_command::Reference>())
        return {error_code::kSettingsConflict, "REFerence: no cell of the map moves that way"};
      return {error_code::kDataOutOfRange,
              "outside the device limits (cycles, duty, frequency or stroke)"};
    case control::Refusal::NoPosition:
      return {error_code::kDataCorruptOrStale,
              "the position is not known (no valid interferometer reading)"};
    case control::Refusal::EndOfTravel:
      return {error_code::kSettingsConflict,
              std::string("the axis stopped at its end of travel (") +
                  (p.motion.eot < 0 ? "low" : "high") +
                  "): only motion away from it is allowed (or REFerence)"};
    case control::Refusal::NotReferenced:
      return {
          error_code::kSettingsConflict,
          "the axis is not referenced (require_reference): REFerence it first, or MOVE:RELative"};
    case control::Refusal::Reloading:
      return {error_code::kSettingsConflict,
              "a reload of the settings (SIGHUP, or a *RST after a sweep) waits for the motions "
              "in progress to end; try again once MOVE:DONE? is 1 on every axis"};
  }
  return {error_code::kExecutionError, control::refusal_name(r)};
}

CommandError Daemon::move_absolute(int axis, double target_m) {
  AxisCommand c;
  c.axis = axis;
  c.body = axis_command::MoveAbsolute{target_m -
                                      axes_.at(static_cast<std::size_t>(axis))->user_offset_m()};
  return submit(c);
}

CommandError Daemon::move_relative(int axis, double distance_m) {
  AxisCommand c;
  c.axis = axis;
  c.body = axis_command::MoveRelative{distance_m};
  return submit(c);
}

CommandError Daemon::step(int axis, std::int64_t cycles, double duty, double freq_hz,
                          double stroke_m) {
  if (cycles == 0) return {error_code::kDataOutOfRange, "STEP cycles: must not be 0"};
  const bool cell_given = !std::isnan(duty) || !std::isnan(freq_hz);
  if (cell_given && (std::isnan(duty) || std::isnan(freq_hz)))
    return {error_code::kMissingParameter, "STEP takes <n> or <n>,<duty>,<freq_hz>[,<stroke_m>]"};
  if (!std::isnan(stroke_m) && !cell_given)
    return {error_code::kMissingParameter, "STEP stroke_m needs duty and freq_hz before it"};
  const auto out_of_range = [](const char* what, double v, const std::string& allowed) {
    return CommandError{error_code::kDataOutOfRange, std::string("STEP ") + what + ": " + num(v) +
                                                         " is out of range, allowed " + allowed};
  };
  control::DeviceLimits limits;
  {
    std::lock_guard<std::mutex> lock(control_mutex_);
    limits = axes_.at(static_cast<std::size_t>(axis))->limits();
  }
  if (cell_given) {
    if (!(duty > 0 && duty < 1) || duty == 0.5)
      return out_of_range("duty", duty, "(0, 1) except 0.5 (the sign of n picks the direction)");
    if (!(freq_hz >= limits.min_freq_hz && freq_hz <= limits.max_freq_hz))
      return out_of_range("freq_hz", freq_hz,
                          "[" + num(limits.min_freq_hz) + ", " + num(limits.max_freq_hz) + "] Hz");
  }
  if (!std::isnan(stroke_m) &&
      !(stroke_m >= limits.min_stroke_m && stroke_m <= limits.max_stroke_m))
    return out_of_range("stroke_m", stroke_m,
                        "[" + num(limits.min_stroke_m) + ", " + num(limits.max_stroke_m) + "] m");
  AxisCommand c;
  c.axis = axis;
  c.body = axis_command::Step{cycles, duty, freq_hz, stroke_m};
  return submit(c);
}

CommandError Daemon::stop() {
  if (sweeps_) sweeps_->abort();  // between trials too: the next one is never asked for
  AxisCommand c;                  // Stop, every axis
  c.axis = -1;
  return submit(c);
}

CommandError Daemon::stop(int axis) {
  if (sweeps_ && sweeps_->active() && sweeps_->status().axis == axis) sweeps_->abort();
  AxisCommand c;  // Stop
  c.axis = axis;
  return submit(c);
}

CommandError Daemon::set_soft_limits(int axis, double lower_m, double upper_m) {
  if (std::isnan(lower_m) || std::isnan(upper_m))
    return {error_code::kNumericDataError, "a soft limit is not a number"};
  if (!(lower_m < upper_m))
    return {error_code::kDataOutOfRange, "the lower limit " + num(lower_m) +
                                             " m must be below the upper limit " + num(upper_m) +
                                             " m"};
  const Axis& a = *axes_.at(static_cast<std::size_t>(axis));
  const model::StageFile& st = a.config().stage;
  // The travel is the stage's (the dial frame); the client gave user-frame limits.
  const double off = a.user_offset_m();
  const std::string travel = "the stage's travel [" + num(st.travel_lower_m + off) + ", " +
                             num(st.travel_upper_m + off) + "] m" +
                             (off != 0 ? " (with the user offset " + num(off) + " m)" : "");
  // A limit at the travel's end read back (LIM?: 12 significant digits, in the user frame) and
  // written again differs from it by that rounding: within it, it is the travel's end.
  const auto at_edge = [off](double user_m, double edge_m) {
    return std::fabs(user_m - off - edge_m) <= 1e-12 * std::max(std::fabs(user_m), 1e-3);
  };
  double lower_dial_m = lower_m - off, upper_dial_m = upper_m - off;
  if (lower_dial_m < st.travel_lower_m) {
    if (!at_edge(lower_m, st.travel_lower_m))
      return {error_code::kDataOutOfRange,
              "the lower limit " + num(lower_m) + " m lies outside " + travel};
    lower_dial_m = st.travel_lower_m;
  }
  if (upper_dial_m > st.travel_upper_m) {
    if (!at_edge(upper_m, st.travel_upper_m))
      return {error_code::kDataOutOfRange,
              "the upper limit " + num(upper_m) + " m lies outside " + travel};
    upper_dial_m = st.travel_upper_m;
  }
  AxisCommand c;
  c.axis = axis;
  c.body = axis_command::SetLimits{lower_dial_m, upper_dial_m};
  return submit(c);
}

CommandError Daemon::set_user_offset(int axis, double offset_m) {
  if (std::isnan(offset_m))
    return {error_code::kNumericDataError, "POSition:OFFSet: the offset is not a number"};
  if (!(std::fabs(offset_m) <= kMaxUserOffsetM))
    return {error_code::kDataOutOfRange,
            "POSition:OFFSet: " + num(offset_m) + " m is out of range, allowed " + offset_range()};
  Axis& a = *axes_.at(static_cast<std::size_t>(axis));
  const double before = a.user_offset_m();
  a.set_user_offset_m(offset_m);
  if (offset_m != before)
    housekeeping_->note(false, "axis " + a.config().name + ": user offset " + num(before) +
                                   " m -> " + num(offset_m) +
                                   " m (positions, targets and soft limits read " +
                                   num(offset_m - before) + " m more)");
  return {};
}

CommandError Daemon::set_position(int axis, double position_m) {
  if (std::isnan(position_m))
    return {error_code::kNumericDataError, "POSition:SET: the position is not a number"};
  Axis& a = *axes_.at(static_cast<std::size_t>(axis));
  const AxisPublished p = a.published();
  // At rest, so that "the current position" is one number (a reading averaged at rest), and a
  // move's target does not shift under it while it plays.
  if (!motion_done(axis))
    return {error_code::kSettingsConflict,
            "POSition:SET: a motion is in progress: STOP it or wait for MOVE:DONE? 1"};
  if (!position_trusted(p, a.link().health().state))
    return {error_code::kDataCorruptOrStale,
            "POSition:SET: the position is not known (no valid interferometer reading)"};
  const double offset_m = position_m - p.motion.position_m;
  if (!(std::fabs(offset_m) <= kMaxUserOffsetM))
    return {error_code::kDataOutOfRange, "POSition:SET: " + num(position_m) +
                                             " m would need a user offset of " + num(offset_m) +
                                             " m, allowed " + offset_range()};
  return set_user_offset(axis, offset_m);
}

// The value against the key's own range, then the axis's config as it stands now (the file's,
// with the settings commands have changed) with the value in it against every relation the file
// is checked against (a window of at least one count, a hold window no smaller than the move
// window, ...): what the file would refuse, the protocol refuses, naming the key it breaks.
CommandError Daemon::check_setting(int axis, const MotionSettings& now, const char* command,
                                   const char* key, double value) {
  ControlConfig probe;
  {
    std::lock_guard<std::mutex> lock(control_mutex_);
    probe = axes_.at(static_cast<std::size_t>(axis))->control();
  }
  control::PositionerConfig& pc = probe.positioner;
  pc.tolerance_m = now.window_m;
  pc.dwell_s = now.dwell_s;
  pc.max_speed_m_s = now.max_speed_m_s;
  pc.eot_step_m = now.eot_step_m;
  pc.eot_cycles = now.eot_cycles;
  pc.hold_s = now.hold_s;
  pc.hold_window_m = now.hold_window_set_m;
  try {
    control_params().set(probe, key, value, command);
  } catch (const model::InputError& e) {
    return {error_code::kDataOutOfRange, e.what()};
  }
  try {
    control_params().check_relations(probe, YAML::Node(YAML::NodeType::Undefined), "", "control");
  } catch (const model::InputError& e) {
    return {error_code::kDataOutOfRange,
            std::string(command) + " " + model::format_number(value) +
                " breaks a relation of the axis's settings: " + e.what()};
  }
  return {};
}

CommandError Daemon::set_motion_setting(int axis, MotionSetting which, double value) {
  // The command's name and the config key (control.*) whose table checks the value: one range
  // for the file, the protocol and the positioner.
  static const struct {
    const char* command;
    const char* key;
  } kSetting[] = {{"MOVE:WINDow", "tolerance_m"},
                  {"MOVE:DWELl", "dwell_s"},
                  {"EOT:STEP", "eot_step_m"},
                  {"EOT:CYCLes", "eot_cycles"},
                  {"HOLD", "hold_s"},
                  {"HOLD:WINDow", "hold_window_m"},
                  {"MOVE:VELocity", "max_speed_m_s"}};
  const auto& r = kSetting[static_cast<std::size_t>(which)];
  if (!std::isfinite(value))
    return {error_code::kNumericDataError, std::string(r.command) + ": not a finite number"};
  const AxisPublished p = axes_.at(static_cast<std::size_t>(axis))->published();
  if (CommandError e = check_setting(axis, p.settings, r.command, r.key, value); !e.ok()) return e;
  AxisCommand c;
  c.axis = axis;
  namespace ac = axis_command;
  switch (which) {
    case MotionSetting::Window:
      c.body = ac::SetWindow{value};
      break;
    case MotionSetting::Dwell:
      c.body = ac::SetDwell{value};
      break;
    case MotionSetting::MaxSpeed:
      c.body = ac::SetSpeed{value};
      break;
    case MotionSetting::EotStep:
      c.body = ac::SetEot{value, p.settings.eot_cycles};
      break;
    case MotionSetting::EotCycles:
      c.body = ac::SetEot{p.settings.eot_step_m, static_cast<int>(value)};
      break;
    case MotionSetting::Hold:
      c.body = ac::SetHold{value, p.settings.hold_window_set_m};
      break;
    case MotionSetting::HoldWindow:
      c.body = ac::SetHold{p.settings.hold_s, value};
      break;
  }
  return submit(c);
}

double Daemon::motion_setting(int axis, MotionSetting which) {
  const MotionSettings s = axes_.at(static_cast<std::size_t>(axis))->published().settings;
  switch (which) {
    case MotionSetting::Window:
      return s.window_m;
    case MotionSetting::Dwell:
      return s.dwell_s;
    case MotionSetting::MaxSpeed:
      return s.max_speed_m_s;
    case MotionSetting::EotStep:
      return s.eot_step_m;
    case MotionSetting::EotCycles:
      return s.eot_cycles;
    case MotionSetting::Hold:
      return s.hold_s;
    case MotionSetting::HoldWindow:
      return s.hold_window_m;
  }
  return kNaN;
}

CommandError Daemon::reference(int axis, ReferenceMethod method) {
  const Axis& a = *axes_.at(static_cast<std::size_t>(axis));
  const AxisConfig& cfg = a.config();
  if (method == ReferenceMethod::Default)
    method = cfg.reference == AxisConfig::Reference::Positive ? ReferenceMethod::Positive
             : cfg.reference == AxisConfig::Reference::Mark   ? ReferenceMethod::Mark
                                                              : ReferenceMethod::Negative;
  AxisCommand c;
  c.axis = axis;
  if (method == ReferenceMethod::Mark) {
    if (!a.has_reference_mark())
      return {error_code::kSettingsConflict,
              "REFerence MARK: axis " + cfg.name +
                  "'s interferometer reports no reference mark; use NEGative or POSitive"};
    // The search drives the configured way first (and turns at an end stop); the mark reads
    // reference_position_m, 0 when not configured.
    c.body = axis_command::Reference{
        cfg.reference_mark_search == AxisConfig::Reference::Positive ? 1 : -1,
        std::isnan(cfg.reference_position_m) ? 0.0 : cfg.reference_position_m, true};
    return submit(c);
  }
  const bool negative = method == ReferenceMethod::Negative;
  double at = cfg.reference_position_m;
  if (std::isnan(at)) at = negative ? cfg.stage.travel_lower_m : cfg.stage.travel_upper_m;
  c.body = axis_command::Reference{negative ? -1 : 1, at, false};
  return submit(c);
}

CommandError Daemon::reset() {
  if (CommandError e = stop(); !e.ok()) return e;
  errors_cleared_s_ = drivers::monotonic_s();  // after the stop: what it stopped is cleared too
  if (housekeeping_->reload_pending())
    return {};  // one is on its way: the stop above ends
                // what it waits for
  if (sweeps_->active()) {
    // The sweep winds down on the recorder thread; rather than hold the server thread (and every
    // other client) meanwhile, housekeeping reloads the settings once it has ended, without
    // stopping a move another client started since (it waits for it). motion_done() is false
    // until then, so "*RST;*OPC?" waits for the reset to be complete.
    housekeeping_->request_reload(false, "*RST after the sweep");
    return {};
  }
  // No sweep: the loop parks at the playing chunks' ends (at most control.max_chunk_s).
  std::string error;
  if (!reload_control(error, SoftLimits::Keep))
    return {error_code::kExecutionError, "*RST: " + error};
  return {};
}

// ---- queries ----

bool Daemon::motion_done() {
  if (sweeps_->active() || housekeeping_->reload_pending()) return false;
  return supervisor_->at_rest();
}

bool Daemon::motion_done(int axis) {
  if (housekeeping_->reload_pending()) return false;
  if (sweeps_->active() && sweeps_->status().axis == axis) return false;
  const AxisPublished p = axes_.at(static_cast<std::size_t>(axis))->published();
  return (p.motion.state == control::MotionState::Idle ||
          p.motion.state == control::MotionState::Fault || p.motion.holding) &&
         !p.trial_active;
}

InstrumentStatus Daemon::status(int axis) {
  Axis& a = *axes_.at(static_cast<std::size_t>(axis));
  const AxisPublished p = a.published();
  const drivers::LinkState device = a.link().health().state;
  InstrumentStatus s;
  s.name = a.config().name;
  s.state = control::motion_state_name(p.motion.state);
  s.position_valid = position_trusted(p, device);
  s.user_offset_m = a.user_offset_m();
  s.position_m = p.motion.position_m + s.user_offset_m;
  s.target_m = p.motion.target_m + s.user_offset_m;
  s.fault = control::motion_fault_name(p.motion.fault);
  s.motion_done = motion_done(axis);
  s.soft_lower_m = p.soft_lower_m + s.user_offset_m;
  s.soft_upper_m = p.soft_upper_m + s.user_offset_m;
  s.resolution_m = a.count_m();
  s.referenced = p.referenced;
  s.device = drivers::link_state_name(device);
  s.moves = p.motion.moves;
  s.bursts = p.motion.bursts;
  s.cycles = p.motion.cycles;
  s.result = control::move_result_name(p.motion.result);
  s.result_distance_m = p.motion.result_distance_m;
  s.least_window_m = p.motion.least_window_m;
  s.motion = p.motion.kind == control::MotionKind::Move        ? "move"
             : p.motion.kind == control::MotionKind::Step      ? "step"
             : p.motion.kind == control::MotionKind::Reference ? "reference"
                                                               : "";
  s.eot = p.motion.eot;
  s.in_position =
      p.motion.in_window && s.motion_done && p.motion.state != control::MotionState::Fault;
  s.holding = p.motion.holding;
  s.referencing = p.referencing;
  const ErrorNote fault = a.fault_note();
  const ErrorNote other = housekeeping_->error(static_cast<std::size_t>(axis));
  const ErrorNote& last = fault.t_s >= other.t_s ? fault : other;
  if (last.t_s >= 0 && last.t_s >= errors_cleared_s_) s.last_error = last.text;
  return s;
}

std::vector<double> Daemon::positions() {
  std::vector<double> out;
  for (const auto& a : axes_) {
    const AxisPublished p = a->published();
    out.push_back(position_trusted(p, a->link().health().state)
                      ? p.motion.position_m + a->user_offset_m()
                      : kNaN);
  }
  return out;
}

CommandError Daemon::region(int axis, double freq_hz, double duty, double stroke_m,
                            std::string& region, double& step_m) {
  if (!std::isfinite(freq_hz) || !std::isfinite(duty) || std::isinf(stroke_m))
    return {error_code::kNumericDataError, "the argument is not a finite number"};
  if (!(freq_hz > 0) || !(duty > 0 && duty < 1) || !(std::isnan(stroke_m) || stroke_m > 0))
    return {error_code::kDataOutOfRange, "need freq_hz > 0, 0 < duty < 1, stroke_m > 0"};
  std::lock_guard<std::mutex> lock(control_mutex_);
  const Axis& a = *axes_.at(static_cast<std::size_t>(axis));
  const double stroke = std::isnan(stroke_m) ? a.limits().max_stroke_m : stroke_m;
  try {
    const control::RegionCell cell = a.map().at(freq_hz, duty, stroke);
    region = model::region_protocol_name(cell.region);
    step_m = cell.step_m;
  } catch (const model::InputError& e) {
    return {error_code::kDataOutOfRange, e.what()};
  }
  return {};
}

Instrument::RegionRange Daemon::region_range(int axis) {
  std::lock_guard<std::mutex> lock(control_mutex_);
  const control::DeviceLimits& l = axes_.at(static_cast<std::size_t>(axis))->limits();
  return {l.min_freq_hz, l.max_freq_hz, l.min_stroke_m, l.max_stroke_m};
}

LoopStats Daemon::loop_stats() {
  return loop_->stats();
}

SweepStatus Daemon::sweep_status() {
  return sweeps_->status();
}

// ---- the simulated stage ----

namespace {

CommandError inject(Axis& a, drivers::SimAction action) {
  action.channel = static_cast<std::uint32_t>(a.channel());
  if (!a.link().simulated(a.channel()))
    return {error_code::kHardwareMissing,
            "axis " + a.config().name + " is on a " +
                a.config().document["daq"]["driver"].as<std::string>() +
                " device, not a simulated one"};
  if (!a.link().inject(action))
    return {error_code::kExecutionError, "the simulated device's queue is full: try again"};
  return {};
}

}  // namespace

CommandError Daemon::sim_push(int axis, double distance_m) {
  if (!std::isfinite(distance_m) || std::fabs(distance_m) > 0.1)
    return {error_code::kDataOutOfRange,
            "SIMulation:PUSH: " + num(distance_m) + " is out of range, allowed [-0.1, 0.1] m"};
  drivers::SimAction a;
  a.kind = drivers::SimAction::Kind::Push;
  a.value = distance_m;
  return inject(*axes_.at(static_cast<std::size_t>(axis)), a);
}

CommandError Daemon::sim_fault(int axis, const std::string& fault, double value) {
  using K = drivers::SimAction::Kind;
  static const struct {
    const char* name;
    K kind;
  } kFaults[] = {{"beam_lost", K::BeamLost},     {"stalled", K::Stalled},
                 {"glitches", K::Glitches},      {"disconnect", K::Disconnect},
                 {"power_cycle", K::PowerCycle}, {"timeouts", K::Timeouts}};
  drivers::SimAction a;
  bool known = false;
  for (const auto& f : kFaults)
    if (fault == f.name) {
      a.kind = f.kind;
      known = true;
    }
  if (!known)
    return {error_code::kDataOutOfRange,
            "SIMulation:FAULt: unknown fault '" + fault +
                "', allowed beam_lost, stalled, glitches, disconnect, power_cycle, timeouts"};
  if (!std::isfinite(value) || value < 0 || value > 1)
    return {error_code::kDataOutOfRange,
            "SIMulation:FAULt " + fault + ": " + num(value) + " is out of range, allowed [0, 1]"};
  if (a.kind == K::Disconnect && value == 0) a.kind = K::Reconnect;
  if (a.kind == K::PowerCycle && value == 0) a.kind = K::Reconnect;  // switched back on
  a.value = value;
  return inject(*axes_.at(static_cast<std::size_t>(axis)), a);
}

// ---- SWEEP ----

CommandError Daemon::check_sweep(int axis, const std::vector<double>& freqs_hz,
                                 const std::vector<double>& duties, int trials, int cycles) {
  if (freqs_hz.empty() || duties.empty())
    return {error_code::kMissingParameter, "SWEEP needs at least one frequency and one duty"};
  if (trials < 1 || trials > kMaxSweepTrials)
    return {error_code::kDataOutOfRange, "SWEEP trials: " + std::to_string(trials) +
                                             " is out of range, allowed [1, " +
                                             std::to_string(kMaxSweepTrials) + "]"};
  if (cycles < 1 || cycles > kMaxSweepCycles)
    return {error_code::kDataOutOfRange, "SWEEP cycles: " + std::to_string(cycles) +
                                             " is out of range, allowed [1, " +
                                             std::to_string(kMaxSweepCycles) + "]"};
  const std::size_t total = freqs_hz.size() * duties.size() * static_cast<std::size_t>(trials);
  if (total > static_cast<std::size_t>(config_.recording.sweep_max_trials))
    return {error_code::kDataOutOfRange,
            std::to_string(total) + " trials, more than recording.sweep_max_trials (" +
                std::to_string(config_.recording.sweep_max_trials) + ")"};
  if (sweeps_->active()) return {error_code::kSettingsConflict, "a sweep is already running"};
  if (!motion_done(axis))
    return {error_code::kSettingsConflict,
            "a motion is in progress: STOP it or wait for MOVE:DONE? 1"};
  Axis& a = *axes_.at(static_cast<std::size_t>(axis));
  const AxisPublished p = a.published();
  if (p.motion.state == control::MotionState::Fault) return fault_error(p.motion.fault);
  const drivers::OutputCapabilities& caps = a.link().output_capabilities(a.channel());
  const drivers::InterferometerCapabilities& ic = a.link().interferometer_capabilities(a.channel());
  const control::DeviceLimits& lim = a.limits();
  const bool buffered = caps.mode == drivers::OutputMode::BufferedSamples;
  for (double f : freqs_hz) {
    if (!std::isfinite(f)) return {error_code::kNumericDataError, "a frequency is not finite"};
    if (f < lim.min_freq_hz || f > lim.max_freq_hz)
      return {error_code::kDataOutOfRange, "frequency " + num(f) + " Hz outside the device's [" +
                                               num(lim.min_freq_hz) + ", " + num(lim.max_freq_hz) +
                                               "] Hz"};
    const double trial_s = config_.recording.sweep_rest_s +
                           static_cast<double>(cycles + config_.recording.sweep_settle_cycles) / f;
    const double records = trial_s * ic.stream_rate_hz + 2;
    if (records > static_cast<double>(ic.stream_capacity))
      return {error_code::kDataOutOfRange, "a trial at " + num(f) + " Hz with " +
                                               std::to_string(cycles) + " cycles is " +
                                               num(records) + " records, the capture holds " +
                                               std::to_string(ic.stream_capacity)};
    for (double d : duties) {
      if (!std::isfinite(d)) return {error_code::kNumericDataError, "a duty is not finite"};
      if (!(d > 0 && d < 1))
        return {error_code::kDataOutOfRange, "duty " + num(d) + ": allowed (0, 1)"};
      if (buffered) {
        const model::Segment seg = model::make_segment(
            f, d, lim.max_stroke_m, static_cast<std::uint64_t>(cycles), lim.output_sample_rate_hz,
            config_.recording.sweep_rest_s, config_.recording.sweep_settle_cycles / f);
        const std::size_t room =
            std::min<std::size_t>(caps.max_burst_samples, std::size_t{1} << 21);
        if (seg.sample_count() > room)
          return {error_code::kDataOutOfRange,
                  "a trial at " + num(f) + " Hz with " + std::to_string(cycles) + " cycles needs " +
                      std::to_string(seg.sample_count()) + " samples, the output holds " +
                      std::to_string(room)};
      } else if (static_cast<std::uint32_t>(cycles) > caps.max_cycles) {
        return {error_code::kDataOutOfRange, "cycles above the device's max_cycles"};
      }
    }
  }
  return {};
}

// The bytes a sweep's dataset takes, generously: a row of three numbers (up to 26 characters each)
// per sample of every trial file, and sweep.csv (a row of about 200 bytes per trial) twice over,
// since it is rewritten whole beside its predecessor after each trial.
CommandError Daemon::check_sweep_space(Axis& a, const std::vector<double>& freqs_hz,
                                       std::size_t duties, int trials, int cycles) {
  const double stream_hz = a.link().interferometer_capabilities(a.channel()).stream_rate_hz;
  double bytes = 1 << 20;  // plan.yaml, stage.yaml and what the file system keeps of them
  for (const double f : freqs_hz) {
    const double trial_s = config_.recording.sweep_rest_s +
                           static_cast<double>(cycles + config_.recording.sweep_settle_cycles) / f;
    bytes += static_cast<double>(duties) * trials * ((trial_s * stream_hz + 2) * 80.0 + 400.0);
  }
  struct statvfs st {};
  if (::fstatvfs(data_dir_.get(), &st) != 0)
    return {
        error_code::kMassStorageError,
        "SWEEP: recording.data_dir " + config_.recording.data_dir + ": " + std::strerror(errno)};
  const double free_bytes = static_cast<double>(st.f_bavail) * static_cast<double>(st.f_frsize);
  if (free_bytes < bytes)
    return {error_code::kMassStorageError,
            "SWEEP: its dataset needs about " + num(std::ceil(bytes / 1e6)) + " MB, " +
                num(std::floor(free_bytes / 1e6)) + " MB free in recording.data_dir " +
                config_.recording.data_dir};
  return {};
}

CommandError Daemon::sweep(int axis, const std::string& dir, const std::vector<double>& freqs_hz,
                           const std::vector<double>& duties, int trials, int cycles) {
  if (dir.empty()) return {error_code::kMissingParameter, "SWEEP needs a directory"};
  if (CommandError e = check_sweep(axis, freqs_hz, duties, trials, cycles); !e.ok()) return e;
  Axis& a = *axes_.at(static_cast<std::size_t>(axis));
  // Confined to the data directory, a new directory every time (never a symlink followed, never
  // a file overwritten).
  std::string error;
  if (!data_dir_.valid()) open_data_dir();  // created since the start, perhaps
  if (!data_dir_.valid())
    return {error_code::kMassStorageError,
            "SWEEP: recording.data_dir " + config_.recording.data_dir + ": " + data_dir_error_};
  if (CommandError e = check_sweep_space(a, freqs_hz, duties.size(), trials, cycles); !e.ok())
    return e;
  std::string path;
  recording::DirFd dataset =
      create_dataset_dir(data_dir_, config_.recording.data_dir, dir, path, error);
  if (!dataset.valid()) return {error_code::kDataOutOfRange, "SWEEP: " + error};
  auto job = std::make_unique<SweepJob>();
  const drivers::OutputCapabilities& caps = a.link().output_capabilities(a.channel());
  job->axis = axis;
  job->dir = path;
  job->freqs_hz = freqs_hz;
  job->duties = duties;
  job->trials = trials;
  job->cycles = cycles;
  job->stroke_m = a.limits().max_stroke_m;
  job->sample_rate_hz =
      caps.mode == drivers::OutputMode::BufferedSamples ? a.limits().output_sample_rate_hz : 0.0;
  job->rest_s = config_.recording.sweep_rest_s;
  job->settle_cycles = config_.recording.sweep_settle_cycles;
  job->span_m = config_.recording.sweep_span_m;
  job->stream_rate_hz = a.link().interferometer_capabilities(a.channel()).stream_rate_hz;
  try {
    job->writer.emplace(std::move(dataset), path, a.config().stage, planned_cells(*job),
                        a.config().name);
  } catch (const std::exception& e) {
    return {error_code::kExecutionError, std::string("cannot create the dataset: ") + e.what()};
  }
  if (!sweeps_->submit(std::move(job)))
    return {error_code::kSettingsConflict, "a sweep is already running"};
  return {};
}

}  // namespace idm::daemon
