// The step ladder (step_ladder.h): the rungs built from the map, what they learn, and the choice
// of each closed-loop chunk. The landing plan's part is step_ladder_landing.cpp.
#include "control/step_ladder.h"

#include <algorithm>
#include <cmath>

namespace idm::control {

StepLadder::StepLadder(const RegionMap& map, const PositionerConfig& config,
                       Calibration* calibration)
    : map_(map), config_(config), calibration_(calibration) {}

void StepLadder::build(double count_m, const ChunkLimits& chunk_limits) {
  count_m_ = count_m;
  chunk_limits_ = chunk_limits;
  rls_ = calibration_ != nullptr ? calibration_->config() : CalibrationConfig{};
  // Frequency bands x bands of the fast phase's share min(duty, 1 - duty): one rung per (stroke,
  // band, share band), so that a rung that does not move on the real stage (stiction near
  // cut-off, the amplifier rounding a short fast phase, the actuator's resonance) has neighbours.
  static constexpr double kBandEdges[] = {0, 300, 700, 1200, 1e300};
  static constexpr double kShareEdges[] = {0, 0.03, 0.1, 0.25, 0.5};
  constexpr std::size_t kBands = sizeof kBandEdges / sizeof kBandEdges[0] - 1;
  constexpr std::size_t kShares = sizeof kShareEdges / sizeof kShareEdges[0] - 1;
  const double rel = rls_.rung_initial_relative_sd;
  for (int dir : {-1, 1}) {
    std::vector<Rung>& ladder = ladder_[index(dir)];
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
        const double sd_offset =
            std::max(rel, 1.0) * std::max(std::fabs(r.seed.offset_m), r.seed.step_m);
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
  landing_rungs_.reserve(ladder_[0].size() + ladder_[1].size());
  landing_index_.reserve(ladder_[0].size() + ladder_[1].size());
}

void StepLadder::start_move() {
  for (std::vector<Rung>& ladder : ladder_) {
    for (Rung& r : ladder) {
      RungEstimate stored;
      if (calibration_ != nullptr && calibration_->find_rung(r.direction, r.seed.freq_hz,
                                                             r.seed.duty, r.seed.stroke_m, stored))
        r.est = stored;
      else if (calibration_ == nullptr || !calibration_->config().enabled)
        r.est = r.seed;  // without calibration nothing is carried from one move to the next
      r.pending_pred_m = 0;
      r.pending_moved_m = 0;
      r.pending_cycles = 0;
      r.missed_cycles = 0;
    }
  }
  landing_try_ = LandingTry{};
  update_gain();
}

bool StepLadder::moves_enough(const Rung& r) const {
  return r.est.step_m >= config_.min_step_counts * count_m_;
}

bool StepLadder::live(Rung& r, std::uint64_t moves) {
  if (r.dead) {
    if (moves < r.dead_until_move) return false;
    // Its time is over: try it again from the seed.
    r.dead = false;
    r.killed_in_streak = false;
    r.est = r.seed;
    r.pending_pred_m = r.pending_moved_m = 0;
    r.pending_cycles = 0;
    if (calibration_ != nullptr) calibration_->store_rung(r.direction, r.est);
  }
  if (r.est.updates == 0) {
    // Never learned: its seed, scaled by what the learned rungs show of this stage. A seed
    // under min_step_counts is left out for now, not killed: with the gain it may yet move.
    r.est = scaled_seed(r);
    return moves_enough(r);
  }
  if (!moves_enough(r)) {
    kill(r, moves);
    return false;
  }
  return true;
}

RungEstimate StepLadder::scaled_seed(const Rung& r) const {
  RungEstimate e = r.seed;
  e.step_m *= gain_;
  e.offset_m *= gain_;
  e.p_ss *= gain_ * gain_;
  e.p_oo *= gain_ * gain_;
  e.p_os *= gain_ * gain_;
  return e;
}

void StepLadder::update_gain() {
  // The geometric mean of learned / seeded step over the learned rungs of both directions (the
  // stage's own alpha against the map's: one figure for the whole ladder), kept to [1/4, 4].
  double sum_log = 0;
  int n = 0;
  for (const std::vector<Rung>& l : ladder_)
    for (const Rung& x : l)
      if (!x.dead && x.est.updates > 0 && x.est.step_m > 0 && x.seed.step_m > 0) {
        sum_log += std::log(x.est.step_m / x.seed.step_m);
        ++n;
      }
  gain_ = n > 0 ? std::clamp(std::exp(sum_log / n), 0.25, 4.0) : 1.0;
}

double StepLadder::rung_uncertainty(const Rung& r) const {
  // Two standard deviations of its scatter once a few chunks have shown it; until then 100 %
  // (on a real stage a rung's first chunks move anywhere from nothing to twice the model's
  // step). Never below the step model's approach uncertainty.
  if (r.scatter_chunks < 3) return 1.0;
  return std::clamp(2.0 * std::sqrt(r.scatter_var), config_.approach_uncertainty, 1.0);
}

std::uint64_t StepLadder::chunk_limit(const Rung& r) const {
  const RegionCell& cell = map_.cells()[r.cell];
  return chunk_cycle_limit(chunk_limits_, config_.max_chunk_s, cell.freq_hz, cell.period_samples,
                           cell.max_cycles);
}

std::uint64_t StepLadder::moving_cycles(const Rung& r) const {
  return static_cast<std::uint64_t>(
      std::min(control::moving_cycles(r.est.offset_m, r.est.step_m), 1e6));
}

StepLadder::FinalChunk StepLadder::final_chunk_for(const Rung& r, double distance) const {
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
  out.cycles = !(n_real >= 1) ? 1
                              : (n_real >= 1e15 ? static_cast<std::uint64_t>(1e15)
                                                : static_cast<std::uint64_t>(n_real));
  const std::uint64_t max_cycles = map_.cells()[r.cell].max_cycles;
  if (max_cycles > 0) out.cycles = std::min(out.cycles, max_cycles);
  const std::uint64_t n_min = moving_cycles(r);
  while (out.cycles > n_min && passes(out.cycles)) {
    --out.cycles;
    out.cut = true;
  }
  out.safe = !passes(out.cycles);
  return out;
}

void StepLadder::kill(Rung& r, std::uint64_t moves) {
  r.dead = true;
  r.proven = false;
  r.dead_until_move = moves + static_cast<std::uint64_t>(config_.dead_rung_moves);
  r.pending_pred_m = r.pending_moved_m = 0;
  r.pending_cycles = 0;
}

void StepLadder::kill(int direction, std::size_t i, std::uint64_t moves) {
  kill(ladder_[index(direction)].at(i), moves);
}

double StepLadder::finest_live_step_m(int direction) const {
  double finest = 0;
  for (const Rung& r : ladder_[index(direction)]) {
    if (r.dead || !moves_enough(r)) continue;
    if (finest == 0 || r.est.step_m < finest) finest = r.est.step_m;
  }
  return finest;
}

StepLadder::Choice StepLadder::next_chunk(double error, double position_m, double landing_m,
                                          bool may_correct, std::uint64_t moves) {
  Choice out;
  const int sign = error > 0 ? 1 : -1;
  const double distance = std::fabs(error);
  std::vector<Rung>& ladder = ladder_[index(sign)];
  if (ladder.empty()) {
    out.kind = Choice::Kind::NoRungs;
    return out;
  }
  const int fin = final_rung(ladder, moves);
  if (fin < 0) {
    out.kind = Choice::Kind::NoLiveRung;
    return out;
  }
  const double b_final = ladder[static_cast<std::size_t>(fin)].est.step_m;
  out.direction = sign;
  out.final_step_m = b_final;
  // Approach: outside the final zone (ten final steps, at least three counts).
  if (distance > std::max(10.0 * b_final, 3.0 * count_m_))
    out.rung = approach_rung(ladder, distance, 3.0 * b_final + landing_m, out.cycles);
  if (out.rung >= 0) return out;
  out.final_chunk = true;
  out.rung = final_try(ladder, fin, distance, out.cycles, out.capped);
  if (!out.capped &&
      landing_plan(sign, error, position_m, landing_m, out.rung, out.cycles, moves, out))
    return out;
  // A chunk expected to end no nearer the target than the slider is now (the rung's shortest
  // chunk, its first cycle's offset and a step, is longer than twice the error) cannot land
  // from here: back off to where a rung lands within the window, and come back.
  const double landing_error =
      std::fabs(distance - ladder[static_cast<std::size_t>(out.rung)].est.predict_m(out.cycles));
  if (landing_error < distance) return out;
  // Another live rung that way may land nearer: the one whose chunk ends nearest the target.
  std::uint64_t n_near = 0;
  const int nearest = nearest_landing(ladder, distance, n_near);
  if (nearest >= 0 && std::fabs(distance - ladder[static_cast<std::size_t>(nearest)].est.predict_m(
                                               n_near)) < distance) {
    out.rung = nearest;
    out.cycles = n_near;
    out.capped = false;
    return out;
  }
  if (!may_correct) {
    out.kind = Choice::Kind::OutOfTries;
    return out;
  }
  if (back_off(sign, ladder, distance, landing_m, moves, out)) return out;
  // Neither: the chunk is played as planned, but never one predicted to move less than half a
  // step. Where a rung's first cycles move nothing, the nearest landing can be a chunk predicted
  // to move nothing, and such a chunk, never judged, was played 400 times in a row; one that
  // moves is judged and teaches the rung.
  const Rung& r = ladder[static_cast<std::size_t>(out.rung)];
  const std::uint64_t max_cycles = map_.cells()[r.cell].max_cycles;
  const std::uint64_t n_min = moving_cycles(r);
  out.cycles = std::max(out.cycles, max_cycles > 0 ? std::min(n_min, max_cycles) : n_min);
  return out;
}

int StepLadder::nearest_landing(const std::vector<Rung>& ladder, double distance,
                                std::uint64_t& cycles) const {
  int chosen = -1;
  double best = 0;
  for (std::size_t i = 0; i < ladder.size(); ++i) {
    const Rung& r = ladder[i];
    const double a = r.est.offset_m, b = r.est.step_m;
    if (r.dead || !r.proven || !moves_enough(r)) continue;
    const std::uint64_t max_cycles = map_.cells()[r.cell].max_cycles;
    const double n_real = std::clamp(std::round((distance - a) / b), 1.0, 1e6);
    for (double n : {n_real - 1, n_real, n_real + 1}) {
      if (n < 1 || (max_cycles > 0 && n > static_cast<double>(max_cycles))) continue;
      const auto cyc = static_cast<std::uint64_t>(n);
      const double miss = std::fabs(distance - r.est.predict_m(cyc));
      if (chosen < 0 || miss < best) {
        chosen = static_cast<int>(i);
        cycles = cyc;
        best = miss;
      }
    }
  }
  return chosen;
}

bool StepLadder::back_off(int sign, std::vector<Rung>& toward, double distance, double landing_m,
                          std::uint64_t moves, Choice& out) {
  // A rung toward the target lands within the window from a distance D when its chunks can be
  // placed that finely: its step (a chunk of n cycles moves offset + n steps) within the window's
  // width, from D at least its shortest moving chunk. The rung needing the least way back.
  const double width = 2.0 * landing_m;
  double from = 0;
  for (Rung& r : toward) {
    if (!live(r, moves) || !r.proven) continue;
    const double a = r.est.offset_m, b = r.est.step_m;
    if (!(b > 0) || b > width) continue;
    const double n_moving = control::moving_cycles(a, b);
    const double shortest = a + n_moving * b;
    if (!(shortest > 0)) continue;
    const double d = shortest + 0.5 * b;
    if (from == 0 || d < from) from = d;
  }
  const double away = from - distance;
  if (!(from > 0) || !(away > 0)) return false;
  // Away: the live rung whose chunk covers `away` with the least to spare (going farther only
  // costs the way back).
  std::vector<Rung>& other = ladder_[index(-sign)];
  int chosen = -1;
  std::uint64_t cycles = 0;
  double best = 0;
  for (std::size_t i = 0; i < other.size(); ++i) {
    Rung& r = other[i];
    if (!live(r, moves)) continue;
    const double a = r.est.offset_m, b = r.est.step_m;
    if (!(b > 0)) continue;
    const double n_real = std::max(1.0, std::ceil((away - a) / b));
    if (!(n_real < 1e6)) continue;
    const auto n = static_cast<std::uint64_t>(n_real);
    const RegionCell& cell = map_.cells()[r.cell];
    if (cell.max_cycles > 0 && n > cell.max_cycles) continue;
    const double moved = r.est.predict_m(n);
    if (!(moved >= away)) continue;
    if (chosen < 0 || moved < best) {
      chosen = static_cast<int>(i);
      cycles = n;
      best = moved;
    }
  }
  if (chosen < 0) return false;
  out.direction = -sign;
  out.rung = chosen;
  out.cycles = cycles;
  out.final_chunk = false;
  out.capped = false;
  out.back_off = true;
  out.final_step_m = other[static_cast<std::size_t>(chosen)].est.step_m;
  return true;
}

// The final rung: the live rung of the final class (learned step <= final_step_counts) with the
// best progress per second; without one, the finest live rung. -1: no live rung.
int StepLadder::final_rung(std::vector<Rung>& ladder, std::uint64_t moves) {
  const double final_bound = config_.final_step_counts * count_m_;
  int fin = -1, finest = -1;
  double fin_rate = 0;
  for (std::size_t i = 0; i < ladder.size(); ++i) {
    Rung& r = ladder[i];
    if (!live(r, moves)) continue;
    const double b = r.est.step_m;
    if (finest < 0 || b < ladder[static_cast<std::size_t>(finest)].est.step_m)
      finest = static_cast<int>(i);
    const double rate = b * map_.cells()[r.cell].freq_hz;
    if (b <= final_bound && rate > fin_rate) {
      fin_rate = rate;
      fin = static_cast<int>(i);
    }
  }
  return fin >= 0 ? fin : finest;
}

// The rung with the most expected progress per second of a chunk (its cycles plus
// chunk_overhead_s) among those whose planned burst, grown by the approach uncertainty and the
// rung's own, still stops `keep` short of the target. -1: none (the final zone's business).
int StepLadder::approach_rung(const std::vector<Rung>& ladder, double distance, double keep,
                              std::uint64_t& cycles) const {
  int chosen = -1;
  double best_score = 0;
  for (std::size_t i = 0; i < ladder.size(); ++i) {
    const Rung& r = ladder[i];
    if (r.dead) continue;  // live() ran before
    const RegionCell& cell = map_.cells()[r.cell];
    const double a = r.est.offset_m, b = r.est.step_m;
    // The speed limit: a rung whose learned speed, grown two standard deviations, exceeds it is
    // not used to approach.
    if (config_.max_speed_m_s > 0 &&
        (std::fabs(b) + 2.0 * std::sqrt(std::max(r.est.p_ss, 0.0))) * cell.freq_hz >
            config_.max_speed_m_s)
      continue;
    // Pessimistic: offset and step two standard deviations up, and the whole grown by
    // approach_uncertainty (friction along the guide).
    const double a_hi = a + 2.0 * std::sqrt(std::max(r.est.p_oo, 0.0));
    const double b_hi = b + 2.0 * std::sqrt(std::max(r.est.p_ss, 0.0));
    const double n_real =
        std::floor(((distance - keep) / (1.0 + config_.approach_uncertainty) - a_hi) / b_hi);
    if (!(n_real >= 1)) continue;
    std::uint64_t n =
        n_real >= 1e15 ? static_cast<std::uint64_t>(1e15) : static_cast<std::uint64_t>(n_real);
    if (cell.max_cycles > 0) n = std::min(n, cell.max_cycles);
    const std::uint64_t n_chunk = std::min(n, chunk_limit(r));
    const double progress = a + b * static_cast<double>(n_chunk);
    if (!(progress > 0)) continue;
    const double score =
        progress / (static_cast<double>(n_chunk) / cell.freq_hz + config_.chunk_overhead_s);
    if (score > best_score) {
      best_score = score;
      chosen = static_cast<int>(i);
      cycles = n;
    }
  }
  return chosen;
}

// Final: the final rung, the number of cycles whose learned displacement lands nearest; fewer
// when that burst, grown by the rung's uncertainty, could pass the target by more than 0.8 of its
// own steps. Such a shortened chunk is approach, not a try at the target (`capped`): it stops
// short and the next chunk is planned from where it stopped. Never below the cycles predicted to
// move at least half a step: a burst's first cycles can move nothing, and a chunk that moves
// nothing teaches nothing. When even that shortest chunk could pass too far, a finer live rung
// whose shortest chunk cannot is taken instead.
int StepLadder::final_try(const std::vector<Rung>& ladder, int fin, double distance,
                          std::uint64_t& cycles, bool& capped) const {
  const double b_final = ladder[static_cast<std::size_t>(fin)].est.step_m;
  int chosen = fin;
  FinalChunk plan = final_chunk_for(ladder[static_cast<std::size_t>(fin)], distance);
  if (!plan.safe) {
    double best_rate = 0;
    for (std::size_t i = 0; i < ladder.size(); ++i) {
      const Rung& x = ladder[i];
      if (static_cast<int>(i) == fin || x.dead || !(x.est.step_m < b_final) || !moves_enough(x))
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
  return chosen;
}

StepLadder::Judgement StepLadder::judge(int sign, int rung, std::uint64_t cycles,
                                        double predicted_along_m, double moved_m, bool in_stall_run,
                                        std::uint64_t moves) {
  std::vector<Rung>& ladder = ladder_[index(sign)];
  Rung& r = ladder.at(static_cast<std::size_t>(rung));
  ++r.chunks;
  const double along = sign * moved_m;
  const double predicted = std::max(predicted_along_m, 0.0);
  r.pending_pred_m += predicted;
  r.pending_moved_m += along;
  r.pending_cycles += cycles;
  Judgement j;
  // Judged once the prediction is a few counts and more than one cycle was played (a burst's
  // first cycle can stay in static friction: one cycle alone says little).
  j.judged = r.pending_pred_m >= config_.stall_min_counts * resolution_m() && r.pending_cycles >= 2;
  const bool wrong_way = along < -2.0 * resolution_m();
  // Not moving: less than stall_fraction of the prediction and less than two counts (a rung
  // that moves a quarter of its seed is slow, not dead: its estimate learns that).
  j.failed = wrong_way ||
             (j.judged && r.pending_moved_m < std::min(config_.stall_fraction * r.pending_pred_m,
                                                       2.0 * resolution_m()));
  if (j.judged || j.failed) {
    r.pending_pred_m = r.pending_moved_m = 0;
    r.pending_cycles = 0;
  }
  if (j.failed) {
    // A rung that does not move (or moves back) is left out; it counts toward a stall only when
    // it had moved before and is not of the final class, or is one of the coarse rungs (within
    // half of the largest live step): a fine rung near cut-off that does not move is the map
    // being wrong, or a stretch of the guide with more friction (where it moved before), not the
    // slider stuck. A rung that moved the slider the wrong way is left out too, but says nothing
    // of a stall or an end stop: the slider moved (a compliant stage's cell near cut-off can step
    // backwards on a stretch of the guide); if every rung that way fails, the ladder is empty
    // and that is the stall.
    double largest = 0;
    for (const Rung& x : ladder)
      if (!x.dead && &x != &r) largest = std::max(largest, x.est.step_m);
    const bool fine = r.est.step_m <= config_.final_step_counts * count_m_;
    const bool stuck = along >= -2.0 * resolution_m();
    j.counts_as_stall =
        stuck && ((r.proven && !fine) || r.est.step_m >= 0.5 * largest || in_stall_run);
    kill(r, moves);
    r.killed_in_streak = true;
    return j;
  }
  if (j.judged) {
    r.proven = true;
    for (std::vector<Rung>& l : ladder_)
      for (Rung& x : l) x.killed_in_streak = false;
  }
  learn(r, sign, cycles, along, predicted, moved_m, moves);
  return j;
}

void StepLadder::revive_streak() {
  for (std::vector<Rung>& l : ladder_)
    for (Rung& x : l)
      if (x.killed_in_streak) {
        x.dead = false;
        x.killed_in_streak = false;
      }
}

void StepLadder::learn(Rung& r, int sign, std::uint64_t cycles, double along, double predicted,
                       double moved_m, std::uint64_t moves) {
  if (along > -resolution_m() && predicted >= 2.0 * resolution_m()) {
    // Scored against the estimate the chunk was planned with, before it learns from it.
    const double rel = (along - predicted) / predicted;
    ++r.scatter_chunks;
    const double w = std::max(0.1, 1.0 / static_cast<double>(r.scatter_chunks));
    r.scatter_var += w * (rel * rel - r.scatter_var);
  }
  if (along > -resolution_m() &&
      Calibration::rls_update(r.est, cycles, along, resolution_m(), rls_.observation_relative_sd,
                              rls_.rung_forgetting, r.seed.p_oo, r.seed.p_ss)) {
    if (calibration_ != nullptr) calibration_->store_rung(sign, r.est);
    update_gain();
  }
  if (!moves_enough(r)) kill(r, moves);
  if (calibration_ != nullptr)
    calibration_->update(map_.cells()[r.cell], cycles, moved_m, count_m_);
}

}  // namespace idm::control
