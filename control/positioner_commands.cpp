// The positioner's commands (control/README.md, "Positioner"): moves, open-loop steps, the
// reference search, the motion settings, stop, soft limits, and entering a fault. Part of class
// Positioner.
#include <algorithm>
#include <cmath>

#include "control/calibration.h"
#include "control/positioner.h"
#include "model/impulse_model.h"
#include "model/yaml_util.h"

namespace idm::control {

// ---- commands ----

void Positioner::reset_progress() {
  last_try_done_ = false;
  stall_count_ = 0;
  streak_cycles_ = 0;
  streak_along_m_ = 0;
  move_chunks_ = 0;
  eot_count_ = 0;
  eot_next_ = 0;
}

void Positioner::start_motion(MotionKind kind) {
  motion_start_m_ = status_.position_m;
  status_.kind = kind;
  status_.result = MoveResult::None;
  status_.corrections = 0;
  status_.fault = MotionFault::None;
  status_.least_window_m = 0;
  status_.in_window = false;
  arrived_ = false;
  status_.holding = false;
  hold_armed_ = false;
  hold_correcting_ = false;
  referencing_ = false;
  mark_search_ = MarkSearch::Off;
  stop_requested_ = false;
  stop_result_ = MoveResult::Stopped;
  reset_progress();
  move_cycles_ = 0;
  move_started_ = false;
  dwell_failures_ = 0;
  phase_ = Phase::Pending;
  status_.state = MotionState::Moving;
}

bool Positioner::toward_eot(double end_m) const {
  // Beyond where the stop was met (the slider may have been thrown back from it since).
  return status_.eot != 0 && (end_m - status_.eot_position_m) * status_.eot > -tolerance_m();
}

Refusal Positioner::move_absolute(double target_m) {
  requested_target_m_ = target_m;
  if (!std::isfinite(target_m)) return Refusal::NotFinite;
  if (phase_ == Phase::Fault) return Refusal::Faulted;
  // A hold's correction in progress takes the new target at its chunk's end.
  const bool retarget = hold_correcting_ && phase_ != Phase::Idle;
  if (phase_ != Phase::Idle && !retarget) return Refusal::Busy;
  if (!target_allowed(target_m, config_.soft_lower_m, config_.soft_upper_m))
    return Refusal::OutsideSoftLimits;
  if (!status_.position_valid) return Refusal::NoPosition;
  if (toward_eot(target_m)) return Refusal::EndOfTravel;
  status_.eot = 0;  // a move away from it
  ladder_.start_move();
  status_.target_m = target_m;
  target_known_ = true;
  status_.closed_loop = true;
  ++status_.moves;
  const Phase phase = phase_;
  start_motion(MotionKind::Move);
  if (retarget) phase_ = phase;  // the chunk in flight ends first
  return Refusal::None;
}

Refusal Positioner::move_relative(double distance_m) {
  requested_target_m_ = std::numeric_limits<double>::quiet_NaN();
  if (!std::isfinite(distance_m)) return Refusal::NotFinite;
  if (!status_.position_valid)
    return phase_ == Phase::Fault ? Refusal::Faulted : Refusal::NoPosition;
  // From the target when in position (no creep of the error from move to move), else the reading.
  const double base = status_.in_window ? status_.target_m : status_.position_m;
  return move_absolute(base + distance_m);
}

double Positioner::nominal_open_loop_step_m(double freq_hz, double duty, double stroke_m) const {
  return model::steady_step_corrected_m(map_.config().stage, freq_hz, duty, stroke_m);
}

Refusal Positioner::check_burst(const model::Segment& segment, double from_m) const {
  if (!std::isfinite(from_m)) return Refusal::NoPosition;
  const double step = nominal_open_loop_step_m(segment.freq_hz, segment.duty, segment.stroke_m);
  if (!std::isfinite(step)) return Refusal::OutOfRange;
  // A cycle may slip by as much as the map's largest step: a trial's cell may lie where the
  // model's prediction is least sure (near a region boundary, or cut off).
  const double slip = std::max({std::fabs(step), largest_step_m_[0], largest_step_m_[1]});
  const Excursion e = burst_excursion(segment.cycles, step, config_.approach_uncertainty, slip);
  if (status_.eot != 0 && (status_.eot > 0 ? from_m + e.hi_m : from_m + e.lo_m) * status_.eot >
                              status_.eot_position_m * status_.eot - tolerance_m())
    return Refusal::EndOfTravel;
  if (!excursion_allowed(from_m, e, config_.soft_lower_m, config_.soft_upper_m))
    return Refusal::OutsideSoftLimits;
  return Refusal::None;
}

Refusal Positioner::step_open_loop(std::int64_t cycles, double duty, double freq_hz,
                                   double stroke_m) {
  requested_target_m_ = std::numeric_limits<double>::quiet_NaN();
  const bool cell_omitted = std::isnan(duty) && std::isnan(freq_hz);
  if (!cell_omitted && (!std::isfinite(duty) || !std::isfinite(freq_hz))) return Refusal::NotFinite;
  if (std::isinf(stroke_m)) return Refusal::NotFinite;
  if (phase_ == Phase::Fault) return Refusal::Faulted;
  if (phase_ != Phase::Idle) return Refusal::Busy;
  if (!status_.position_valid) return Refusal::NoPosition;
  if (cycles == 0) return Refusal::OutOfRange;
  const int sign = cycles > 0 ? 1 : -1;
  const std::uint64_t n = static_cast<std::uint64_t>(cycles > 0 ? cycles : -cycles);
  const DeviceLimits& lim = map_.config().limits;
  if (std::isnan(stroke_m)) stroke_m = lim.max_stroke_m;
  if (stroke_m < lim.min_stroke_m * (1 - 1e-12) || stroke_m > lim.max_stroke_m * (1 + 1e-12))
    return Refusal::OutOfRange;
  Chunk c;
  if (cell_omitted) {
    // The map's largest-step cell moving that way (positive cycles: positive) at the stroke.
    const int d = direction_index(sign);
    if (!has_largest_cell_[d]) return Refusal::OutOfRange;
    c = cell_chunk(map_.cells()[largest_cell_[d]]);
    c.stroke_m = std::min(stroke_m, c.stroke_m);
  } else {
    if (!(duty > 0 && duty < 1) || duty == 0.5) return Refusal::OutOfRange;
    if (cycles < 0) duty = 1.0 - duty;
    if (freq_hz < lim.min_freq_hz * (1 - 1e-12) || freq_hz > lim.max_freq_hz * (1 + 1e-12))
      return Refusal::OutOfRange;
    c.stroke_m = stroke_m;
    if (buffered_) {
      const ClockedWave w = snap_to_sample_clock(sample_rate_hz_, freq_hz, duty);
      if ((w.duty - 0.5) * (duty - 0.5) <= 0) return Refusal::OutOfRange;
      c.freq_hz = w.freq_hz;
      c.duty = w.duty;
      c.period_samples = w.period_samples;
      c.extension_samples = w.extension_samples;
    } else {
      c.freq_hz = freq_hz;
      c.duty = duty;
    }
  }
  if (n > lim.max_burst_cycles * 1000000ull) return Refusal::OutOfRange;
  if (buffered_ && c.period_samples + 1 > max_chunk_samples_) return Refusal::OutOfRange;
  // Soft limits: the nominal steady step times the cycles, grown by the step model's uncertainty,
  // must stay inside.
  const double step = nominal_open_loop_step_m(c.freq_hz, c.duty, c.stroke_m);
  const double end = status_.position_m + static_cast<double>(n) * step;
  requested_target_m_ = end;
  if (toward_eot(end)) return Refusal::EndOfTravel;
  // The motion gate: the burst, its step wrong by approach_uncertainty and a cycle's slip of a
  // step either way, stays within the soft limits.
  if (!excursion_allowed(status_.position_m,
                         burst_excursion(n, step, config_.approach_uncertainty, step),
                         config_.soft_lower_m, config_.soft_upper_m))
    return Refusal::OutsideSoftLimits;
  c.predicted_m = step;  // per cycle here; per chunk when a chunk is made
  c.cell = nullptr;
  open_loop_ = c;
  open_loop_remaining_ = n;
  status_.target_m = end;
  target_known_ = true;
  status_.closed_loop = false;
  status_.eot = 0;
  start_motion(MotionKind::Step);
  return Refusal::None;
}

bool Positioner::reference_drive(int sign) {
  const int d = direction_index(sign);
  if (!has_largest_cell_[d]) return false;
  Chunk c = cell_chunk(map_.cells()[largest_cell_[d]]);
  const double step = nominal_open_loop_step_m(c.freq_hz, c.duty, c.stroke_m);
  if (!(std::fabs(step) > 0)) return false;
  // Enough cycles to cross the soft range four times at the nominal step (a real stage steps
  // less); the end stop ends it long before.
  const double span = std::isfinite(config_.soft_upper_m - config_.soft_lower_m)
                          ? config_.soft_upper_m - config_.soft_lower_m
                          : 0.02;
  const double n = std::ceil(4.0 * span / std::fabs(step));
  c.predicted_m = step;
  c.cell = nullptr;
  open_loop_ = c;
  open_loop_remaining_ = static_cast<std::uint64_t>(std::clamp(n, 1.0, 1e9));
  return true;
}

Refusal Positioner::start_reference(int direction, double position_m, bool mark) {
  requested_target_m_ = std::numeric_limits<double>::quiet_NaN();
  if (!std::isfinite(position_m)) return Refusal::NotFinite;
  if (phase_ == Phase::Fault) return Refusal::Faulted;
  if (phase_ != Phase::Idle) return Refusal::Busy;
  if (!status_.position_valid) return Refusal::NoPosition;
  if (!reference_drive(direction > 0 ? 1 : -1)) return Refusal::OutOfRange;
  status_.closed_loop = false;
  status_.eot = 0;
  start_motion(MotionKind::Reference);
  referencing_ = true;
  mark_search_ = mark ? MarkSearch::Searching : MarkSearch::Off;
  mark_seen_ = false;
  mark_reversed_ = false;
  reference_position_m_ = position_m;
  status_.target_m = position_m;
  target_known_ = true;
  return Refusal::None;
}

Refusal Positioner::reference(int direction, double position_at_stop_m) {
  return start_reference(direction, position_at_stop_m, false);
}

Refusal Positioner::reference_mark(int direction, double position_at_mark_m) {
  return start_reference(direction, position_at_mark_m, true);
}

// The settings a command changes go through the config's own table (positioner_params): one
// range for the file, the protocol and the code.
Refusal Positioner::set_settings(const std::vector<std::pair<const char*, double>>& values) {
  PositionerConfig c = config_;
  for (const auto& [key, value] : values) {
    if (!std::isfinite(value)) return Refusal::NotFinite;
    try {
      positioner_params().set(c, key, value, key);
    } catch (const model::InputError&) {
      return Refusal::OutOfRange;
    }
  }
  config_ = c;
  status_.window_m = tolerance_m();
  return Refusal::None;
}

Refusal Positioner::set_window(double window_m) {
  return set_settings({{"tolerance_m", window_m}});
}

Refusal Positioner::set_dwell(double dwell_s) {
  return set_settings({{"dwell_s", dwell_s}});
}

Refusal Positioner::set_eot(double step_m, int cycles) {
  return set_settings({{"eot_step_m", step_m}, {"eot_cycles", cycles}});
}

Refusal Positioner::set_hold(double hold_s, double window_m) {
  return set_settings({{"hold_s", hold_s}, {"hold_window_m", window_m}});
}

void Positioner::resume_hold(double until_s) {
  if (phase_ != Phase::Idle) return;
  hold_armed_ = true;
  status_.holding = true;
  hold_until_s_ = until_s;
  hold_sum_m_ = 0;
  hold_n_ = 0;
  hold_correction_due_ = false;
  arrived_ = true;
}

void Positioner::end_hold() {
  hold_armed_ = false;
  status_.holding = false;
  if (hold_correcting_) {
    hold_correcting_ = false;
    if (phase_ != Phase::Idle && phase_ != Phase::Fault) stop_requested_ = true;
  }
}

void Positioner::stop() {
  end_hold();
  if (phase_ == Phase::Idle || phase_ == Phase::Fault) return;
  stop_requested_ = true;
}

void Positioner::reset_fault() {
  if (phase_ != Phase::Fault || device_lost_) return;  // a device still away stays a fault
  phase_ = Phase::Idle;
  status_.state = MotionState::Idle;
  status_.fault = MotionFault::None;
  invalid_sample_status_ = 0;
  stop_requested_ = false;
}

Refusal Positioner::set_soft_limits(double lower_m, double upper_m) {
  if (std::isnan(lower_m) || std::isnan(upper_m)) return Refusal::NotFinite;
  if (!(lower_m < upper_m)) return Refusal::OutOfRange;
  if (phase_ != Phase::Idle && phase_ != Phase::Fault) {
    // A move in progress must not end outside the new limits.
    if (status_.target_m < lower_m || status_.target_m > upper_m) return Refusal::Busy;
  }
  config_.soft_lower_m = lower_m;
  config_.soft_upper_m = upper_m;
  return Refusal::None;
}

void Positioner::continue_from(const MotionStatus& previous) {
  status_.target_m = previous.target_m;
  target_known_ = previous.position_valid || previous.moves > 0;
  status_.closed_loop = previous.closed_loop;
  status_.position_m = previous.position_m;
  status_.position_valid = previous.position_valid;
  status_.moves = previous.moves;
  status_.bursts = previous.bursts;
  status_.cycles = previous.cycles;
  status_.last_move_time_s = previous.last_move_time_s;
  status_.kind = previous.kind;
  status_.result = previous.result;
  status_.result_distance_m = previous.result_distance_m;
  status_.motions_ended = previous.motions_ended;
  status_.eot = previous.eot;
  status_.eot_position_m = previous.eot_position_m;
  status_.moved_dirs = previous.moved_dirs;
  status_.references = previous.references;
  status_.offset_m = previous.offset_m;
  offset_m_ = previous.offset_m;
  // In position carries over (and keeps following the readings).
  status_.in_window = arrived_ = previous.in_window && previous.state == MotionState::Idle;
}

// ---- faults ----

void Positioner::enter_fault(MotionFault fault) {
  // Output to zero at once: the request replaces anything not yet handed out.
  request_ = model::OutputRequest{};
  request_.kind = model::OutputRequest::Kind::Stop;
  request_.seq = seq_;
  request_due_ = true;
  const bool moving = phase_ != Phase::Idle && phase_ != Phase::Fault;
  phase_ = Phase::Fault;
  status_.state = MotionState::Fault;
  status_.fault = fault;
  stop_requested_ = false;
  hold_armed_ = hold_correcting_ = false;
  status_.holding = false;
  status_.in_window = false;
  arrived_ = false;
  referencing_ = false;
  mark_search_ = MarkSearch::Off;
  if (moving || status_.result == MoveResult::None) {
    status_.result = MoveResult::Fault;
    status_.result_distance_m = status_.target_m - status_.position_m;
    if (moving) ++status_.motions_ended;
  }
}

}  // namespace idm::control
