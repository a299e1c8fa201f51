#include "control/positioner.h"

#include <algorithm>
#include <cmath>

#include "control/calibration.h"
#include "model/impulse_model.h"
#include "model/waveform.h"
#include "model/yaml_util.h"

namespace idm::control {

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
    case MotionFault::WindowUnreachable:
      return "window_unreachable";
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
    : map_(map),
      planner_(planner),
      config_(config),
      device_(device),
      calibration_(calibration),
      ladder_(map_, config_, calibration_) {
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
  chunk_limits_.buffered = buffered_;
  chunk_limits_.max_chunk_samples = max_chunk_samples_;
  chunk_limits_.max_burst_cycles = limits.max_burst_cycles;
  chunk_limits_.device_max_cycles = device_.max_cycles;
  ladder_.build(count_m_, chunk_limits_);
  status_.state = MotionState::Idle;
  status_.window_m = tolerance_m();
}

double Positioner::tolerance_m() const {
  return config_.tolerance_m > 0 ? config_.tolerance_m : count_m_;
}

double Positioner::landing_m() const {
  // Inside the window by half a count: a slider read at k counts lies anywhere within half a
  // count of it, so a reading within tolerance - count / 2 keeps the slider itself inside. Never
  // finer than the reading nearest the target (a window of a count or less: half a count).
  return std::max(0.5 * count_m_, tolerance_m() - 0.5 * count_m_);
}

double Positioner::window_for_landing_m(double landing_m) const {
  return landing_m + 0.5 * count_m_;
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
    // A fresh reading is one at rest: it joins the mean shown at rest too, so that the position
    // read just after a move ends is the mean the landing judged, not its first single word (a
    // slider resting near a count's edge read one count off by POS? now and then, on a loaded
    // machine where a client asks before the next words).
    rest_mean_.add(position);
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
        ladder_.set_reading_sd_m(std::sqrt(reading_var_m2_ / config_.latch_words));
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

// The chunk of the ladder's choice (its planned cycles cut to a chunk), and its request.
void Positioner::play(const StepLadder::Choice& choice, double error) {
  const int sign = choice.direction;
  const std::uint64_t cycles = choice.cycles;
  const StepLadder::Rung& r = ladder_.at(sign, static_cast<std::size_t>(choice.rung));
  const RegionCell& cell = map_.cells()[r.cell];
  chunk_ = cell_chunk(cell);
  chunk_.cell = &cell;
  chunk_.direction = sign;
  chunk_.rung = choice.rung;
  chunk_.cycles =
      std::min(cycles, chunk_cycle_limit(chunk_limits_, config_.max_chunk_s, cell.freq_hz,
                                         cell.period_samples, cell.max_cycles));
  // A try at the target: the whole final burst, expected to end within the window. A final
  // chunk expected to end short of it (a rung whose chunks cannot be placed finer, creeping in)
  // is progress, not a try: it counts toward max_chunks_per_move, not max_retries.
  chunk_.completes_last_burst =
      choice.final_chunk && !choice.capped && chunk_.cycles == cycles &&
      std::fabs(std::fabs(error) - r.est.predict_m(cycles)) <= tolerance_m();
  chunk_.predicted_along_m = r.est.predict_m(chunk_.cycles);
  chunk_.predicted_m = 0;  // closed loop: judged per rung (the ladder's judge)
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
  plan_.final_step_m = choice.final_chunk ? r.est.step_m : choice.final_step_m;
  start_chunk();
}

Positioner::RungInfo Positioner::rung(int direction, std::size_t index) const {
  const StepLadder::Rung& r = ladder_.at(direction, index);
  RungInfo info;
  info.cell = r.cell;
  info.estimate = r.est;
  info.dead = r.dead;
  info.proven = r.proven;
  info.chunks = r.chunks;
  return info;
}

void Positioner::mark_rung_dead(int direction, std::size_t index) {
  ladder_.kill(direction, index, status_.moves);
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
      std::min(open_loop_remaining_, chunk_cycle_limit(chunk_limits_, config_.max_chunk_s,
                                                       chunk_.freq_hz, chunk_.period_samples, 0));
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
    if (!judge_chunk(moved)) return;
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
        ladder_.at(chunk_.direction, static_cast<std::size_t>(chunk_.rung)).proven;
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
