// How the positioner's motions end (control/README.md, "Positioner"): the result, arriving in
// the window, the dwell, the hold after a move, and the end of travel. Part of class Positioner.
#include <algorithm>
#include <cmath>

#include "control/calibration.h"
#include "control/positioner.h"
#include "model/impulse_model.h"

namespace idm::control {

// ---- ending ----

void Positioner::finish(double now_s, MoveResult result) {
  if (mark_search_ == MarkSearch::Approaching && result == MoveResult::Ok) {
    start_crawl(now_s);  // before the mark: the slow pass across it (the motion goes on)
    return;
  }
  phase_ = Phase::Idle;
  status_.state = MotionState::Idle;
  stop_requested_ = false;
  if (hold_correcting_) {
    hold_correcting_ = false;
    if (result == MoveResult::Ok) {  // back in the window: holding on
      hold_armed_ = true;
      status_.in_window = true;
      arrived_ = true;
      return;
    }
    status_.holding = false;
  }
  status_.last_move_time_s = now_s - move_start_s_;
  status_.result = result;
  status_.result_distance_m = status_.target_m - status_.position_m;
  ++status_.motions_ended;
  status_.in_window = status_.kind == MotionKind::Move && result == MoveResult::Ok;
  arrived_ = status_.in_window;
  // A mark search is done once the move back onto the mark arrived.
  if (mark_search_ == MarkSearch::Returning && result == MoveResult::Ok) ++status_.references;
  mark_search_ = MarkSearch::Off;
  referencing_ = false;
  if (status_.in_window && config_.hold_s != 0) {
    hold_armed_ = true;
    status_.holding = true;
    hold_until_s_ =
        config_.hold_s < 0 ? std::numeric_limits<double>::infinity() : now_s + config_.hold_s;
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
  ladder_.start_move();
  const std::uint64_t moves = status_.moves;
  start_motion(MotionKind::Move);
  status_.moves = moves;
  status_.holding = true;
  hold_correcting_ = true;
  status_.closed_loop = true;
}

bool Positioner::end_of_travel_seen(double moved_m) {
  const double eot_step =
      config_.eot_step_m > 0 ? config_.eot_step_m : (referencing_ ? 0.25 * count_m_ : 0.0);
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
    const StepLadder::Rung& r = ladder_.at(sign, static_cast<std::size_t>(chunk_.rung));
    expected = r.est.step_m >= std::max(5.0 * eot_step, config_.final_step_counts * count_m_);
    proven = r.proven;
  }
  if (!expected) return false;
  // A collapse needs steps before it: a slider that has never moved this way is stuck (a stall
  // fault), not at the end of its travel. A reference looks for the stop, wherever it starts.
  const double expected_along =
      chunk_.rung < 0 ? std::fabs(open_loop_.predicted_m) * static_cast<double>(chunk_.cycles)
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
  // Closed loop: the run of non-moving chunks that makes a stall (judge_chunk) decides; one
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

double Positioner::end_margin_m() const {
  return 5.0 * map_.config().stage.stroke_m;
}

void Positioner::end_of_travel(double now_s, int sign) {
  const double at_m = sign < 0 ? std::min(chunk_lo_m_, status_.position_m)
                               : std::max(chunk_hi_m_, status_.position_m);
  // Far from the end it drove toward: the slider is held by something inside the travel (a
  // collision, debris, a cable): a fault *RST clears, not an end that refuses motion that way
  // for good. A reference looks for a stop wherever the coordinates put it.
  const double end_m = sign < 0 ? config_.travel_lower_m : config_.travel_upper_m;
  if (!referencing_ && mark_search_ == MarkSearch::Off && std::isfinite(end_m) &&
      (end_m - at_m) * sign > end_margin_m()) {
    enter_fault(MotionFault::Stall);
    return;
  }
  status_.eot = sign;
  status_.eot_position_m = at_m;
  if (mark_search_ == MarkSearch::Searching) {
    mark_search_end_stop(now_s, sign);
    return;
  }
  if (referencing_) {
    // At the stop: this is where the reference lies.
    const double shift = reference_position_m_ - status_.position_m;
    offset_m_ += shift;
    rest_mean_.shift(shift);  // the readings at rest it holds, in the new frame
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

// ---- the reference mark ----

void Positioner::mark_found(double now_s) {
  // The mark's reading becomes the reference position: readings, target and the end of travel
  // move with the offset.
  const double shift = reference_position_m_ - mark_reading_m_;
  offset_m_ += shift;
  rest_mean_.shift(shift);
  status_.offset_m = offset_m_;
  status_.position_m += shift;
  status_.eot_position_m += shift;
  chunk_lo_m_ += shift;
  chunk_hi_m_ += shift;
  // The marked word is the first past the mark: at the search's speed the mark may lie up to a
  // sample's travel behind it. Back off before it and cross it again slowly (the crawl); after
  // the crawl, or without a crawl cell, back onto the mark.
  const int sign = open_loop_.predicted_m >= 0 ? 1 : -1;
  if (mark_search_ == MarkSearch::Searching && crawl_chunk(sign, crawl_)) {
    const double back = sample_travel_m(open_loop_) + 10.0 * count_m_;
    const double cycles =
        std::ceil(10.0 * (back + 10.0 * count_m_) / std::fabs(crawl_.predicted_m));
    crawl_cycles_ = static_cast<std::uint64_t>(std::clamp(cycles, 1.0, 1e9));
    crawl_tries_ = 0;
    crawl_start_m_ = reference_position_m_ - sign * back;
    mark_search_ = MarkSearch::Approaching;
    move_onto(now_s, crawl_start_m_);
  } else {
    mark_search_ = MarkSearch::Returning;
    move_onto(now_s, reference_position_m_);
  }
}

void Positioner::move_onto(double now_s, double target_m) {
  // A closed-loop move of the mark search: to the point before the mark, or onto it.
  status_.target_m = target_m;
  referencing_ = false;
  status_.eot = 0;
  status_.closed_loop = true;
  ladder_.start_move();
  reset_progress();
  plan_next_chunk(now_s);
}

double Positioner::sample_travel_m(const Chunk& c) const {
  // The slider steps in the fast phase, at up to the velocity jump m/(M+m) times the phase's
  // rate, and never farther than about its step in one cycle.
  const double fast_s = std::min(c.duty, 1.0 - c.duty) / c.freq_hz;
  const double jump_m_s = map_.config().stage.mass_ratio() * c.stroke_m / fast_s;
  return std::min(jump_m_s / device_.stream_rate_hz, std::fabs(c.predicted_m));
}

bool Positioner::crawl_chunk(int sign, Chunk& out) {
  // Among the live rungs that way, by their learned step: one whose slider moves at most the
  // final class's step (final_step_counts) between two stream samples before one that moves
  // more, a proven one before one that is not, then the largest step (the slowest, when none is
  // fine enough).
  bool found = false, fine = false, proven = false;
  double best_step = 0, best_travel = 0;
  for (std::size_t i = 0; i < ladder_.size(sign); ++i) {
    const StepLadder::Rung& r = ladder_.at(sign, i);
    if (r.dead || !(r.est.step_m >= config_.min_step_counts * count_m_)) continue;
    Chunk c = cell_chunk(map_.cells()[r.cell]);
    c.predicted_m = sign * r.est.step_m;
    const double travel = sample_travel_m(c), step = r.est.step_m;
    const bool c_fine = travel <= config_.final_step_counts * count_m_;
    bool better = !found || c_fine > fine;
    if (found && c_fine == fine)
      better = c_fine ? (r.proven > proven || (r.proven == proven && step > best_step))
                      : travel < best_travel;
    if (!better) continue;
    found = true;
    fine = c_fine;
    proven = r.proven;
    best_step = step;
    best_travel = travel;
    out = c;
    crawl_rung_ = static_cast<int>(i);
  }
  return found;
}

void Positioner::start_crawl(double now_s) {
  // At the point before the mark: open loop across it with the crawl cell, watching for it.
  open_loop_ = crawl_;
  open_loop_remaining_ = crawl_cycles_;
  status_.closed_loop = false;
  status_.target_m = reference_position_m_;
  mark_search_ = MarkSearch::Crawling;
  mark_seen_ = false;
  stall_count_ = 0;
  eot_count_ = 0;
  eot_next_ = 0;
  move_chunks_ = 0;
  next_open_loop_chunk(now_s);
}

void Positioner::crawl_failed(double now_s) {
  // The crawl's cell did not carry the slider across the mark (it stalled, or stepped less than
  // it should): its rung is left out and the next one tries from the point before the mark, a
  // few times; then the search's reading stands.
  const int sign = crawl_.predicted_m >= 0 ? 1 : -1;
  if (crawl_rung_ >= 0 && static_cast<std::size_t>(crawl_rung_) < ladder_.size(sign))
    ladder_.kill(sign, static_cast<std::size_t>(crawl_rung_), status_.moves);
  if (++crawl_tries_ < kCrawlTries && crawl_chunk(sign, crawl_)) {
    mark_search_ = MarkSearch::Approaching;
    move_onto(now_s, crawl_start_m_);
    return;
  }
  mark_search_ = MarkSearch::Returning;
  move_onto(now_s, reference_position_m_);
}

void Positioner::mark_search_end_stop(double now_s, int sign) {
  // An end stop before the mark: the mark lies the other way (once); a second stop means the
  // travel has no mark, and the axis is not referenced.
  if (!mark_reversed_ && !stop_requested_ && reference_drive(-sign)) {
    mark_reversed_ = true;
    status_.eot = 0;
    eot_count_ = 0;
    eot_next_ = 0;
    stall_count_ = 0;
    next_open_loop_chunk(now_s);
    return;
  }
  referencing_ = false;
  finish(now_s, stop_requested_ ? stop_result_ : MoveResult::EndOfTravel);
}

void Positioner::plan_next_chunk(double now_s) {
  const double error = status_.target_m - status_.position_m;
  if (std::fabs(error) <= landing_m()) {
    arrived(now_s);
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
  const bool may_correct = static_cast<int>(status_.corrections) < config_.max_retries;
  const StepLadder::Choice choice =
      ladder_.next_chunk(error, status_.position_m, landing_m(), may_correct, status_.moves);
  switch (choice.kind) {
    case StepLadder::Choice::Kind::NoRungs:
      enter_fault(MotionFault::NoPlan);
      return;
    case StepLadder::Choice::Kind::NoLiveRung:
      // Every rung that way has been judged not to move.
      enter_fault(MotionFault::Stall);
      return;
    case StepLadder::Choice::Kind::OutOfTries:
      enter_fault(MotionFault::RetryLimit);
      return;
    case StepLadder::Choice::Kind::Play:
      break;
  }
  if (choice.final_chunk || choice.back_off || choice.vernier) {
    // About to try for the window: can it be met at all? (Said before the first try, never after
    // max_retries of hunting.)
    const double least =
        ladder_.unreachable_landing_m(landing_m(), config_.max_retries + 1, status_.moves);
    if (least > 0) {
      status_.least_window_m = window_for_landing_m(least);
      enter_fault(MotionFault::WindowUnreachable);
      return;
    }
  }
  if (choice.back_off) ++status_.corrections;  // a way back counts as a correction round
  play(choice, error);
}

bool Positioner::judge_chunk(double moved_m) {
  const int sign = chunk_.direction;
  const StepLadder::Judgement j =
      ladder_.judge(sign, chunk_.rung, chunk_.cycles, chunk_.predicted_along_m, moved_m,
                    stall_count_ > 0, status_.moves);
  if (j.failed) {
    if (!j.counts_as_stall) return true;
    streak_cycles_ += chunk_.cycles;
    streak_along_m_ += sign * moved_m;
    if (++stall_count_ < config_.stall_bursts) return true;
    // The slider is stuck: the rungs are not to blame.
    ladder_.revive_streak();
    // Driven and not moving: at an end stop when the mean step over the run collapsed (to
    // nothing: a run that crept the wrong way is friction along the guide, not a stop).
    if (config_.eot_step_m > 0 && streak_cycles_ > 0 &&
        (status_.moved_dirs & (1u << direction_index(sign))) &&
        std::fabs(streak_along_m_ / static_cast<double>(streak_cycles_)) < config_.eot_step_m) {
      end_of_travel(now_s_, sign);
      return false;
    }
    enter_fault(MotionFault::Stall);
    return false;
  }
  if (j.judged) {
    stall_count_ = 0;
    streak_cycles_ = 0;
    streak_along_m_ = 0;
  }
  return true;
}

}  // namespace idm::control
