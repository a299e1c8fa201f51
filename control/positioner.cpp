#include "control/positioner.h"

#include <algorithm>
#include <cmath>

#include "control/calibration.h"
#include "model/impulse_model.h"
#include "model/waveform.h"
#include "model/yaml_util.h"

namespace idm::control {

namespace {

using model::integer;
using model::real;
using model::with_default;
using model::with_relation;
using P = PositionerConfig;

// The window, the corrections, the stall, the chunks, the readings and the soft limits.
std::vector<model::Param<P>> move_params() {
  return {
      real<P>(
          "tolerance_m", "m", {0, 1e-3},
          "the in-position window (RDBD, MOVE:WINDow); 0: one count (the loop aims for half a "
          "count within it)",
          [](auto& c) -> auto& { return c.tolerance_m; }),
      integer<P>(
          "max_retries", "count", 0, 1000, "correction rounds after the first plan (RTRY)",
          [](auto& c) -> auto& { return c.max_retries; }),
      integer<P>(
          "stall_bursts", "count", 1, 1000, "bursts in a row without progress: a stall fault",
          [](auto& c) -> auto& { return c.stall_bursts; }),
      real<P>(
          "stall_fraction", "1", {0, 1, false, true},
          "a burst that moved less than this share of its prediction made no progress",
          [](auto& c) -> auto& { return c.stall_fraction; }),
      real<P>(
          "settle_s", "s", {0, 10}, "after a burst, wait this long before the position is read",
          [](auto& c) -> auto& { return c.settle_s; }),
      real<P>(
          "max_chunk_s", "s", {0, 10, true},
          "the longest piece played at once: what a STOP waits for (must fit the capture)",
          [](auto& c) -> auto& { return c.max_chunk_s; }),
      integer<P>(
          "latch_words", "count", 1, RestMean::kMaxWords,
          "readings averaged for a position at rest (the one shown, and the landing's: up to 16 "
          "times as many while its mean is not surely inside the window)",
          [](auto& c) -> auto& { return c.latch_words; }),
      with_relation(with_default(real<P>(
                                     "soft_lower_m", "m", {-10, 10},
                                     "soft limit (LLM): a move or STEP ending below is refused",
                                     [](auto& c) -> auto& { return c.soft_lower_m; }),
                                 "stage.travel_m"),
                    "< soft_upper_m",
                    [](const P& c) {
                      return model::Range{-1e300, c.soft_upper_m, false, true};
                    }),
      with_relation(with_default(real<P>(
                                     "soft_upper_m", "m", {-10, 10},
                                     "soft limit (HLM): a move or STEP ending above is refused",
                                     [](auto& c) -> auto& { return c.soft_upper_m; }),
                                 "stage.travel_m"),
                    "> soft_lower_m",
                    [](const P& c) {
                      return model::Range{c.soft_lower_m, 1e300, true, false};
                    }),
  };
}

// hold_s: -1 (until the next motion) or [0, 86400] s, which one interval cannot say: the real
// key's range, read, check and assign, each refusing what lies between -1 and 0.
model::Param<P> hold_param() {
  const auto get = [](auto& c) -> auto& {
    return c.hold_s;
  };
  model::Param<P> p = real<P>(
      "hold_s", "s", {-1, 86400},
      "after a move: keep the target this long (0: no hold, -1: until the next motion; HOLD)", get);
  p.range = "-1 or [0, 86400]";
  const auto ok = [](double x) { return x == -1 || (x >= 0 && x <= 86400); };
  const auto refuse = [range = p.range](double x) {
    return model::format_number(x) + " is out of range, allowed " + range;
  };
  p.read = [ok, refuse, get](P& c, const YAML::Node& v, const std::string& file,
                             const std::string& key) {
    const double x = model::read_double(v, file, key, -1e308, 1e308);
    if (!ok(x)) throw model::InputError(model::located(file, v, key, refuse(x)));
    get(c) = x;
  };
  p.check = [ok, refuse](const P& c, const std::string& key) {
    if (!ok(c.hold_s)) throw model::InputError(key + ": " + refuse(c.hold_s));
  };
  p.assign = [ok, refuse](P& c, double x, const std::string& key) {
    if (!ok(x)) throw model::InputError(key + ": " + refuse(x) + " s");
    c.hold_s = x;
  };
  return p;
}

// The approach and the step ladder, and how a motion ends: dwell, timeout, end of travel, hold.
std::vector<model::Param<P>> ladder_and_end_params() {
  return {
      real<P>(
          "approach_uncertainty", "1", {0, 10},
          "share by which an approach burst may exceed its prediction",
          [](auto& c) -> auto& { return c.approach_uncertainty; }),
      real<P>(
          "stall_min_counts", "count", {0, 1e6},
          "chunks predicted to move fewer counts are not judged for a stall",
          [](auto& c) -> auto& { return c.stall_min_counts; }),
      integer<P>(
          "max_chunks_per_move", "count", 0, 100000000,
          "most chunks in one move (0: the planner's max_bursts)",
          [](auto& c) -> auto& { return c.max_chunks_per_move; }),
      real<P>(
          "final_step_counts", "count", {0.5, 1000},
          "the last chunks use a rung of at most this step",
          [](auto& c) -> auto& { return c.final_step_counts; }),
      with_relation(real<P>(
                        "min_step_counts", "count", {0, 1000, false, true},
                        "a rung stepping less per cycle is taken as not moving",
                        [](auto& c) -> auto& { return c.min_step_counts; }),
                    "< final_step_counts",
                    [](const P& c) {
                      return model::Range{-1e300, c.final_step_counts, false, true};
                    }),
      integer<P>(
          "dead_rung_moves", "count", 1, 1000000,
          "a rung judged not to move is left out for this many moves",
          [](auto& c) -> auto& { return c.dead_rung_moves; }),
      real<P>(
          "chunk_overhead_s", "s", {0, 10},
          "time a chunk costs beyond its cycles (planning weight)",
          [](auto& c) -> auto& { return c.chunk_overhead_s; }),
      real<P>(
          "max_speed_m_s", "m/s", {0, 1},
          "speed limit of a move's approach (0: none; MOVE:VELocity; the final rung plays at its "
          "own speed)",
          [](auto& c) -> auto& { return c.max_speed_m_s; }),
      real<P>(
          "dwell_s", "s", {0, 60},
          "a move is done once fresh readings stayed in the window this long (MOVE:DWELl)",
          [](auto& c) -> auto& { return c.dwell_s; }),
      real<P>(
          "move_timeout_s", "s", {0, 86400},
          "a move not done after this long ends with TIMEOUT (0: no limit)",
          [](auto& c) -> auto& { return c.move_timeout_s; }),
      real<P>(
          "eot_step_m", "m", {0, 1e-3},
          "end of travel: mean step below this while driving stops the axis (0: off; EOT:STEP)",
          [](auto& c) -> auto& { return c.eot_step_m; }),
      integer<P>(
          "eot_cycles", "count", 1, 100000,
          "end of travel: the cycles the mean step is taken over (EOT:CYCLes)",
          [](auto& c) -> auto& { return c.eot_cycles; }),
      hold_param(),
      real<P>(
          "hold_window_m", "m", {0, 1e-3},
          "a hold corrects when a reading leaves this window (0: the move window; HOLD:WINDow)",
          [](auto& c) -> auto& { return c.hold_window_m; }),
  };
}

}  // namespace

const model::ParamTable<PositionerConfig>& positioner_params() {
  static const model::ParamTable<P> table(model::join<P>({move_params(), ladder_and_end_params()}));
  return table;
}

void validate(const PositionerConfig& c, const std::string& where) {
  // Infinite soft limits are allowed in code (no limit), as the ends of the range on their side;
  // files always give finite ones. The table checks the ranges and the relations (lower < upper,
  // min_step_counts < final_step_counts).
  PositionerConfig finite = c;
  if (std::isinf(finite.soft_lower_m)) finite.soft_lower_m = std::copysign(10.0, c.soft_lower_m);
  if (std::isinf(finite.soft_upper_m)) finite.soft_upper_m = std::copysign(10.0, c.soft_upper_m);
  positioner_params().validate(finite, where);
  if (!(c.travel_lower_m < c.travel_upper_m))
    throw model::InputError(where + ": the travel [" + model::format_number(c.travel_lower_m) +
                            ", " + model::format_number(c.travel_upper_m) +
                            "] m is not an interval (stage.travel_m: lower < upper)");
}

const char* motion_state_name(MotionState s) {
  switch (s) {
    case MotionState::Idle:
      return "IDLE";
    case MotionState::Moving:
      return "MOVING";
    case MotionState::Settling:
      return "SETTLING";
    case MotionState::Fault:
      return "FAULT";
  }
  return "?";
}

const char* motion_fault_name(MotionFault f) {
  switch (f) {
    case MotionFault::None:
      return "none";
    case MotionFault::InvalidSample:
      return "invalid_sample";
    case MotionFault::Stall:
      return "stall";
    case MotionFault::RetryLimit:
      return "retry_limit";
    case MotionFault::Driver:
      return "driver";
    case MotionFault::NoPlan:
      return "no_plan";
    case MotionFault::CaptureOverrun:
      return "capture_overrun";
    case MotionFault::DeviceLost:
      return "device_lost";
  }
  return "?";
}

const char* move_result_name(MoveResult r) {
  switch (r) {
    case MoveResult::None:
      return "NONE";
    case MoveResult::Ok:
      return "OK";
    case MoveResult::Stopped:
      return "STOPPED";
    case MoveResult::Limit:
      return "LIMIT";
    case MoveResult::EndOfTravel:
      return "END_OF_TRAVEL";
    case MoveResult::Fault:
      return "FAULT";
    case MoveResult::Timeout:
      return "TIMEOUT";
  }
  return "?";
}

const char* refusal_name(Refusal r) {
  switch (r) {
    case Refusal::None:
      return "none";
    case Refusal::NotFinite:
      return "not_finite";
    case Refusal::OutsideSoftLimits:
      return "outside_soft_limits";
    case Refusal::Faulted:
      return "faulted";
    case Refusal::Busy:
      return "busy";
    case Refusal::OutOfRange:
      return "out_of_range";
    case Refusal::NoPosition:
      return "no_position";
    case Refusal::NotReferenced:
      return "not_referenced";
    case Refusal::EndOfTravel:
      return "end_of_travel";
    case Refusal::Reloading:
      return "reloading";
  }
  return "?";
}

Positioner::Positioner(const RegionMap& map, const PlannerConfig& planner,
                       const PositionerConfig& config, const AxisDeviceInfo& device,
                       Calibration* calibration)
    : map_(map), planner_(planner), config_(config), device_(device), calibration_(calibration) {
  validate(config_);
  if (!(device_.count_m > 0))
    throw model::InputError("control: the interferometer's count must be > 0");
  count_m_ = device_.count_m;
  rest_mean_.reset(config_.latch_words);
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
      const double fit_s =
          (static_cast<double>(device_.stream_capacity) - 1) / device_.stream_rate_hz;
      throw model::InputError(
          "control.max_chunk_s / control.min_freq_hz: the longest chunk (" +
          model::format_number(longest_s) + " s: max_chunk_s, or one cycle at min_freq_hz) is " +
          model::format_number(records) + " records of the interferometer's " +
          model::format_number(device_.stream_rate_hz) + " Hz capture, more than the " +
          std::to_string(device_.stream_capacity) + " it holds for one burst; set max_chunk_s <= " +
          model::format_number(fit_s) + " and min_freq_hz >= " + model::format_number(1.0 / fit_s) +
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
      largest_step_m_[d] = along;
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
  landing_rungs_.reserve(ladder_[0].size() + ladder_[1].size());
  landing_index_.reserve(ladder_[0].size() + ladder_[1].size());
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
    rest_mean_.reset(config_.latch_words);
    invalid_sample_status_ = e.status;
    // An overrun is the capture being too small for the chunk, not the beam: say so.
    if (phase_ != Phase::Fault)
      enter_fault(e.overrun ? MotionFault::CaptureOverrun : MotionFault::InvalidSample);
    return;
  }
  const double position = e.position_m + offset_m_;
  // A segment the positioner did not play (a sweep's trial) moves the slider: the mean at rest
  // starts over with the readings after it.
  if (e.in_segment && phase_ == Phase::Idle) rest_mean_.reset(config_.latch_words);
  if (e.mark && !mark_seen_ &&
      (mark_search_ == MarkSearch::Searching || mark_search_ == MarkSearch::Crawling)) {
    mark_seen_ = true;
    mark_reading_m_ = position;
  }
  // At rest the position shown is the mean of the latest latch_words readings; else the latest.
  status_.position_m = at_rest() && !e.in_segment ? rest_mean_.add(position) : position;
  chunk_lo_m_ = std::min(chunk_lo_m_, position);
  chunk_hi_m_ = std::max(chunk_hi_m_, position);
  status_.position_valid = true;
  if (!target_known_) {  // before the first motion the target is where the slider is (VAL = RBV)
    status_.target_m = position;
    target_known_ = true;
  }
  if ((phase_ == Phase::Pending || phase_ == Phase::Settling || phase_ == Phase::Dwell) &&
      !e.in_segment && e.t_s >= fresh_.after_s && fresh_.count < fresh_.wanted) {
    if (fresh_.count == 0) fresh_.first_m = position;
    fresh_.sum_m += position;
    fresh_.sum_sq_m += (position - fresh_.first_m) * (position - fresh_.first_m);
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
      if (std::fabs(status_.target_m - mean) > window) hold_correction_due_ = true;
    }
  }
  // In position follows the readings: at rest after a move that arrived, the mean of the latest
  // latch_words readings within the move window of the target. A push, a drift or a sweep's
  // trial that moved the slider clears it, so that MOVE:REL counts from the reading then, not
  // from a target the slider has left.
  if (arrived_ && phase_ == Phase::Idle && !e.in_segment &&
      rest_mean_.count() >= config_.latch_words)
    status_.in_window = std::fabs(status_.target_m - status_.position_m) <= tolerance_m();
}

void Positioner::want_fresh(double after_s) {
  fresh_ = Fresh{};
  fresh_.after_s = after_s;
  fresh_.wanted = config_.latch_words;
}

bool Positioner::fresh_position(double& position_m) {
  if (fresh_.count >= fresh_.wanted) {
    const double n = fresh_.count;
    const double mean = fresh_.sum_m / n;
    // A mean that says arrived must say it surely (the slider itself within the window): while
    // the window's edge lies nearer than kArrivalStandardErrors standard errors, twice the
    // readings. The scatter is the larger of the batch's and the one pooled over the batches
    // taken so far (8 readings alone read it half as large in one batch of 40); a batch joins
    // the pool once, when it is taken.
    const double d = mean - fresh_.first_m;
    const double batch_var = n > 1 ? std::max(fresh_.sum_sq_m / n - d * d, 0.0) * n / (n - 1) : 0.0;
    const double var = std::max(batch_var, reading_var_m2_);
    const double error = std::fabs(status_.target_m - mean);
    if (status_.closed_loop && error <= landing_m() &&
        tolerance_m() - error < kArrivalStandardErrors * std::sqrt(var / n) &&
        fresh_.wanted < kMaxFreshFactor * config_.latch_words) {
      fresh_.wanted = std::min(2 * fresh_.wanted, kMaxFreshFactor * config_.latch_words);
      fresh_.requested = false;
    } else {
      if (n > 1) {
        reading_var_weight_ = kReadingVarForgetting * reading_var_weight_ + (n - 1);
        reading_var_m2_ += (n - 1) / reading_var_weight_ * (batch_var - reading_var_m2_);
      }
      position_m = mean;
      status_.position_m = position_m;
      return true;
    }
  }
  if (!fresh_.requested && now_s_ >= fresh_.after_s && !request_due_) {
    // Ask for them now rather than wait for the link's rest polling.
    request_ = model::OutputRequest{};
    request_.kind = model::OutputRequest::Kind::Read;
    request_.readings = static_cast<std::uint32_t>(fresh_.wanted - fresh_.count);
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
  rest_mean_.reset(config_.latch_words);
  ++status_.bursts;
  ++move_chunks_;
  status_.cycles += c.cycles;
  move_cycles_ += c.cycles;
  phase_ = Phase::Playing;
  status_.state = MotionState::Moving;
}

void Positioner::next_open_loop_chunk(double now_s) {
  if (open_loop_remaining_ == 0) {
    // A reference that met no end stop within its cycles did not find it.
    if (mark_search_ == MarkSearch::Crawling)
      crawl_failed(now_s);
    else
      finish(now_s, referencing_ ? MoveResult::Timeout : MoveResult::Ok);
    return;
  }
  chunk_ = open_loop_;
  chunk_.cycles =
      std::min(open_loop_remaining_, chunk_cycle_limit(chunk_.freq_hz, chunk_.period_samples, 0));
  open_loop_remaining_ -= chunk_.cycles;
  const double predicted = open_loop_.predicted_m * static_cast<double>(chunk_.cycles);
  chunk_.predicted_m =
      std::fabs(predicted) >= config_.stall_min_counts * count_m_ ? predicted : 0.0;
  chunk_.completes_last_burst = false;
  start_chunk();
}

void Positioner::after_chunk(double now_s, double position) {
  if ((mark_search_ == MarkSearch::Searching || mark_search_ == MarkSearch::Crawling) &&
      mark_seen_ && !stop_requested_) {
    mark_found(now_s);
    return;
  }
  const double moved = position - chunk_start_position_m_;
  if (end_of_travel_seen(moved)) {
    end_of_travel(
        now_s, chunk_.direction != 0 ? chunk_.direction : (open_loop_.predicted_m >= 0 ? 1 : -1));
    return;
  }
  if (status_.closed_loop && chunk_.rung >= 0) {
    if (!judge_and_learn(moved)) return;
  } else if (chunk_.predicted_m != 0) {
    // Open loop. Stall: a chunk that moved less than stall_fraction of its prediction.
    const double along = moved / chunk_.predicted_m;
    if (along < config_.stall_fraction && mark_search_ == MarkSearch::Crawling &&
        !stop_requested_) {
      crawl_failed(now_s);
      return;
    }
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
  // A closed-loop move may land on a target at a limit up to its window and a final step past
  // it (a final chunk may pass the target by most of a step): a landing, not a runaway. The
  // ladder is looked at only for a reading already past the window (not on every tick).
  const auto allowed = [&](double tolerance) {
    return reading_allowed(position, motion_start_m_, config_.soft_lower_m, config_.soft_upper_m,
                           tolerance);
  };
  if (!referencing_ && !allowed(tolerance_m()) &&
      !(status_.closed_loop && allowed(tolerance_m() + finest_live_step_m(chunk_.direction)))) {
    finish(now_s, MoveResult::Limit);  // outside the soft limits: nothing more is played
    return;
  }
  if (status_.closed_loop) {
    const bool passed = (status_.target_m - position) * chunk_.direction < 0;
    // A final chunk is a try at the target once its rung is known to move (a rung still being
    // judged, or just found not to move, is the ladder learning, not a correction).
    const bool rung_known =
        chunk_.rung < 0 ||
        ladder_[direction_index(chunk_.direction)][static_cast<std::size_t>(chunk_.rung)].proven;
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
