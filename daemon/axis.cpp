#include "daemon/axis.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>

#include "drivers/position_word.h"
#include "model/range.h"

namespace idm::daemon {

namespace {

bool grid_changed(const ControlConfig& a, const ControlConfig& b) {
  return a.freq_step_hz != b.freq_step_hz || a.duty_step != b.duty_step ||
         a.stroke_count != b.stroke_count || a.min_freq_hz != b.min_freq_hz ||
         a.max_freq_hz != b.max_freq_hz || a.min_stroke_m != b.min_stroke_m ||
         a.max_stroke_m != b.max_stroke_m || a.output_sample_rate_hz != b.output_sample_rate_hz ||
         a.friction_uncertainty != b.friction_uncertainty;
}

// Counts may have been missed: the beam or the reference signal was lost, or the decoder lost
// continuity.
bool counts_lost(std::uint8_t status) {
  namespace ss = drivers::sample_status;
  return (status & (ss::kMeasurementSignalLost | ss::kReferenceSignalLost | ss::kContinuityLost)) !=
         0;
}

}  // namespace

void set_note(ErrorNote& note, double t_s, const char* a, const char* b, const char* c) {
  note.t_s = t_s;
  std::size_t used = 0;
  for (const char* s : {a, b, c}) {
    const std::size_t n = std::min(std::strlen(s), sizeof note.text - 1 - used);
    std::memcpy(note.text + used, s, n);
    used += n;
  }
  note.text[used] = '\0';
}

const char* trial_failure_text(TrialFailure why) {
  switch (why) {
    case TrialFailure::None:
      return "none";
    case TrialFailure::Positioning:
      return "positioning failed";
    case TrialFailure::Driver:
      return "the device failed or was lost";
    case TrialFailure::Overflow:
      return "sample queue overflow";
    case TrialFailure::Stopped:
      return "stopped";
    case TrialFailure::Busy:
      return "motion in progress";
    case TrialFailure::Limits:
      return "it could leave the soft limits (the motion gate: its worst-case excursion from here "
             "and from the sweep's start)";
    case TrialFailure::LeftLimits:
      return "a reading left the soft limits while it played: stopped at once";
    case TrialFailure::EndOfTravel:
      return "it could reach the end of travel the axis met before";
    case TrialFailure::NoPosition:
      return "no valid position to judge it from";
  }
  return "?";
}

namespace {

const char* motion_word(control::MotionKind kind) {
  switch (kind) {
    case control::MotionKind::Move:
      return "MOVE";
    case control::MotionKind::Step:
      return "STEP";
    case control::MotionKind::Reference:
      return "REFerence";
    case control::MotionKind::None:
      break;
  }
  return "motion";
}

}  // namespace

std::string motion_note_text(const std::string& axis, const MotionNote& n) {
  std::string text = "axis " + axis + ": ";
  if (n.kind == MotionNote::Kind::Fault) {
    text += std::string("FAULT ") + control::motion_fault_name(n.fault) +
            (n.ended_motion ? std::string(", ending its ") + motion_word(n.motion) : " at rest");
  } else {
    text += std::string(motion_word(n.motion)) + " ended " + control::move_result_name(n.result);
    if (n.result == control::MoveResult::EndOfTravel && n.eot != 0)
      text += n.eot < 0 ? " (low end)" : " (high end)";
  }
  const double off = n.user_offset_m;
  text += ": position " +
          (n.position_valid ? model::format_number(n.position_m + off) + " m" : "unknown") +
          ", target " + model::format_number(n.target_m + off) + " m";
  if (n.position_valid) text += ", distance " + model::format_number(n.distance_m) + " m";
  if (off != 0) text += ", user offset " + model::format_number(off) + " m";
  return text;
}

Axis::Axis(const AxisConfig& config, drivers::DeviceLink& link, std::size_t link_index)
    : config_(config),
      link_(link),
      link_index_(link_index),
      port_(link.port(link_index)),
      has_reference_mark_(link.interferometer_capabilities(link_index).reference_mark) {
  soft_lower_m_ = config_.control.positioner.soft_lower_m;
  soft_upper_m_ = config_.control.positioner.soft_upper_m;
}

// ---- not real-time ----

void Axis::prepare(const ControlConfig& control) {
  next_map_.reset();
  if (map_ && !grid_changed(control_, control)) return;
  const drivers::OutputCapabilities& oc = link_.output_capabilities(channel());
  next_limits_ = device_limits(control, config_.stage.stage, oc);
  next_map_ = std::make_unique<control::RegionMap>(
      region_map_config(control, config_.stage.stage, next_limits_));
}

void Axis::build(const ControlConfig& control) {
  const drivers::OutputCapabilities& oc = link_.output_capabilities(channel());
  const drivers::InterferometerCapabilities& ic = link_.interferometer_capabilities(channel());
  count_m_.store(ic.word.count_m(), std::memory_order_relaxed);
  if (!next_map_ && (!map_ || grid_changed(control_, control))) prepare(control);
  const control::MotionStatus previous =
      positioner_ ? positioner_->status() : control::MotionStatus{};
  const bool had_positioner = positioner_ != nullptr;
  control::PositionerConfig pc = control.positioner;
  pc.soft_lower_m = soft_lower_m_;
  pc.soft_upper_m = soft_upper_m_;
  std::unique_ptr<control::RegionMap> map = next_map_ ? std::move(next_map_) : nullptr;
  const control::RegionMap& use = map ? *map : *map_;
  if (!calibration_ && control.calibration.enabled)
    calibration_ = std::make_unique<control::Calibration>(config_.stage.stage, control.calibration);
  // Built before anything is swapped: a bad setting leaves the axis as it was.
  auto positioner = std::make_unique<control::Positioner>(
      use, control.planner, pc, axis_device_info(oc, ic), calibration_.get());
  if (had_positioner) {
    positioner->continue_from(previous);
    // A hold in force goes on (a reload must not let the stage drift off the target).
    if (previous.holding) positioner->resume_hold(positioner_->hold_until_s());
  }
  positioner_ = std::move(positioner);
  if (map) {
    map_ = std::move(map);
    limits_ = next_limits_;
  }
  control_ = control;
  if (calibration_) {
    const control::CalibrationState state = calibration_->state();
    calibration_snapshot_.store(state);
    calibration_published_ = state.total_updates;
  }
  pub_.soft_lower_m = soft_lower_m_;
  pub_.soft_upper_m = soft_upper_m_;
  pub_.motion = positioner_->status();
  published_.store(pub_);
}

void Axis::restore_reference(double offset_m) {
  control::MotionStatus status = positioner_->status();
  status.offset_m = offset_m;
  positioner_->continue_from(status);
  referenced_ = true;
  pub_.referenced = true;
  pub_.motion = positioner_->status();
  published_.store(pub_);
}

void Axis::set_soft_limits_now(double lower_m, double upper_m) {
  soft_lower_m_ = lower_m;
  soft_upper_m_ = upper_m;
}

// ---- the loop ----

control::Refusal Axis::apply(const AxisCommand& command) {
  using control::Refusal;
  namespace ac = axis_command;
  const bool busy = trial_phase_ != TrialPhase::Idle;
  if (busy && command.motion()) return Refusal::Busy;
  // One overload per command type (a type without one does not compile).
  struct Apply {
    Axis& a;
    Refusal operator()(const ac::MoveAbsolute& c) const {
      if (a.config_.require_reference && !a.referenced_) return Refusal::NotReferenced;
      return a.positioner_->move_absolute(c.target_m);
    }
    Refusal operator()(const ac::MoveRelative& c) const {
      return a.positioner_->move_relative(c.distance_m);
    }
    Refusal operator()(const ac::Step& c) const {
      return a.positioner_->step_open_loop(c.cycles, c.duty, c.freq_hz, c.stroke_m);
    }
    Refusal operator()(const ac::SetWindow& c) const {
      return a.positioner_->set_window(c.window_m);
    }
    Refusal operator()(const ac::SetDwell& c) const { return a.positioner_->set_dwell(c.dwell_s); }
    Refusal operator()(const ac::SetEot& c) const {
      return a.positioner_->set_eot(c.step_m, c.cycles);
    }
    Refusal operator()(const ac::SetHold& c) const {
      return a.positioner_->set_hold(c.hold_s, c.window_m);
    }
    Refusal operator()(const ac::SetSpeed& c) const {
      return a.positioner_->set_settings({{"max_speed_m_s", c.max_speed_m_s}});
    }
    Refusal operator()(const ac::Reference& c) const {
      const int direction = c.direction > 0 ? 1 : -1;
      const Refusal r = c.mark ? a.positioner_->reference_mark(direction, c.position_m)
                               : a.positioner_->reference(direction, c.position_m);
      if (r == Refusal::None) a.referenced_ = false;  // until it is found
      return r;
    }
    Refusal operator()(const ac::SetLimits& c) const {
      const Refusal r = a.positioner_->set_soft_limits(c.lower_m, c.upper_m);
      if (r == Refusal::None) {
        a.soft_lower_m_ = a.pub_.soft_lower_m = c.lower_m;
        a.soft_upper_m_ = a.pub_.soft_upper_m = c.upper_m;
      }
      return r;
    }
    Refusal operator()(const ac::Stop&) const {
      a.positioner_->stop();
      return Refusal::None;
    }
  };
  return std::visit(Apply{*this}, command.body);
}

void Axis::stop(TrialNotices& notices) {
  positioner_->stop();
  if (trial_phase_ != TrialPhase::Idle) fail_trial(TrialFailure::Stopped, notices);
}

void Axis::tick(double now_s, TrialNotices& notices) {
  now_s_ = now_s;
  step_axis(port_, *positioner_, now_s, pending_,
            [&](const model::AxisEvent& e) { observe(e, notices); });
  if (trial_phase_ != TrialPhase::Idle) trial_tick(notices);
}

void Axis::observe(const model::AxisEvent& e, TrialNotices& notices) {
  using Kind = model::AxisEvent::Kind;
  switch (e.kind) {
    case Kind::Reading:
      if (counts_lost(e.status)) referenced_ = false;
      // The motion gate's stop for a trial: a reading beyond the soft limits, farther out than
      // where the trial started, stops it at once.
      if (trial_phase_ == TrialPhase::Playing && e.valid() && e.in_segment &&
          !control::reading_allowed(e.position_m + positioner_->status().offset_m, trial_start_m_,
                                    positioner_->config().soft_lower_m,
                                    positioner_->config().soft_upper_m, positioner_->tolerance_m()))
        fail_trial(TrialFailure::LeftLimits, notices);
      return;
    case Kind::DeviceBack:
      if (!e.count_kept) referenced_ = false;
      return;
    case Kind::DeviceLost:
      if (trial_phase_ != TrialPhase::Idle) fail_trial(TrialFailure::Driver, notices);
      return;
    case Kind::SegmentDone:
      if (trial_phase_ == TrialPhase::Playing && e.seq == trial_seq_)
        trial_phase_ = TrialPhase::Idle;
      return;
    case Kind::OutputFailed:
      if (trial_phase_ == TrialPhase::Playing && e.seq == trial_seq_)
        fail_trial(TrialFailure::Driver, notices);
      return;
    case Kind::SegmentStarted:
      return;
  }
}

bool Axis::start_trial(const TrialRequest& t, TrialNotices& notices) {
  positioner_->end_hold();
  if (trial_phase_ != TrialPhase::Idle || !positioner_->at_rest()) {
    TrialNotice n;  // the trial in progress stays as it is
    n.kind = TrialNotice::Kind::Failed;
    n.index = t.index;
    n.seq = t.seq;
    n.why = TrialFailure::Busy;
    notices.push(n);
    return false;
  }
  trial_ = t;
  trial_seq_ = t.seq;
  // The motion gate, from where the trial will start; from the sweep's start when not from here.
  const control::MotionStatus& s = positioner_->status();
  const double here = s.position_valid ? s.position_m : std::numeric_limits<double>::quiet_NaN();
  const double from = std::isfinite(t.return_to_m) ? t.return_to_m : here;
  control::Refusal gate = positioner_->check_burst(t.segment, from);
  if (gate != control::Refusal::None && !std::isfinite(t.return_to_m) && std::isfinite(t.home_m) &&
      positioner_->check_burst(t.segment, t.home_m) == control::Refusal::None) {
    trial_.return_to_m = t.home_m;
    gate = control::Refusal::None;
  }
  if (gate != control::Refusal::None) {
    trial_phase_ = TrialPhase::Starting;  // nothing asked of the positioner or the output yet
    fail_trial(gate == control::Refusal::EndOfTravel  ? TrialFailure::EndOfTravel
               : gate == control::Refusal::NoPosition ? TrialFailure::NoPosition
                                                      : TrialFailure::Limits,
               notices);
    return false;
  }
  if (std::isfinite(trial_.return_to_m)) {
    if (positioner_->move_absolute(trial_.return_to_m) != control::Refusal::None) {
      trial_phase_ = TrialPhase::Positioning;
      fail_trial(TrialFailure::Positioning, notices);
      return false;
    }
    trial_phase_ = TrialPhase::Positioning;
    return true;
  }
  trial_phase_ = TrialPhase::Starting;
  return true;
}

void Axis::trial_tick(TrialNotices& notices) {
  if (trial_phase_ == TrialPhase::Positioning) {
    if (!positioner_->at_rest()) return;
    if (positioner_->status().fault != control::MotionFault::None)
      return fail_trial(TrialFailure::Positioning, notices);
    trial_phase_ = TrialPhase::Starting;
  }
  if (trial_phase_ == TrialPhase::Starting) {
    if (positioner_->status().state == control::MotionState::Fault)
      return fail_trial(TrialFailure::Driver, notices);
    model::OutputRequest r;
    r.kind = model::OutputRequest::Kind::Play;
    r.record = true;
    r.seq = trial_.seq;
    r.segment = trial_.segment;
    if (pending_.due || !port_.requests.push(r)) return;  // next tick
    trial_phase_ = TrialPhase::Playing;
    trial_start_m_ = positioner_->status().position_m;
    TrialNotice n;
    n.kind = TrialNotice::Kind::Started;
    n.index = trial_.index;
    n.seq = r.seq;
    if (!notices.push(n)) fail_trial(TrialFailure::Overflow, notices);
  }
}

void Axis::fail_trial(TrialFailure why, TrialNotices& notices) {
  if (trial_phase_ == TrialPhase::Playing) {
    model::OutputRequest stop;
    stop.kind = model::OutputRequest::Kind::Stop;
    stop.seq = trial_seq_;
    if (!port_.requests.push(stop)) {
      pending_.due = true;
      pending_.request = stop;
    }
  }
  if (trial_phase_ == TrialPhase::Positioning) positioner_->stop();
  trial_phase_ = TrialPhase::Idle;
  TrialNotice n;
  n.kind = TrialNotice::Kind::Failed;
  n.index = trial_.index;
  n.seq = trial_seq_;
  n.why = why;
  notices.push(n);  // the recorder drains continuously
}

void Axis::publish(bool parked) {
  pub_.motion = positioner_->status();
  if (pub_.motion.references != references_seen_) {  // a reference was found
    references_seen_ = pub_.motion.references;
    referenced_ = true;
  }
  pub_.referencing = pub_.motion.kind == control::MotionKind::Reference && !positioner_->at_rest();
  const control::PositionerConfig& pc = positioner_->config();
  pub_.settings.window_m = positioner_->tolerance_m();
  pub_.settings.dwell_s = pc.dwell_s;
  pub_.settings.max_speed_m_s = pc.max_speed_m_s;
  pub_.settings.eot_step_m = pc.eot_step_m;
  pub_.settings.eot_cycles = pc.eot_cycles;
  pub_.settings.hold_s = pc.hold_s;
  pub_.settings.hold_window_set_m = pc.hold_window_m;
  pub_.settings.hold_window_m =
      pc.hold_window_m > 0 ? pc.hold_window_m : positioner_->tolerance_m();
  pub_.trial_active = trial_phase_ != TrialPhase::Idle;
  pub_.referenced = referenced_;
  pub_.parked = parked;
  published_.store(pub_);
  if ((pub_.motion.fault != noted_fault_ && pub_.motion.fault != control::MotionFault::None) ||
      pub_.motion.motions_ended != noted_ended_)
    note_motion();
  if (pub_.motion.fault != noted_fault_) note_fault(now_s_);
  // Only when a burst updated it (at most once per chunk): a copy of a few hundred bytes.
  if (calibration_ && calibration_->total_updates() != calibration_published_) {
    calibration_published_ = calibration_->total_updates();
    calibration_snapshot_.store(calibration_->state());
  }
}

void Axis::note_motion() {
  const control::MotionStatus& m = pub_.motion;
  using control::MoveResult;
  const bool entered = m.fault != control::MotionFault::None && m.fault != noted_fault_;
  const bool ended = m.motions_ended != noted_ended_;
  noted_ended_ = m.motions_ended;
  MotionNote n;
  n.kind = entered ? MotionNote::Kind::Fault : MotionNote::Kind::Ended;
  n.fault = m.fault;
  n.result = m.result;
  n.motion = m.kind;
  n.ended_motion = entered && ended && m.result == MoveResult::Fault;
  n.position_valid = m.position_valid;
  n.position_m = m.position_m;
  n.target_m = m.target_m;
  n.distance_m = ended ? m.result_distance_m : m.target_m - m.position_m;
  n.eot = m.eot;
  n.user_offset_m = user_offset_m();
  // A motion that ended OK, or STOPPED as a client (or the daemon stopping) asked, is no news.
  if (!entered && (m.result == MoveResult::Ok || m.result == MoveResult::Stopped ||
                   m.result == MoveResult::None))
    return;
  if (!motion_notes_.push(n)) motion_notes_dropped_.fetch_add(1, std::memory_order_relaxed);
}

void Axis::note_fault(double now_s) {
  noted_fault_ = pub_.motion.fault;
  if (noted_fault_ == control::MotionFault::None) return;
  ErrorNote note;
  const bool device = noted_fault_ == control::MotionFault::Driver ||
                      noted_fault_ == control::MotionFault::DeviceLost;
  const drivers::LinkHealth h = link_.health();  // a seqlock copy: no allocation
  set_note(note, now_s, "fault ", control::motion_fault_name(noted_fault_),
           device && h.message[0] != '\0' ? ": " : "");
  if (device && h.message[0] != '\0') {
    const std::size_t used = std::strlen(note.text);
    const std::size_t n = std::min(std::strlen(h.message), sizeof note.text - 1 - used);
    std::memcpy(note.text + used, h.message, n);
    note.text[used + n] = '\0';
  }
  fault_note_.store(note);
}

}  // namespace idm::daemon
