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
      real<P>("tolerance_m", "m", {0, 1e-3}, "|target - position| that counts as arrived; 0: one count (RDBD)",
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
  }
  return "?";
}

Positioner::Positioner(const RegionMap& map, const PlannerConfig& planner,
                       const PositionerConfig& config, const AxisDeviceInfo& device,
                       Calibration* calibration)
    : map_(map),
      planner_(map, planner),
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
  max_chunks_ = config_.max_chunks_per_move > 0 ? config_.max_chunks_per_move : planner_.config().max_bursts;
  plan_.bursts.reserve(static_cast<std::size_t>(planner_.config().max_bursts));
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
}

double Positioner::tolerance_m() const {
  return config_.tolerance_m > 0 ? config_.tolerance_m : 0.5 * count_m_;
}

bool Positioner::at_rest() const {
  return status_.state == MotionState::Idle || status_.state == MotionState::Fault;
}

// ---- commands ----

Refusal Positioner::move_absolute(double target_m) {
  requested_target_m_ = target_m;
  if (!std::isfinite(target_m)) return Refusal::NotFinite;
  if (phase_ == Phase::Fault) return Refusal::Faulted;
  if (phase_ != Phase::Idle) return Refusal::Busy;
  if (target_m < config_.soft_lower_m || target_m > config_.soft_upper_m)
    return Refusal::OutsideSoftLimits;
  if (!status_.position_valid) return Refusal::NoPosition;
  load_rung_estimates();
  status_.target_m = target_m;
  target_known_ = true;
  status_.closed_loop = true;
  status_.corrections = 0;
  status_.fault = MotionFault::None;
  ++status_.moves;
  stop_requested_ = false;
  last_try_done_ = false;
  stall_count_ = 0;
  move_chunks_ = 0;
  move_cycles_ = 0;
  move_started_ = false;
  phase_ = Phase::Pending;
  status_.state = MotionState::Moving;
  return Refusal::None;
}

Refusal Positioner::move_relative(double distance_m) {
  requested_target_m_ = std::numeric_limits<double>::quiet_NaN();
  if (!std::isfinite(distance_m)) return Refusal::NotFinite;
  if (!status_.position_valid) return phase_ == Phase::Fault ? Refusal::Faulted : Refusal::NoPosition;
  return move_absolute(status_.position_m + distance_m);
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
  status_.corrections = 0;
  status_.fault = MotionFault::None;
  stop_requested_ = false;
  stall_count_ = 0;
  move_chunks_ = 0;
  move_cycles_ = 0;
  move_started_ = false;
  phase_ = Phase::Pending;
  status_.state = MotionState::Moving;
  return Refusal::None;
}

void Positioner::stop() {
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
}

// ---- faults ----

void Positioner::enter_fault(MotionFault fault) {
  // Output to zero at once: the request replaces anything not yet handed out.
  request_ = model::OutputRequest{};
  request_.kind = model::OutputRequest::Kind::Stop;
  request_.seq = seq_;
  request_due_ = true;
  phase_ = Phase::Fault;
  status_.state = MotionState::Fault;
  status_.fault = fault;
  stop_requested_ = false;
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
  status_.position_m = e.position_m;
  status_.position_valid = true;
  if (!target_known_) {  // before the first motion the target is where the slider is (VAL = RBV)
    status_.target_m = e.position_m;
    target_known_ = true;
  }
  if ((phase_ == Phase::Pending || phase_ == Phase::Settling) && !e.in_segment &&
      e.t_s >= fresh_.after_s && fresh_.count < config_.latch_words) {
    fresh_.sum_m += e.position_m;
    ++fresh_.count;
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
  ++status_.bursts;
  ++move_chunks_;
  status_.cycles += c.cycles;
  move_cycles_ += c.cycles;
  phase_ = Phase::Playing;
  status_.state = MotionState::Moving;
}

void Positioner::finish(double now_s) {
  phase_ = Phase::Idle;
  status_.state = MotionState::Idle;
  status_.last_move_time_s = now_s - move_start_s_;
  stop_requested_ = false;
}

// ---- the step ladder ----

void Positioner::build_ladder() {
  rung_cfg_ = calibration_ != nullptr ? calibration_->config() : CalibrationConfig{};
  // Frequency bands: one rung per (stroke, band), so that a rung that does not move on the real
  // stage (stiction near cut-off, the actuator's resonance) has neighbours to fall back on.
  // Frequency bands x bands of the fast phase's share min(duty, 1 - duty): one rung per (stroke,
  // band, share band), so that a rung that does not move on the real stage (stiction near
  // cut-off, the amplifier rounding a short fast phase, the actuator's resonance) has neighbours.
  static constexpr double kBandEdges[] = {0, 300, 700, 1200, 1e300};
  static constexpr double kShareEdges[] = {0, 0.03, 0.1, 0.25, 0.5};
  constexpr std::size_t kBands = sizeof kBandEdges / sizeof kBandEdges[0] - 1;
  constexpr std::size_t kShares = sizeof kShareEdges / sizeof kShareEdges[0] - 1;
  const double rel = rung_cfg_.rung_initial_relative_sd;
  for (int dir : {-1, 1}) {
    std::vector<Rung>& ladder = ladder_[direction_index(dir)];
    ladder.clear();
    for (double stroke : map_.strokes_m()) {
      for (std::size_t band = 0; band < kBands * kShares; ++band) {
        const std::size_t fb = band / kShares, sb = band % kShares;
        std::size_t best = 0;
        double best_rate = 0;
        for (std::size_t i : map_.usable_cells()) {
          const RegionCell& c = map_.cells()[i];
          if (c.direction() != dir || std::fabs(c.stroke_m - stroke) > 1e-9 * stroke) continue;
          if (c.freq_hz < kBandEdges[fb] || c.freq_hz >= kBandEdges[fb + 1]) continue;
          const double share = std::min(c.duty, 1.0 - c.duty);
          if (share < kShareEdges[sb] || share >= kShareEdges[sb + 1]) continue;
          // The best predicted progress per second of the band (the map's step times f).
          const double rate = std::fabs(c.step_m) * c.freq_hz;
          if (rate > best_rate) {
            best_rate = rate;
            best = i;
          }
        }
        if (!(best_rate > 0)) continue;
        const RegionCell& c = map_.cells()[best];
        Rung r;
        r.cell = best;
        r.direction = dir;
        r.seed.freq_hz = c.freq_hz;
        r.seed.duty = c.duty;
        r.seed.stroke_m = c.stroke_m;
        r.seed.step_m = dir * c.step_m;
        r.seed.offset_m = dir * (c.single_burst_m - c.step_m);
        const double sd_step = rel * r.seed.step_m;
        // The model's first-cycle transient means little on a compliant actuator (measured:
        // up to a full step either way): its seed is known no better than one step.
        const double sd_offset = std::max(rel, 1.0) * std::max(std::fabs(r.seed.offset_m), r.seed.step_m);
        r.seed.p_ss = sd_step * sd_step;
        r.seed.p_oo = sd_offset * sd_offset;
        r.seed.p_os = 0;
        r.seed.updates = 0;
        r.est = r.seed;
        ladder.push_back(r);
      }
    }
    // Coarse to fine by the model's step.
    std::stable_sort(ladder.begin(), ladder.end(),
                     [](const Rung& x, const Rung& y) { return x.seed.step_m > y.seed.step_m; });
    if (ladder.size() > static_cast<std::size_t>(CalibrationState::kMaxRungs))
      ladder.resize(static_cast<std::size_t>(CalibrationState::kMaxRungs));
  }
}

void Positioner::load_rung_estimates() {
  for (std::vector<Rung>& ladder : ladder_) {
    for (Rung& r : ladder) {
      RungEstimate stored;
      if (calibration_ != nullptr &&
          calibration_->find_rung(r.direction, r.seed.freq_hz, r.seed.duty, r.seed.stroke_m, stored))
        r.est = stored;
      else if (calibration_ == nullptr || !calibration_->config().enabled)
        r.est = r.seed;  // without calibration nothing is carried from one move to the next
      r.pending_pred_m = 0;
      r.pending_moved_m = 0;
      r.pending_cycles = 0;
    }
  }
}

bool Positioner::rung_live(Rung& r) {
  if (r.dead) {
    if (status_.moves < r.dead_until_move) return false;
    // Its time is over: try it again from the seed.
    r.dead = false;
    r.killed_in_streak = false;
    r.est = r.seed;
    r.pending_pred_m = r.pending_moved_m = 0;
    r.pending_cycles = 0;
    if (calibration_ != nullptr) calibration_->store_rung(r.direction, r.est);
  }
  if (!(r.est.step_m >= config_.min_step_counts * count_m_)) {
    kill_rung(r);
    return false;
  }
  return true;
}

double Positioner::rung_uncertainty(const Rung& r) const {
  // Two standard deviations of its scatter once a few chunks have shown it; until then 100 %
  // (on a real stage a rung's first chunks move anywhere from nothing to twice the model's
  // step). Never below the step model's approach uncertainty.
  if (r.scatter_chunks < 3) return 1.0;
  return std::clamp(2.0 * std::sqrt(r.scatter_var), config_.approach_uncertainty, 1.0);
}

Positioner::FinalChunk Positioner::final_chunk_for(const Rung& r, double distance) const {
  constexpr double kPassSteps = 0.8;  // planned to pass by at most this share of a step
  const double a = r.est.offset_m, b = r.est.step_m;
  const double u = rung_uncertainty(r);
  auto passes = [&](std::uint64_t n) {
    const double nd = static_cast<double>(n);
    const double most = a + nd * b + u * (std::fabs(a) + nd * b);
    return most * (1.0 - kPassSteps / nd) > distance;
  };
  FinalChunk out;
  const double n_real = std::round((distance - a) / b);
  out.cycles = !(n_real >= 1) ? 1 : (n_real >= 1e15 ? static_cast<std::uint64_t>(1e15) : static_cast<std::uint64_t>(n_real));
  const std::uint64_t max_cycles = map_.cells()[r.cell].max_cycles;
  if (max_cycles > 0) out.cycles = std::min(out.cycles, max_cycles);
  const double n_moving = std::ceil((0.5 * b - a) / b);
  const std::uint64_t n_min = n_moving >= 1 ? static_cast<std::uint64_t>(std::min(n_moving, 1e6)) : 1;
  while (out.cycles > n_min && passes(out.cycles)) {
    --out.cycles;
    out.cut = true;
  }
  out.safe = !passes(out.cycles);
  return out;
}

void Positioner::kill_rung(Rung& r) {
  r.dead = true;
  r.proven = false;
  r.dead_until_move = status_.moves + static_cast<std::uint64_t>(config_.dead_rung_moves);
  r.pending_pred_m = r.pending_moved_m = 0;
  r.pending_cycles = 0;
}

Positioner::RungInfo Positioner::rung(int direction, std::size_t index) const {
  const Rung& r = ladder_[direction_index(direction)].at(index);
  RungInfo info;
  info.cell = r.cell;
  info.estimate = r.est;
  info.dead = r.dead;
  info.proven = r.proven;
  info.chunks = r.chunks;
  return info;
}

void Positioner::mark_rung_dead(int direction, std::size_t index) {
  kill_rung(ladder_[direction_index(direction)].at(index));
}

double Positioner::finest_live_step_m(int direction) const {
  double finest = 0;
  for (const Rung& r : ladder_[direction_index(direction)]) {
    if (r.dead || !(r.est.step_m >= config_.min_step_counts * count_m_)) continue;
    if (finest == 0 || r.est.step_m < finest) finest = r.est.step_m;
  }
  return finest;
}

void Positioner::plan_next_chunk(double now_s) {
  const double error = status_.target_m - status_.position_m;
  const double tolerance = tolerance_m();
  if (std::fabs(error) <= tolerance) {
    finish(now_s);
    return;
  }
  if (last_try_done_) {
    // A final chunk was played in full, or a chunk passed the target, and the target is not
    // reached: a correction (the motor record's retry).
    last_try_done_ = false;
    if (static_cast<int>(status_.corrections) >= config_.max_retries) {
      enter_fault(MotionFault::RetryLimit);
      return;
    }
    ++status_.corrections;
  }
  if (static_cast<int>(move_chunks_) >= max_chunks_) {
    enter_fault(MotionFault::RetryLimit);
    return;
  }
  const int sign = error > 0 ? 1 : -1;
  const double distance = std::fabs(error);
  std::vector<Rung>& ladder = ladder_[direction_index(sign)];
  if (ladder.empty()) {
    enter_fault(MotionFault::NoPlan);
    return;
  }
  // The final rung: the live rung of the final class (learned step <= final_step_counts) with the
  // best progress per second; without one, the finest live rung.
  const double final_bound = config_.final_step_counts * count_m_;
  int fin = -1, finest = -1;
  double fin_rate = 0;
  for (std::size_t i = 0; i < ladder.size(); ++i) {
    Rung& r = ladder[i];
    if (!rung_live(r)) continue;
    const double b = r.est.step_m;
    if (finest < 0 || b < ladder[static_cast<std::size_t>(finest)].est.step_m) finest = static_cast<int>(i);
    const double rate = b * map_.cells()[r.cell].freq_hz;
    if (b <= final_bound && rate > fin_rate) {
      fin_rate = rate;
      fin = static_cast<int>(i);
    }
  }
  if (fin < 0) fin = finest;
  if (fin < 0) {
    // Every rung that way has been judged not to move.
    enter_fault(MotionFault::Stall);
    return;
  }
  const Rung& final_rung = ladder[static_cast<std::size_t>(fin)];
  const double b_final = final_rung.est.step_m;
  int chosen = -1;
  std::uint64_t cycles = 0;
  bool final_chunk = false;
  // Approach: outside the final zone, the rung with the most expected progress per second of a
  // chunk (its cycles plus chunk_overhead_s) among those whose planned burst, grown by the
  // approach uncertainty and the rung's own, still stops `keep` short of the target.
  const double zone = std::max(10.0 * b_final, 3.0 * count_m_);
  if (distance > zone) {
    const double keep = 3.0 * b_final + tolerance;
    double best_score = 0;
    for (std::size_t i = 0; i < ladder.size(); ++i) {
      Rung& r = ladder[i];
      if (r.dead) continue;  // rung_live ran above
      const RegionCell& cell = map_.cells()[r.cell];
      const double a = r.est.offset_m, b = r.est.step_m;
      // Pessimistic: offset and step two standard deviations up, and the whole grown by
      // approach_uncertainty (friction along the guide).
      const double a_hi = a + 2.0 * std::sqrt(std::max(r.est.p_oo, 0.0));
      const double b_hi = b + 2.0 * std::sqrt(std::max(r.est.p_ss, 0.0));
      const double n_real = std::floor(((distance - keep) / (1.0 + config_.approach_uncertainty) - a_hi) / b_hi);
      if (!(n_real >= 1)) continue;
      std::uint64_t n = n_real >= 1e15 ? static_cast<std::uint64_t>(1e15) : static_cast<std::uint64_t>(n_real);
      if (cell.max_cycles > 0) n = std::min(n, cell.max_cycles);
      const std::uint64_t n_chunk = std::min(n, chunk_cycle_limit(cell.freq_hz, cell.period_samples, cell.max_cycles));
      const double progress = a + b * static_cast<double>(n_chunk);
      if (!(progress > 0)) continue;
      const double score = progress / (static_cast<double>(n_chunk) / cell.freq_hz + config_.chunk_overhead_s);
      if (score > best_score) {
        best_score = score;
        chosen = static_cast<int>(i);
        cycles = n;
      }
    }
  }
  bool capped = false;
  if (chosen < 0) {
    // Final: the final rung, the number of cycles whose learned displacement lands nearest;
    // fewer when that burst, grown by the rung's uncertainty, could pass the target by more than
    // 0.8 of its own steps (displacement / cycles). Such a shortened chunk is approach, not a
    // try at the target: it stops short and the next chunk is planned from where it stopped.
    // Never below the cycles predicted to move at least half a step: a burst's first cycles can
    // move nothing (offset about -step), and a chunk that moves nothing teaches nothing. When
    // even that shortest chunk could pass too far, a finer live rung whose shortest chunk cannot
    // is taken instead.
    chosen = fin;
    final_chunk = true;
    FinalChunk plan = final_chunk_for(final_rung, distance);
    if (!plan.safe) {
      double best_rate = 0;
      for (std::size_t i = 0; i < ladder.size(); ++i) {
        const Rung& x = ladder[i];
        if (static_cast<int>(i) == fin || x.dead || !(x.est.step_m < b_final) ||
            !(x.est.step_m >= config_.min_step_counts * count_m_))
          continue;
        const FinalChunk alt = final_chunk_for(x, distance);
        const double rate = x.est.step_m * map_.cells()[x.cell].freq_hz;
        if (alt.safe && rate > best_rate) {
          best_rate = rate;
          chosen = static_cast<int>(i);
          plan = alt;
        }
      }
    }
    cycles = plan.cycles;
    capped = plan.cut;
  }
  Rung& r = ladder[static_cast<std::size_t>(chosen)];
  const RegionCell& cell = map_.cells()[r.cell];
  chunk_.freq_hz = cell.freq_hz;
  chunk_.duty = cell.duty;
  chunk_.stroke_m = cell.stroke_m;
  chunk_.period_samples = cell.period_samples;
  chunk_.extension_samples = cell.extension_samples;
  chunk_.cell = &cell;
  chunk_.direction = sign;
  chunk_.rung = chosen;
  const std::uint64_t limit = chunk_cycle_limit(cell.freq_hz, cell.period_samples, cell.max_cycles);
  chunk_.cycles = std::min(cycles, limit);
  chunk_.completes_last_burst = final_chunk && !capped && chunk_.cycles == cycles;
  chunk_.predicted_along_m = r.est.predict_m(chunk_.cycles);
  chunk_.predicted_m = 0;  // closed loop: judged per rung (judge_and_learn)
  // The plan of this chunk: one burst of the rung (its planned cycles, before cutting).
  plan_.target_m = error;
  plan_.bursts.clear();
  Burst burst;
  burst.freq_hz = cell.freq_hz;
  burst.duty = cell.duty;
  burst.stroke_m = cell.stroke_m;
  burst.period_samples = cell.period_samples;
  burst.extension_samples = cell.extension_samples;
  burst.cycles = cycles;
  burst.step_m = sign * r.est.step_m;
  burst.displacement_m = sign * r.est.predict_m(cycles);
  burst.cell_index = r.cell;
  plan_.bursts.push_back(burst);
  plan_.predicted_m = burst.displacement_m;
  plan_.final_step_m = final_chunk ? r.est.step_m : b_final;
  start_chunk();
}

bool Positioner::judge_and_learn(double moved_m) {
  const int sign = chunk_.direction;
  std::vector<Rung>& ladder = ladder_[direction_index(sign)];
  Rung& r = ladder[static_cast<std::size_t>(chunk_.rung)];
  ++r.chunks;
  const double along = sign * moved_m;
  const double predicted = std::max(chunk_.predicted_along_m, 0.0);
  r.pending_pred_m += predicted;
  r.pending_moved_m += along;
  r.pending_cycles += chunk_.cycles;
  // Judged once the prediction is a few counts and more than one cycle was played (a burst's
  // first cycle can stay in static friction: one cycle alone says little).
  const bool judged = r.pending_pred_m >= config_.stall_min_counts * count_m_ && r.pending_cycles >= 2;
  const bool wrong_way = along < -2.0 * count_m_;
  // Not moving: less than stall_fraction of the prediction and less than two counts (a rung
  // that moves a quarter of its seed is slow, not dead: its estimate learns that).
  const bool failed =
      wrong_way || (judged && r.pending_moved_m < std::min(config_.stall_fraction * r.pending_pred_m, 2.0 * count_m_));
  if (judged || failed) {
    r.pending_pred_m = r.pending_moved_m = 0;
    r.pending_cycles = 0;
  }
  if (failed) {
    // A rung that does not move (or moves back) is left out; it is a stall only when it had
    // moved before and is not of the final class, or is one of the coarse rungs (within half of
    // the largest live step): a fine rung near cut-off that does not move is the map being
    // wrong, or a stretch of the guide with more friction (where it moved before), not the
    // slider stuck.
    double largest = 0;
    for (const Rung& x : ladder)
      if (!x.dead && &x != &r) largest = std::max(largest, x.est.step_m);
    const bool fine = r.est.step_m <= config_.final_step_counts * count_m_;
    const bool counts = (r.proven && !fine) || r.est.step_m >= 0.5 * largest || stall_count_ > 0;
    kill_rung(r);
    r.killed_in_streak = true;
    if (counts && ++stall_count_ >= config_.stall_bursts) {
      // The slider is stuck: the rungs are not to blame.
      for (std::vector<Rung>& l : ladder_)
        for (Rung& x : l)
          if (x.killed_in_streak) {
            x.dead = false;
            x.killed_in_streak = false;
          }
      enter_fault(MotionFault::Stall);
      return false;
    }
    return true;
  }
  if (judged) {
    stall_count_ = 0;
    r.proven = true;
    for (std::vector<Rung>& l : ladder_)
      for (Rung& x : l) x.killed_in_streak = false;
  }
  if (along > -count_m_ && predicted >= 2.0 * count_m_) {
    // Scored against the estimate the chunk was planned with, before it learns from it.
    const double rel = (along - predicted) / predicted;
    ++r.scatter_chunks;
    const double w = std::max(0.1, 1.0 / static_cast<double>(r.scatter_chunks));
    r.scatter_var += w * (rel * rel - r.scatter_var);
  }
  if (along > -count_m_ &&
      Calibration::rls_update(r.est, chunk_.cycles, along, count_m_, rung_cfg_.observation_relative_sd,
                              rung_cfg_.rung_forgetting, r.seed.p_oo, r.seed.p_ss)) {
    if (calibration_ != nullptr) calibration_->store_rung(sign, r.est);
  }
  if (!(r.est.step_m >= config_.min_step_counts * count_m_)) kill_rung(r);
  if (calibration_ != nullptr && chunk_.cell != nullptr)
    calibration_->update(*chunk_.cell, chunk_.cycles, moved_m, count_m_);
  return true;
}

void Positioner::next_open_loop_chunk(double now_s) {
  if (open_loop_remaining_ == 0) {
    finish(now_s);
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
    finish(now_s);
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
  switch (phase_) {
    case Phase::Fault:
    case Phase::Idle:
    case Phase::Playing:  // the link's events move it on
      break;
    case Phase::Pending: {
      if (!move_started_) {
        move_started_ = true;
        move_start_s_ = now_s;
        want_fresh(now_s);  // the position the move starts from: read after the command
      }
      if (stop_requested_) {
        finish(now_s);
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
