// One axis inside the daemon: its region map, calibration and positioner, the channel of the
// device link it drives, and its motion state machine as the real-time loop runs it (commands,
// sweep trials, referencing flag, published status). The motion supervisor (supervisor.h) owns
// every Axis and calls the RT methods from the loop thread only; build() and the accessors
// marked so run on other threads while the loop is parked or not yet started.
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <string>
#include <variant>

#include "control/calibration.h"
#include "control/positioner.h"
#include "control/region_map.h"
#include "daemon/axis_step.h"
#include "daemon/config.h"
#include "drivers/link.h"
#include "drivers/lockfree.h"
#include "model/axis_io.h"

namespace idm::daemon {

using drivers::Seqlock;
using drivers::SpscRing;

// server -> loop. Stop with axis -1 stops every axis.
// What the server asks of one axis (or of every axis: Stop with axis -1), one type per command,
// each with its arguments named (positions in the axis's own frame, SI units).
namespace axis_command {
struct MoveAbsolute {
  double target_m = 0;
};
struct MoveRelative {
  double distance_m = 0;
};
struct Step {  // an omitted duty/frequency/stroke is NaN (control::Positioner::step_open_loop)
  std::int64_t cycles = 0;
  double duty = 0, freq_hz = 0, stroke_m = 0;
};
struct Stop {};
struct SetLimits {
  double lower_m = 0, upper_m = 0;
};
struct SetWindow {
  double window_m = 0;
};
struct SetDwell {
  double dwell_s = 0;
};
struct SetEot {
  double step_m = 0;
  int cycles = 0;
};
struct SetHold {
  double hold_s = 0, window_m = 0;
};
struct SetSpeed {
  double max_speed_m_s = 0;
};
struct Reference {
  int direction = -1;     // the way the end stop (or the mark's search) lies
  double position_m = 0;  // the position it sets there
  bool mark = false;      // find the reference mark (else the end stop)
};
using Body = std::variant<MoveAbsolute, MoveRelative, Step, Stop, SetLimits, SetWindow, SetDwell,
                          SetEot, SetHold, SetSpeed, Reference>;
}  // namespace axis_command

struct AxisCommand {
  axis_command::Body body = axis_command::Stop{};
  std::int32_t axis = -1;  // -1: every axis (Stop only)
  std::uint64_t seq = 0;   // the supervisor's, for the acknowledgement
  template <class T>
  bool is() const {
    return std::holds_alternative<T>(body);
  }
  // Motion: a move, a step or a reference (what a stop, a park or a sweep refuses).
  bool motion() const {
    return is<axis_command::MoveAbsolute>() || is<axis_command::MoveRelative>() ||
           is<axis_command::Step>() || is<axis_command::Reference>();
  }
};

// Published by the loop after every tick, per axis (seqlock).
// The settings in force for the motions that follow (MOVE:WINDow?, HOLD?, ...).
struct MotionSettings {
  double window_m = 0, dwell_s = 0, eot_step_m = 0, hold_s = 0, hold_window_m = 0;
  double hold_window_set_m = 0;  // as set (0: the move window)
  int eot_cycles = 0;
  double max_speed_m_s = 0;  // 0: no limit
};

struct AxisPublished {
  control::MotionStatus motion;
  MotionSettings settings;
  bool referencing = false;
  double soft_lower_m = 0, soft_upper_m = 0;
  bool trial_active = false;
  bool referenced = false;
  bool parked = false;
};

// An error text with the time it happened (CLOCK_MONOTONIC), through a seqlock; NUL terminated.
struct ErrorNote {
  double t_s = -1;  // < 0: none
  char text[224] = {};
};
// Copies text into note (truncated); no allocation.
void set_note(ErrorNote& note, double t_s, const char* a, const char* b = "", const char* c = "");

// loop -> log (housekeeping): an axis entered FAULT, or a motion (MOVE, STEP, REFerence, a
// hold's correction) ended other than OK or STOPPED. One per event, never per tick; a motion that
// ended in a fault is the fault's note (`ended_motion`), not a second one.
struct MotionNote {
  enum class Kind : std::uint8_t { Fault, Ended };
  Kind kind = Kind::Fault;
  control::MotionFault fault = control::MotionFault::None;
  control::MoveResult result = control::MoveResult::None;
  control::MotionKind motion = control::MotionKind::None;  // what the motion was
  bool ended_motion = false;  // a fault: it ended the motion in progress
  bool position_valid = false;
  double position_m = 0, target_m = 0, distance_m = 0;  // distance: target - position
  int eot = 0;                                          // END_OF_TRAVEL: -1 low, +1 high
  double user_offset_m = 0;  // Axis::user_offset_m then: the line gives positions as clients do
};
using MotionNotes = SpscRing<MotionNote, 32>;
// The note as one log line: "axis x: FAULT stall, ending its MOVE: position ... m, target ... m,
// distance ... m" / "axis x: STEP ended LIMIT: position ...". Positions in the clients' (user)
// frame, with ", user offset ... m" when the axis has one.
std::string motion_note_text(const std::string& axis, const MotionNote& note);

// A sweep trial: recorder -> loop.
struct TrialRequest {
  std::uint32_t index = 0;
  std::uint32_t seq = 0;  // unique across sweeps (the recorder's running number, top bit set):
                          // the notices and the capture records of this trial carry it
  std::int32_t axis = 0;
  model::Segment segment;
  double return_to_m = 0;  // NaN: play where the slider is
  // The sweep's start: where a trial the motion gate refuses from here returns to first, if it
  // may run from there (NaN: nowhere).
  double home_m = 0;
};
enum class TrialFailure : std::uint8_t {
  None,
  Positioning,
  Driver,
  Overflow,
  Stopped,
  Busy,
  Limits,       // the motion gate: it could leave the soft limits from here and from home
  LeftLimits,   // a reading left the soft limits while it played: stopped at once
  EndOfTravel,  // it could reach the end of travel the axis met before
  NoPosition,   // no valid position to judge it from
};
const char* trial_failure_text(TrialFailure why);
// loop -> recorder: the trial's segment started (its samples follow on the capture queue), or it
// failed before or while playing.
struct TrialNotice {
  enum class Kind : std::uint8_t { Started, Failed };
  Kind kind = Kind::Started;
  std::uint32_t index = 0;
  std::uint32_t seq = 0;
  TrialFailure why = TrialFailure::None;
};
using TrialNotices = SpscRing<TrialNotice, 64>;

class Axis {
 public:
  // `link_index`: the axis's channel among the link's (config.channel is the device's own).
  Axis(const AxisConfig& config, drivers::DeviceLink& link, std::size_t link_index);
  ~Axis() = default;
  Axis(const Axis&) = delete;
  Axis& operator=(const Axis&) = delete;

  // ---- not real-time: before the loop starts, or while it is parked ----
  // Builds the map (when `control` changes its grid, or the first time), the calibration (first
  // time: loaded from its file) and the positioner. Throws model::InputError.
  void build(const ControlConfig& control);
  // A map for `control` built ahead (allocates; outside the park), installed by build().
  void prepare(const ControlConfig& control);
  void set_soft_limits_now(double lower_m, double upper_m);
  // Before the loop starts: the axis is referenced with a reference an earlier run found (its
  // offset, control::MotionStatus::offset_m; daemon/reference_file.h says when it holds).
  void restore_reference(double offset_m);

  // ---- the loop thread ----
  control::Refusal apply(const AxisCommand& command);
  void tick(double now_s, TrialNotices& notices);
  // STOP (and shutdown): the move ends at its chunk's end, a trial at once.
  void stop(TrialNotices& notices);
  bool start_trial(const TrialRequest& trial, TrialNotices& notices);
  bool trial_active() const { return trial_phase_ != TrialPhase::Idle; }
  // A trial's segment has been handed to the link and its end not yet seen: the next trial waits.
  bool trial_finishing() const { return trial_phase_ == TrialPhase::Playing; }
  bool at_rest() const { return positioner_->at_rest() && trial_phase_ == TrialPhase::Idle; }
  // At rest with nothing for the link still to be handed (the loop may tick at its rest rate).
  bool quiet() const { return at_rest() && !pending_.due; }
  // Done (MOVE:DONE? 1, *OPC?): at rest, or holding the target of a move that arrived.
  bool done() const { return positioner_->done() && trial_phase_ == TrialPhase::Idle; }
  void publish(bool parked);
  // The target of the last command (refused or accepted), NaN when none.
  double requested_target_m() const { return positioner_->requested_target_m(); }

  // ---- any thread ----
  AxisPublished published() const { return published_.load(); }
  ErrorNote fault_note() const { return fault_note_.load(); }
  const AxisConfig& config() const { return config_; }
  const ControlConfig& control() const { return control_; }  // loop parked / non-RT owner
  const control::DeviceLimits& limits() const { return limits_; }
  const control::RegionMap& map() const { return *map_; }
  control::Calibration* calibration() { return calibration_.get(); }
  drivers::ChannelPort& port() { return port_; }
  drivers::DeviceLink& link() { return link_; }
  std::size_t channel() const { return link_index_; }
  double count_m() const { return count_m_.load(std::memory_order_relaxed); }
  // The user offset (POSition:SET, POSition:OFFSet): what the protocol's positions add to the
  // axis's own (user = dial + offset, as the EPICS motor record's OFF). The loop and the control
  // layer work in the dial frame and never read it; set by the server thread (and at start, with
  // a restored reference), read by any.
  double user_offset_m() const { return user_offset_m_.load(std::memory_order_relaxed); }
  void set_user_offset_m(double offset_m) {
    user_offset_m_.store(offset_m, std::memory_order_relaxed);
  }
  // The interferometer reports crossing a reference mark (REFerence MARK can find it).
  bool has_reference_mark() const { return has_reference_mark_; }
  // The calibration as the loop last published it (a copy), and its update count.
  control::CalibrationState calibration_snapshot() const { return calibration_snapshot_.load(); }
  // ---- one consumer thread (housekeeping) ----
  // The next fault or failed motion to log (false: none); and how many the loop could not queue.
  bool take_motion_note(MotionNote& out) { return motion_notes_.pop(out); }
  std::uint64_t motion_notes_dropped() const {
    return motion_notes_dropped_.load(std::memory_order_relaxed);
  }

 private:
  enum class TrialPhase : std::uint8_t { Idle, Positioning, Starting, Playing };
  void observe(const model::AxisEvent& e, TrialNotices& notices);
  void trial_tick(TrialNotices& notices);
  void fail_trial(TrialFailure why, TrialNotices& notices);
  void note_fault(double now_s);
  void note_motion();  // a fault entered or a motion ended: a MotionNote for the log

  AxisConfig config_;
  drivers::DeviceLink& link_;
  std::size_t link_index_;
  drivers::ChannelPort& port_;
  // Written by build() (start, reload: housekeeping), read by the sessions' status unlocked.
  std::atomic<double> count_m_{0};
  std::atomic<double> user_offset_m_{0};
  const bool has_reference_mark_;  // the device's, fixed at construction (any thread reads it)
  ControlConfig control_;
  control::DeviceLimits limits_;
  std::unique_ptr<control::RegionMap> map_, next_map_;
  control::DeviceLimits next_limits_;
  std::unique_ptr<control::Calibration> calibration_;
  std::unique_ptr<control::Positioner> positioner_;
  double soft_lower_m_ = 0, soft_upper_m_ = 0;

  // Loop thread.
  PendingRequest pending_;
  bool referenced_ = false;
  std::uint64_t references_seen_ = 0;
  control::MotionFault noted_fault_ = control::MotionFault::None;
  std::uint64_t noted_ended_ = 0;  // the positioner's motions_ended at the last publication
  std::uint64_t calibration_published_ = 0;
  double now_s_ = 0;
  TrialPhase trial_phase_ = TrialPhase::Idle;
  TrialRequest trial_{};
  std::uint32_t trial_seq_ = 0;
  double trial_start_m_ = 0;  // the reading when its segment was handed to the link

  Seqlock<AxisPublished> published_;
  Seqlock<ErrorNote> fault_note_;
  Seqlock<control::CalibrationState> calibration_snapshot_;
  MotionNotes motion_notes_;
  std::atomic<std::uint64_t> motion_notes_dropped_{0};
  AxisPublished pub_;
};

}  // namespace idm::daemon
