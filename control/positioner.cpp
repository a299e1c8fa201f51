#include "control/positioner.h"

#include <algorithm>
#include <cmath>

#include "control/calibration.h"
#include "model/impulse_model.h"
#include "model/waveform.h"
#include "model/yaml_util.h"

namespace idm::control {

namespace {


int direction_index(int sign) { return sign > 0 ? 1 : 0; }

}  // namespace

const model::ParamTable<PositionerConfig>& positioner_params() {
  using model::integer;
  using model::real;
  using model::with_default;
  using P = PositionerConfig;
  static const model::ParamTable<P> table({
      real<P>("tolerance_m", "m", {0, 1e-3}, "the in-position window (RDBD, MOVE:WINDow); 0: one count (the loop aims for half a count within it)",
              [](auto& c) -> auto& { return c.tolerance_m; }),
      integer<P>("max_retries", "count", 0, 1000, "correction rounds after the first plan (RTRY)",
                 [](auto& c) -> auto& { return c.max_retries; }),
      integer<P>("stall_bursts", "count", 1, 1000, "bursts in a row without progress: a stall fault",
                 [](auto& c) -> auto& { return c.stall_bursts; }),
      real<P>("stall_fraction", "1", {0, 1, false, true}, "a burst that moved less than this share of its prediction made no progress",
              [](auto& c) -> auto& { return c.stall_fraction; }),
      real<P>("settle_s", "s", {0, 10}, "after a burst, wait this long before the position is read",
              [](auto& c) -> auto& { return c.settle_s; }),
      real<P>("max_chunk_s", "s", {0, 10, true}, "the longest piece played at once: what a STOP waits for (must fit the capture)",
              [](auto& c) -> auto& { return c.max_chunk_s; }),
      integer<P>("latch_words", "count", 1, 1000, "readings averaged for a position at rest",
                 [](auto& c) -> auto& { return c.latch_words; }),
      with_default(real<P>("soft_lower_m", "m", {-10, 10}, "soft limit (LLM): a move or STEP ending below is refused",
                           [](auto& c) -> auto& { return c.soft_lower_m; }),
                   "stage.travel_m"),
      with_default(real<P>("soft_upper_m", "m", {-10, 10}, "soft limit (HLM): a move or STEP ending above is refused",
                           [](auto& c) -> auto& { return c.soft_upper_m; }),
                   "stage.travel_m"),
      real<P>("approach_uncertainty", "1", {0, 10}, "share by which an approach burst may exceed its prediction",
              [](auto& c) -> auto& { return c.approach_uncertainty; }),
      real<P>("stall_min_counts", "count", {0, 1e6}, "chunks predicted to move fewer counts are not judged for a stall",
              [](auto& c) -> auto& { return c.stall_min_counts; }),
      integer<P>("max_chunks_per_move", "count", 0, 100000000, "most chunks in one move (0: the planner's max_bursts)",
                 [](auto& c) -> auto& { return c.max_chunks_per_move; }),
      real<P>("final_step_counts", "count", {0.5, 1000}, "the last chunks use a rung of at most this step",
              [](auto& c) -> auto& { return c.final_step_counts; }),
      real<P>("min_step_counts", "count", {0, 1000, false, true}, "a rung stepping less per cycle is taken as not moving (< final_step_counts)",
              [](auto& c) -> auto& { return c.min_step_counts; }),
      integer<P>("dead_rung_moves", "count", 1, 1000000, "a rung judged not to move is left out for this many moves",
                 [](auto& c) -> auto& { return c.dead_rung_moves; }),
      real<P>("chunk_overhead_s", "s", {0, 10}, "time a chunk costs beyond its cycles (planning weight)",
              [](auto& c) -> auto& { return c.chunk_overhead_s; }),
      real<P>("dwell_s", "s", {0, 60}, "a move is done once fresh readings stayed in the window this long (MOVE:DWELl)",
              [](auto& c) -> auto& { return c.dwell_s; }),
      real<P>("move_timeout_s", "s", {0, 86400}, "a move not done after this long ends with TIMEOUT (0: no limit)",
              [](auto& c) -> auto& { return c.move_timeout_s; }),
      real<P>("eot_step_m", "m", {0, 1e-3}, "end of travel: mean step below this while driving stops the axis (0: off; EOT:STEP)",
              [](auto& c) -> auto& { return c.eot_step_m; }),
      integer<P>("eot_cycles", "count", 1, 100000, "end of travel: the cycles the mean step is taken over (EOT:CYCLes)",
                 [](auto& c) -> auto& { return c.eot_cycles; }),
      real<P>("hold_s", "s", {-1, 86400}, "after a move: keep the target this long (0: no hold, -1: until the next motion; HOLD)",
              [](auto& c) -> auto& { return c.hold_s; }),
      real<P>("hold_window_m", "m", {0, 1e-3}, "a hold corrects when a reading leaves this window (0: the move window; HOLD:WINDow)",
              [](auto& c) -> auto& { return c.hold_window_m; }),
  });
  return table;
}

void validate(const PositionerConfig& c, const std::string& where) {
  // Infinite soft limits are allowed in code (no limit); files always give finite ones.
  PositionerConfig finite = c;
  if (std::isinf(finite.soft_lower_m)) finite.soft_lower_m = -10;
  if (std::isinf(finite.soft_upper_m)) finite.soft_upper_m = 10;
  positioner_params().validate(finite, where);
  if (std::isnan(c.soft_lower_m) || std::isnan(c.soft_upper_m) || !(c.soft_lower_m < c.soft_upper_m))
    throw model::InputError(where + ".soft_lower_m/soft_upper_m: [" + model::format_number(c.soft_lower_m) +
                            ", " + model::format_number(c.soft_upper_m) +
                            "] is not an interval, allowed soft_lower_m < soft_upper_m");
  if (c.hold_s < 0 && c.hold_s != -1)
    throw model::InputError(where + ".hold_s: " + model::format_number(c.hold_s) +
                            " is out of range, allowed -1 (until the next motion) or [0, 86400]");
  if (!(c.min_step_counts < c.final_step_counts))
    throw model::InputError(where + ".min_step_counts: " + model::format_number(c.min_step_counts) +
                            " must be below final_step_counts (" + model::format_number(c.final_step_counts) + ")");
}

const char* motion_state_name(MotionState s) {
  switch (s) {
    case MotionState::Idle: return "IDLE";
    case MotionState::Moving: return "MOVING";
    case MotionState::Settling: return "SETTLING";
    case MotionState::Fault: return "FAULT";
  }
  return "?";
}

const char* motion_fault_name(MotionFault f) {
  switch (f) {
    case MotionFault::None: return "none";
    case MotionFault::InvalidSample: return "invalid_sample";
    case MotionFault::Stall: return "stall";
    case MotionFault::RetryLimit: return "retry_limit";
    case MotionFault::Driver: return "driver";
    case MotionFault::NoPlan: return "no_plan";
    case MotionFault::CaptureOverrun: return "capture_overrun";
    case MotionFault::DeviceLost: return "device_lost";
  }
  return "?";
}

const char* move_result_name(MoveResult r) {
  switch (r) {
    case MoveResult::None: return "NONE";
    case MoveResult::Ok: return "OK";
    case MoveResult::Stopped: return "STOPPED";
    case MoveResult::Limit: return "LIMIT";
    case MoveResult::EndOfTravel: return "END_OF_TRAVEL";
    case MoveResult::Fault: return "FAULT";
    case MoveResult::Timeout: return "TIMEOUT";
  }
  return "?";
}

const char* refusal_name(Refusal r) {
  switch (r) {
    case Refusal::None: return "none";
    case Refusal::NotFinite: return "not_finite";
    case Refusal::OutsideSoftLimits: return "outside_soft_limits";
    case Refusal::Faulted: return "faulted";
    case Refusal::Busy: return "busy";
    case Refusal::OutOfRange: return "out_of_range";
    case Refusal::NoPosition: return "no_position";
    case Refusal::NotReferenced: return "not_referenced";
    case Refusal::EndOfTravel: return "end_of_travel";
  }
  return "?";
}

Positioner::Positioner(const RegionMap& map, const PlannerConfig& planner,
                       const PositionerConfig& config, const AxisDeviceInfo& device,
                       Calibration* calibration)
    : map_(map),
      planner_(planner),
      config_(config),
      device_(device),
      calibration_(calibration) {
  validate(config_);
  if (!(device_.count_m > 0))
    throw model::InputError("control: the interferometer's count must be > 0");
  count_m_ = device_.count_m;
  const DeviceLimits& limits = map_.config().limits;
  buffered_ = device_.buffered;
  if (buffered_) {
    sample_rate_hz_ = limits.output_sample_rate_hz;
    if (!(sample_rate_hz_ > 0))
      throw model::InputError(
          "control: the output takes samples but the map has no output clock "
          "(limits.output_sample_rate_hz = 0); set it to the output's sample rate");
    // The largest chunk: whole cycles within max_chunk_s, or one cycle of the lowest frequency.
    const double longest_cycle = std::ceil(sample_rate_hz_ / limits.min_freq_hz) + 1;
    const double chunk = std::floor(config_.max_chunk_s * sample_rate_hz_) + 1;
    double n = std::max(longest_cycle, chunk) + 1;
    n = std::min(n, static_cast<double>(device_.max_burst_samples));
    max_chunk_samples_ = static_cast<std::size_t>(n);
  }
  // A chunk's samples must fit the interferometer's capture: some devices keep a whole burst's
  // records until its end (a Modbus capture), so a longer chunk would overrun it mid-move.
  {
    const double longest_s = std::max(config_.max_chunk_s, 1.0 / limits.min_freq_hz);
    const double records = std::ceil(longest_s * device_.stream_rate_hz) + 1;
    if (records > static_cast<double>(device_.stream_capacity)) {
      const double fit_s = (static_cast<double>(device_.stream_capacity) - 1) / device_.stream_rate_hz;
      throw model::InputError(
          "control.max_chunk_s / control.min_freq_hz: the longest chunk (" +
          model::format_number(longest_s) + " s: max_chunk_s, or one cycle at min_freq_hz) is " +
          model::format_number(records) + " records of the interferometer's " +
          model::format_number(device_.stream_rate_hz) + " Hz capture, more than the " +
          std::to_string(device_.stream_capacity) +
          " it holds for one burst; set max_chunk_s <= " + model::format_number(fit_s) +
          " and min_freq_hz >= " + model::format_number(1.0 / fit_s) +
          " (or a larger capture: the device's stream/capture capacity)");
    }
  }
  max_chunks_ = config_.max_chunks_per_move > 0 ? config_.max_chunks_per_move : planner_.max_bursts;
  plan_.bursts.reserve(static_cast<std::size_t>(planner_.max_bursts));
  // The largest-step usable cell per direction (open-loop steps without a waveform), and the
  // fastest slider the map's cells can make: the velocity jump m/(M+m) times the fast phase's
  // rate. The interferometer's decoder must accept it, or real motion reads as glitches.
  double largest[2] = {0, 0};
  double fastest_m_s = 0;
  const model::StageParams& stage = map_.config().stage;
  for (std::size_t i : map_.usable_cells()) {
    const RegionCell& c = map_.cells()[i];
    const double fast_share = std::min(c.duty, 1.0 - c.duty);
    fastest_m_s = std::max(fastest_m_s, stage.mass_ratio() * c.stroke_m * c.freq_hz / fast_share);
    const int d = direction_index(c.direction());
    const double along = std::fabs(c.step_m);
    if (along > largest[d]) {
      largest[d] = along;
      largest_cell_[d] = i;
      has_largest_cell_[d] = true;
    }
  }
  const double max_velocity = device_.max_velocity_m_s;
  if (fastest_m_s > max_velocity)
    throw model::InputError(
        "interferometer.max_velocity_m_s: " + model::format_number(max_velocity) +
        " m/s is below the slider's fastest velocity jump in the usable cells of the map (" +
        model::format_number(fastest_m_s) +
        " m/s: m/(M+m) times the fast phase's rate); real motion would read as glitches. Raise "
        "it above that, or narrow the map (limits.max_freq_hz, limits.max_stroke_m)");
  build_ladder();
  status_.state = MotionState::Idle;
  status_.window_m = tolerance_m();
}

double Positioner::tolerance_m() const {
  return config_.tolerance_m > 0 ? config_.tolerance_m : count_m_;
}

double Positioner::landing_m() const {
  // Within a window of up to one count the loop aims for the reading nearest the target (half a
  // count), so that the slider itself, read again later with noise, stays inside the window;
  // a wider window is aimed at as it is.
  return tolerance_m() > count_m_ * (1 + 1e-9) ? tolerance_m() : 0.5 * count_m_;
}

bool Positioner::at_rest() const {
  return status_.state == MotionState::Idle || status_.state == MotionState::Fault;
}

// ---- commands ----

void Positioner::start_motion(MotionKind kind) {
  status_.kind = kind;
  status_.result = MoveResult::None;
  status_.corrections = 0;
  status_.fault = MotionFault::None;
  status_.in_window = false;
  status_.holding = false;
  hold_armed_ = false;
  hold_correcting_ = false;
  referencing_ = false;
  stop_requested_ = false;
  stop_result_ = MoveResult::Stopped;
  last_try_done_ = false;
  stall_count_ = 0;
  streak_cycles_ = 0;
  streak_along_m_ = 0;
  move_chunks_ = 0;
  move_cycles_ = 0;
  move_started_ = false;
  eot_count_ = 0;
  eot_next_ = 0;
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
  if (target_m < config_.soft_lower_m || target_m > config_.soft_upper_m)
    return Refusal::OutsideSoftLimits;
  if (!status_.position_valid) return Refusal::NoPosition;
  if (toward_eot(target_m)) return Refusal::EndOfTravel;
  status_.eot = 0;  // a move away from it
  load_rung_estimates();
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
  if (!status_.position_valid) return phase_ == Phase::Fault ? Refusal::Faulted : Refusal::NoPosition;
  // From the target when in position (no creep of the error from move to move), else the reading.
  const double base = status_.in_window ? status_.target_m : status_.position_m;
  return move_absolute(base + distance_m);
}

double Positioner::nominal_open_loop_step_m(double freq_hz, double duty, double stroke_m) const {
  return model::steady_step_corrected_m(map_.config().stage, freq_hz, duty, stroke_m);
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
    const RegionCell& cell = map_.cells()[largest_cell_[d]];
    c.freq_hz = cell.freq_hz;
    c.duty = cell.duty;
    c.stroke_m = std::min(stroke_m, cell.stroke_m);
    c.period_samples = cell.period_samples;
    c.extension_samples = cell.extension_samples;
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
  const double reach = static_cast<double>(n) * step * (1.0 + config_.approach_uncertainty);
  const double far_end = status_.position_m + reach;
  if (std::min(end, far_end) < config_.soft_lower_m || std::max(end, far_end) > config_.soft_upper_m)
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

Refusal Positioner::reference(int direction, double position_at_stop_m) {
  requested_target_m_ = std::numeric_limits<double>::quiet_NaN();
  if (!std::isfinite(position_at_stop_m)) return Refusal::NotFinite;
  if (phase_ == Phase::Fault) return Refusal::Faulted;
  if (phase_ != Phase::Idle) return Refusal::Busy;
  if (!status_.position_valid) return Refusal::NoPosition;
  const int sign = direction > 0 ? 1 : -1;
  const int d = direction_index(sign);
  if (!has_largest_cell_[d]) return Refusal::OutOfRange;
  const RegionCell& cell = map_.cells()[largest_cell_[d]];
  Chunk c;
  c.freq_hz = cell.freq_hz;
  c.duty = cell.duty;
  c.stroke_m = cell.stroke_m;
  c.period_samples = cell.period_samples;
  c.extension_samples = cell.extension_samples;
  const double step = nominal_open_loop_step_m(c.freq_hz, c.duty, c.stroke_m);
  if (!(std::fabs(step) > 0)) return Refusal::OutOfRange;
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
  status_.closed_loop = false;
  status_.eot = 0;
  start_motion(MotionKind::Reference);
  referencing_ = true;
  reference_position_m_ = position_at_stop_m;
  status_.target_m = position_at_stop_m;
  target_known_ = true;
  return Refusal::None;
}

Refusal Positioner::set_window(double window_m) {
  if (!std::isfinite(window_m)) return Refusal::NotFinite;
  if (window_m < 0 || window_m > 1e-3) return Refusal::OutOfRange;
  config_.tolerance_m = window_m;
  status_.window_m = tolerance_m();
  return Refusal::None;
}

Refusal Positioner::set_dwell(double dwell_s) {
  if (!std::isfinite(dwell_s)) return Refusal::NotFinite;
  if (dwell_s < 0 || dwell_s > 60) return Refusal::OutOfRange;
  config_.dwell_s = dwell_s;
  return Refusal::None;
}

Refusal Positioner::set_eot(double step_m, int cycles) {
  if (!std::isfinite(step_m)) return Refusal::NotFinite;
  if (step_m < 0 || step_m > 1e-3 || cycles < 1 || cycles > 100000) return Refusal::OutOfRange;
  config_.eot_step_m = step_m;
  config_.eot_cycles = cycles;
  return Refusal::None;
}

Refusal Positioner::set_hold(double hold_s, double window_m) {
  if (!std::isfinite(hold_s) || !std::isfinite(window_m)) return Refusal::NotFinite;
  if (!(hold_s == -1 || (hold_s >= 0 && hold_s <= 86400)) || window_m < 0 || window_m > 1e-3)
    return Refusal::OutOfRange;
  config_.hold_s = hold_s;
  config_.hold_window_m = window_m;
  return Refusal::None;
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
  status_.eot = previous.eot;
  status_.eot_position_m = previous.eot_position_m;
  status_.moved_dirs = previous.moved_dirs;
  status_.references = previous.references;
  status_.offset_m = previous.offset_m;
  offset_m_ = previous.offset_m;
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
  referencing_ = false;
  if (moving || status_.result == MoveResult::None) {
    status_.result = MoveResult::Fault;
    status_.result_distance_m = status_.target_m - status_.position_m;
  }
}

// ---- readings ----

void Positioner::on_event(const model::AxisEvent& e) {
  using Kind = model::AxisEvent::Kind;
  switch (e.kind) {
    case Kind::Reading:
      on_reading(e);
      return;
    case Kind::SegmentStarted:
      return;
    case Kind::SegmentDone:
      if (phase_ != Phase::Playing || e.seq != seq_) return;
      phase_ = Phase::Settling;
      status_.state = MotionState::Settling;
      settle_until_s_ = e.t_s + config_.settle_s;
      want_fresh(settle_until_s_);
      return;
    case Kind::OutputFailed:
      if (phase_ == Phase::Playing && e.seq == seq_) enter_fault(MotionFault::Driver);
      return;
    case Kind::DeviceLost:
      lost_at_rest_ = at_rest() && phase_ != Phase::Fault;
      device_lost_ = true;
      status_.position_valid = false;
      if (phase_ != Phase::Fault) enter_fault(MotionFault::DeviceLost);
      return;
    case Kind::DeviceBack:
      device_lost_ = false;
      // Back at rest with its count: nothing was lost, the axis carries on. Otherwise the fault
      // stays until a reset (a motion was cut short, or the position may have jumped).
      if (lost_at_rest_ && e.count_kept && status_.fault == MotionFault::DeviceLost) reset_fault();
      return;
  }
}

void Positioner::on_reading(const model::AxisEvent& e) {
  if (device_lost_) return;
  if (!e.valid()) {
    status_.position_valid = false;
    invalid_sample_status_ = e.status;
    // An overrun is the capture being too small for the chunk, not the beam: say so.
    if (phase_ != Phase::Fault)
      enter_fault(e.overrun ? MotionFault::CaptureOverrun : MotionFault::InvalidSample);
    return;
  }
  const double position = e.position_m + offset_m_;
  status_.position_m = position;
  chunk_lo_m_ = std::min(chunk_lo_m_, position);
  chunk_hi_m_ = std::max(chunk_hi_m_, position);
  status_.position_valid = true;
  if (!target_known_) {  // before the first motion the target is where the slider is (VAL = RBV)
    status_.target_m = position;
    target_known_ = true;
  }
  if ((phase_ == Phase::Pending || phase_ == Phase::Settling || phase_ == Phase::Dwell) &&
      !e.in_segment && e.t_s >= fresh_.after_s && fresh_.count < config_.latch_words) {
    fresh_.sum_m += position;
    ++fresh_.count;
    fresh_.worst_m = std::max(fresh_.worst_m, std::fabs(status_.target_m - position));
  }
  if (hold_armed_ && phase_ == Phase::Idle && !e.in_segment) {
    // Holding: the mean of latch_words readings at rest against the hold window.
    hold_sum_m_ += position;
    if (++hold_n_ >= config_.latch_words) {
      const double mean = hold_sum_m_ / hold_n_;
      hold_sum_m_ = 0;
      hold_n_ = 0;
      const double window = config_.hold_window_m > 0 ? config_.hold_window_m : tolerance_m();
      status_.in_window = std::fabs(status_.target_m - mean) <= window;
      if (!status_.in_window) hold_correction_due_ = true;
    }
  }
}

void Positioner::want_fresh(double after_s) {
  fresh_ = Fresh{};
  fresh_.after_s = after_s;
}

bool Positioner::fresh_position(double& position_m) {
  if (fresh_.count >= config_.latch_words) {
    position_m = fresh_.sum_m / fresh_.count;
    status_.position_m = position_m;
    return true;
  }
  if (!fresh_.requested && now_s_ >= fresh_.after_s && !request_due_) {
    // Ask for them now rather than wait for the link's rest polling.
    request_ = model::OutputRequest{};
    request_.kind = model::OutputRequest::Kind::Read;
    request_.readings = static_cast<std::uint32_t>(config_.latch_words);
    request_.seq = seq_;
    request_due_ = true;
    fresh_.requested = true;
  }
  return false;
}

// ---- playing ----

std::uint64_t Positioner::chunk_cycle_limit(double freq_hz, std::uint32_t period_samples,
                                            std::uint64_t max_cycles) const {
  double n = std::floor(config_.max_chunk_s * freq_hz * (1 + 1e-12));
  if (buffered_ && period_samples > 0)
    n = std::min(n, std::floor(static_cast<double>(max_chunk_samples_ - 1) / period_samples));
  if (max_cycles > 0) n = std::min(n, static_cast<double>(max_cycles));
  const DeviceLimits& lim = map_.config().limits;
  n = std::min(n, static_cast<double>(lim.max_burst_cycles));
  if (!buffered_) n = std::min(n, static_cast<double>(device_.max_cycles));
  return n < 1 ? 1 : static_cast<std::uint64_t>(n);
}

void Positioner::start_chunk() {
  const Chunk& c = chunk_;
  model::Segment seg;
  seg.freq_hz = c.freq_hz;
  seg.duty = c.duty;
  seg.stroke_m = c.stroke_m;
  seg.cycles = c.cycles;
  if (buffered_) {
    seg.sample_rate_hz = sample_rate_hz_;
    seg.period_samples = c.period_samples;
    seg.extension_samples = c.extension_samples;
    if (c.period_samples < 2 || c.extension_samples < 1 ||
        c.extension_samples >= c.period_samples || seg.sample_count() > max_chunk_samples_) {
      enter_fault(MotionFault::Driver);  // a chunk the output cannot take: never played
      return;
    }
  }
  request_ = model::OutputRequest{};
  request_.kind = model::OutputRequest::Kind::Play;
  request_.seq = ++seq_;
  request_.segment = seg;
  request_due_ = true;
  chunk_start_position_m_ = status_.position_m;
  chunk_lo_m_ = chunk_hi_m_ = status_.position_m;
  ++status_.bursts;
  ++move_chunks_;
  status_.cycles += c.cycles;
  move_cycles_ += c.cycles;
  phase_ = Phase::Playing;
  status_.state = MotionState::Moving;
}

void Positioner::finish(double now_s, MoveResult result) {
  phase_ = Phase::Idle;
  status_.state = MotionState::Idle;
  stop_requested_ = false;
  if (hold_correcting_) {
    hold_correcting_ = false;
    if (result == MoveResult::Ok) {  // back in the window: holding on
      hold_armed_ = true;
      status_.in_window = true;
      return;
    }
    status_.holding = false;
  }
  status_.last_move_time_s = now_s - move_start_s_;
  status_.result = result;
  status_.result_distance_m = status_.target_m - status_.position_m;
  status_.in_window = status_.kind == MotionKind::Move && result == MoveResult::Ok;
  referencing_ = false;
  if (status_.in_window && config_.hold_s != 0) {
    hold_armed_ = true;
    status_.holding = true;
    hold_until_s_ = config_.hold_s < 0 ? std::numeric_limits<double>::infinity() : now_s + config_.hold_s;
    hold_sum_m_ = 0;
    hold_n_ = 0;
    hold_correction_due_ = false;
  }
}

void Positioner::arrived(double now_s) {
  if (config_.dwell_s > 0 && !hold_correcting_) {
    if (phase_ != Phase::Dwell) {
      phase_ = Phase::Dwell;
      status_.state = MotionState::Settling;
      dwell_until_s_ = now_s + config_.dwell_s;
    }
    want_fresh(now_s);
    return;
  }
  finish(now_s, MoveResult::Ok);
}

void Positioner::dwell_tick(double now_s) {
  if (stop_requested_) {
    finish(now_s, stop_result_);
    return;
  }
  double p = 0;
  const double worst = fresh_.worst_m;
  if (!fresh_position(p)) return;
  // Every reading of the dwell, not only their mean: a slider near the window's edge that the
  // noise reads outside now and then is read outside by a client too.
  if (worst > tolerance_m()) {
    // It left the window during the dwell: correct again. Counted on its own (the mean may still
    // say arrived, and then nothing is played before the next dwell): five times max_retries.
    if (++dwell_failures_ > 5 * std::max(config_.max_retries, 1)) {
      enter_fault(MotionFault::RetryLimit);
      return;
    }
    last_try_done_ = false;
    phase_ = Phase::Settling;
    plan_next_chunk(now_s);
    return;
  }
  if (now_s >= dwell_until_s_)
    finish(now_s, MoveResult::Ok);
  else
    want_fresh(now_s);
}

void Positioner::hold_tick(double now_s) {
  if (!hold_armed_) return;
  if (now_s >= hold_until_s_) {
    hold_armed_ = false;
    status_.holding = false;
    return;
  }
  if (!hold_correction_due_ || !status_.position_valid) return;
  hold_correction_due_ = false;
  // A correction back to the target: a move of its own, the hold carrying on after it.
  load_rung_estimates();
  const std::uint64_t moves = status_.moves;
  start_motion(MotionKind::Move);
  status_.moves = moves;
  status_.holding = true;
  hold_correcting_ = true;
  status_.closed_loop = true;
}

bool Positioner::end_of_travel_seen(double moved_m) {
  const double eot_step = config_.eot_step_m > 0 ? config_.eot_step_m : (referencing_ ? 0.25 * count_m_ : 0.0);
  if (!(eot_step > 0) || chunk_.cycles == 0) return false;
  const int sign = chunk_.direction != 0 ? chunk_.direction : (chunk_.predicted_m >= 0 ? 1 : -1);
  // Only chunks that were expected to move well above the threshold say anything: open-loop
  // chunks at their nominal step; closed-loop chunks of a rung not of the final class that has
  // moved as predicted before (on a compliant stage whole groups of cells stand still on some
  // stretches of the guide, and a fine rung near cut-off often does).
  bool expected = false, proven = true;
  if (chunk_.rung < 0) {
    expected = std::fabs(open_loop_.predicted_m) >= 5.0 * eot_step;
  } else {
    const Rung& r = ladder_[direction_index(sign)][static_cast<std::size_t>(chunk_.rung)];
    expected = r.est.step_m >= std::max(5.0 * eot_step, config_.final_step_counts * count_m_);
    proven = r.proven;
  }
  if (!expected) return false;
  // A collapse needs steps before it: a slider that has never moved this way is stuck (a stall
  // fault), not at the end of its travel. A reference looks for the stop, wherever it starts.
  const double expected_along = chunk_.rung < 0 ? std::fabs(open_loop_.predicted_m) * static_cast<double>(chunk_.cycles)
                                                : std::max(chunk_.predicted_along_m, 0.0);
  const std::uint8_t bit = static_cast<std::uint8_t>(1u << direction_index(sign));
  const bool had_moved = (status_.moved_dirs & bit) != 0 || referencing_;
  const double along = sign * moved_m;
  if (along >= std::max(0.5 * expected_along, 3.0 * count_m_)) status_.moved_dirs |= bit;
  if (!had_moved) return false;
  // Thrown back farther than the chunk could step: at a hard stop the step's momentum goes into
  // the stop and the return stroke's does not.
  // (A compliant stage moves a cell the wrong way by a few steps at times: far beyond that only.)
  if (-along > std::max(5.0 * expected_along, 1000.0 * count_m_)) return true;
  // Closed loop: the run of non-moving chunks that makes a stall (judge_and_learn) decides; one
  // rung standing still on a stretch of the guide is the ladder's business.
  if (!proven || chunk_.rung >= 0) return false;
  eot_chunks_[eot_next_] = EotChunk{chunk_.cycles, along};
  eot_next_ = (eot_next_ + 1) % kEotChunks;
  eot_count_ = std::min(eot_count_ + 1, kEotChunks);
  std::uint64_t cycles = 0;
  double sum = 0;
  for (int k = 1; k <= eot_count_ && cycles < static_cast<std::uint64_t>(config_.eot_cycles); ++k) {
    const EotChunk& c = eot_chunks_[(eot_next_ - k + kEotChunks) % kEotChunks];
    cycles += c.cycles;
    sum += c.along_m;
  }
  if (cycles < static_cast<std::uint64_t>(config_.eot_cycles)) return false;
  return sum / static_cast<double>(cycles) < eot_step;
}

void Positioner::end_of_travel(double now_s, int sign) {
  status_.eot = sign;
  status_.eot_position_m = sign < 0 ? std::min(chunk_lo_m_, status_.position_m) : std::max(chunk_hi_m_, status_.position_m);
  if (referencing_) {
    // At the stop: this is where the reference lies.
    const double shift = reference_position_m_ - status_.position_m;
    offset_m_ += shift;
    status_.eot_position_m += shift;
    status_.offset_m = offset_m_;
    status_.position_m = reference_position_m_;
    status_.target_m = reference_position_m_;
    ++status_.references;
    finish(now_s, MoveResult::Ok);
    return;
  }
  finish(now_s, MoveResult::EndOfTravel);
}

void Positioner::next_open_loop_chunk(double now_s) {
  if (open_loop_remaining_ == 0) {
    // A reference that met no end stop within its cycles did not find it.
    finish(now_s, referencing_ ? MoveResult::Timeout : MoveResult::Ok);
    return;
  }
  chunk_ = open_loop_;
  chunk_.cycles = std::min(open_loop_remaining_,
                           chunk_cycle_limit(chunk_.freq_hz, chunk_.period_samples, 0));
  open_loop_remaining_ -= chunk_.cycles;
  const double predicted = open_loop_.predicted_m * static_cast<double>(chunk_.cycles);
  chunk_.predicted_m = std::fabs(predicted) >= config_.stall_min_counts * count_m_ ? predicted : 0.0;
  chunk_.completes_last_burst = false;
  start_chunk();
}

void Positioner::after_chunk(double now_s, double position) {
  const double moved = position - chunk_start_position_m_;
  if (end_of_travel_seen(moved)) {
    end_of_travel(now_s, chunk_.direction != 0 ? chunk_.direction : (open_loop_.predicted_m >= 0 ? 1 : -1));
    return;
  }
  if (status_.closed_loop && chunk_.rung >= 0) {
    if (!judge_and_learn(moved)) return;
  } else if (chunk_.predicted_m != 0) {
    // Open loop. Stall: a chunk that moved less than stall_fraction of its prediction.
    const double along = moved / chunk_.predicted_m;
    if (along < config_.stall_fraction) {
      if (++stall_count_ >= config_.stall_bursts) {
        enter_fault(MotionFault::Stall);
        return;
      }
    } else {
      stall_count_ = 0;
    }
  }
  if (stop_requested_) {
    finish(now_s, stop_result_);
    return;
  }
  if (!referencing_ && (position < config_.soft_lower_m - tolerance_m() ||
                        position > config_.soft_upper_m + tolerance_m())) {
    finish(now_s, MoveResult::Limit);  // outside the soft limits: nothing more is played
    return;
  }
  if (status_.closed_loop) {
    const bool passed = (status_.target_m - position) * chunk_.direction < 0;
    // A final chunk is a try at the target once its rung is known to move (a rung still being
    // judged, or just found not to move, is the ladder learning, not a correction).
    const bool rung_known =
        chunk_.rung < 0 || ladder_[direction_index(chunk_.direction)][static_cast<std::size_t>(chunk_.rung)].proven;
    last_try_done_ = (chunk_.completes_last_burst && rung_known) || passed;
    plan_next_chunk(now_s);
  } else {
    next_open_loop_chunk(now_s);
  }
}

bool Positioner::tick(double now_s, model::OutputRequest& request) {
  now_s_ = now_s;
  if (phase_ != Phase::Idle && phase_ != Phase::Fault && move_started_ && !stop_requested_ &&
      config_.move_timeout_s > 0 && status_.kind != MotionKind::Step &&
      now_s - move_start_s_ > config_.move_timeout_s) {
    stop_requested_ = true;  // ends at the playing chunk's end
    stop_result_ = MoveResult::Timeout;
  }
  switch (phase_) {
    case Phase::Idle:
      hold_tick(now_s);
      break;
    case Phase::Fault:
    case Phase::Playing:  // the link's events move it on
      break;
    case Phase::Dwell:
      dwell_tick(now_s);
      break;
    case Phase::Pending: {
      if (!move_started_) {
        move_started_ = true;
        move_start_s_ = now_s;
        want_fresh(now_s);  // the position the move starts from: read after the command
      }
      if (stop_requested_) {
        finish(now_s, stop_result_);
        break;
      }
      double p = 0;
      if (!fresh_position(p)) break;
      if (status_.closed_loop)
        plan_next_chunk(now_s);
      else
        next_open_loop_chunk(now_s);
      break;
    }
    case Phase::Settling: {
      if (now_s < settle_until_s_) break;
      double p = 0;
      if (fresh_position(p)) after_chunk(now_s, p);
      break;
    }
  }
  if (!request_due_) return false;
  request = request_;
  request_due_ = false;
  return true;
}

}  // namespace idm::control
