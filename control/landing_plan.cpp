#include "control/landing_plan.h"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace idm::control {

namespace {

double chunk_mean_m(const LandingRung& r, std::uint64_t n) {
  return r.offset_m + static_cast<double>(n) * r.step_m;
}

// The variance of the estimate of D(n).
double estimate_var(const LandingRung& r, std::uint64_t n) {
  const double k = static_cast<double>(n);
  return std::max(r.p_oo + 2 * k * r.p_os + k * k * r.p_ss, 0.0);
}

double chunk_sd_m(const LandingRung& r, std::uint64_t n, double mean_m) {
  const double s = r.rel_sd * mean_m;
  return std::sqrt(s * s + estimate_var(r, n));
}

// The farthest a chunk may end: its mean grown by the rung's margin and two of the estimate's
// standard deviations.
double chunk_most_m(const LandingRung& r, std::uint64_t n, double mean_m) {
  return mean_m + r.rel_margin * std::fabs(mean_m) + 2 * std::sqrt(estimate_var(r, n));
}

double chunk_time_s(const LandingRung& r, std::uint64_t n, double overhead_s) {
  return static_cast<double>(n) / r.freq_hz + overhead_s;
}

bool usable(const LandingRung& r) {
  return r.step_m > 0 && std::isfinite(r.step_m) && std::isfinite(r.offset_m) && r.freq_hz > 0 &&
         r.rel_sd >= 0 && r.rel_margin >= 0 && (r.direction == 1 || r.direction == -1);
}

double room_m(const LandingLimits& lim, int direction) {
  return lim.room_m[direction > 0 ? 1 : 0];
}

// Whether plan a is better than b: less expected time.
bool better(const LandingPlan& a, const LandingPlan& b) {
  if (!(a.probability > 0)) return false;
  if (!(b.probability > 0)) return true;
  return a.expected_s() < b.expected_s();
}

// Chunk (r, cycles) toward a target `distance` away, after a first chunk of variance prior_var
// and time prior_s.
LandingPlan scored(const LandingRung& r, int index, std::uint64_t cycles, double distance,
                   const LandingLimits& lim, double prior_var, double prior_s) {
  const double mean = chunk_mean_m(r, cycles);
  const double sd = chunk_sd_m(r, cycles, mean);
  LandingPlan p;
  p.first = {index, cycles};
  p.probability = landing_probability(
      mean - distance, std::sqrt(sd * sd + prior_var + lim.read_sd_m * lim.read_sd_m),
      lim.half_window_m);
  p.time_s = prior_s + chunk_time_s(r, cycles, lim.chunk_overhead_s);
  return p;
}

// The best single chunk for `error_m` after a first chunk of variance `prior_var` and time
// `prior_s` that moved the slider `moved_m` (signed) from where the limits' room was measured;
// its time_s includes prior_s.
LandingPlan single(double error_m, const LandingLimits& lim, const LandingRung* rungs,
                   std::size_t count, double prior_var, double prior_s, double moved_m) {
  LandingPlan best;
  const int sign = error_m >= 0 ? 1 : -1;
  const double distance = std::fabs(error_m);
  const double room = room_m(lim, sign) - sign * moved_m;
  for (std::size_t i = 0; i < count; ++i) {
    const LandingRung& r = rungs[i];
    if (!usable(r) || r.direction != sign) continue;
    // The nearest landing and its neighbours, the most cycles the limits allow (where the nearest
    // passes too far, the chunk is as long as it may be) and the shortest chunks (the least
    // scatter where a rung's grows with its chunk).
    const double n_real = std::round((distance - r.offset_m) / r.step_m);
    const double reach = std::min(distance + lim.max_pass_steps * r.step_m, room);
    double n_max = std::min(r.max_cycles > 0 ? static_cast<double>(r.max_cycles) : 1e9,
                            std::floor((reach / (1 + r.rel_margin) - r.offset_m) / r.step_m));
    // The estimate's margin grows with n too: the longest chunk that keeps to reach, by
    // bisection (the pessimistic end grows with n).
    auto keeps = [&](double n) {
      const auto c = static_cast<std::uint64_t>(n);
      return chunk_most_m(r, c, chunk_mean_m(r, c)) <= reach;
    };
    if (n_max >= 1 && !keeps(n_max)) {
      double lo = 0, hi = n_max;  // keeps(lo) (or lo 0: none), !keeps(hi)
      while (hi - lo > 1) {
        const double mid = std::floor(0.5 * (lo + hi));
        (keeps(mid) ? lo : hi) = mid;
      }
      n_max = lo;
    }
    const double candidates[] = {1,      2,          3,          n_real - 2, n_real - 1,
                                 n_real, n_real + 1, n_real + 2, n_max - 1,  n_max};
    for (std::size_t k = 0; k < sizeof candidates / sizeof candidates[0]; ++k) {
      const double n = candidates[k];
      bool seen = false;  // each cycle count once
      for (std::size_t j = 0; j < k; ++j) seen = seen || candidates[j] == n;
      if (seen || !(n >= 1) || n > n_max) continue;
      const auto cycles = static_cast<std::uint64_t>(n);
      const double mean = chunk_mean_m(r, cycles);
      const double most = chunk_most_m(r, cycles, mean);
      if (most - distance > lim.max_pass_steps * r.step_m || most > room) continue;
      // A chunk expected to end outside the window lands only by its scatter: once it missed in
      // this move it is not tried so again (a stage that repeats itself misses the same way).
      if (std::fabs(mean - distance) > lim.half_window_m && cycles == r.missed_cycles) continue;
      LandingPlan p = scored(r, static_cast<int>(i), cycles, distance, lim, prior_var, prior_s);
      if (p.probability >= kMinLandingProbability && better(p, best)) best = p;
    }
  }
  return best;
}

}  // namespace

double landing_probability(double miss_m, double sd_m, double half_window_m) {
  if (!(half_window_m > 0)) return 0;
  if (!(sd_m > 0)) return std::fabs(miss_m) <= half_window_m ? 1.0 : 0.0;
  // Phi((w - m) / s) - Phi((-w - m) / s), through erfc for accuracy in the tails.
  const double k = 1.0 / (sd_m * std::sqrt(2.0));
  const double p =
      0.5 * (std::erfc((-half_window_m - miss_m) * k) - std::erfc((half_window_m - miss_m) * k));
  return std::clamp(p, 0.0, 1.0);
}

double moving_cycles(double offset_m, double step_m) {
  return std::max(1.0, std::ceil((0.5 * step_m - offset_m) / step_m));  // NaN: 1
}

double grid_landing_probability(double half_spacing_m, double sd_m, double half_window_m) {
  const double h = std::max(half_spacing_m, 0.0), s = std::max(sd_m, 0.0), w = half_window_m;
  if (!(w > 0)) return 0;
  const double scale = h + s + w;
  if (h <= 1e-9 * scale) return landing_probability(0.0, s, w);
  if (s <= 1e-9 * scale) return std::min(1.0, w / h);
  // (1 / 2h) int_{-h}^{h} [Phi((w - u) / s) - Phi((-w - u) / s)] du, with
  // int Phi(x) dx = x Phi(x) + phi(x) =: G(x).
  const auto G = [](double x) {
    return x * 0.5 * std::erfc(-x / std::sqrt(2.0)) +
           std::exp(-0.5 * x * x) * std::numbers::inv_sqrtpi / std::numbers::sqrt2;
  };
  const double p =
      s / (2 * h) * (G((w + h) / s) - G((w - h) / s) - G((h - w) / s) + G((-w - h) / s));
  return std::clamp(p, 0.0, 1.0);
}

namespace {

// The shortest chunk of r predicted to move half a step, its mean.
double shortest_moving_m(const LandingRung& r) {
  return r.offset_m + moving_cycles(r.offset_m, r.step_m) * r.step_m;
}

double try_probability(const LandingRung* rungs, std::size_t count, double half_window_m,
                       double read_sd_m, std::uint64_t max_first_cycles) {
  // The vernier's first chunks: how many there are, and the least scatter among them.
  double first_chunks = 0, first_var = -1;
  for (std::size_t i = 0; i < count; ++i) {
    const LandingRung& r = rungs[i];
    if (!usable(r)) continue;
    const std::uint64_t n_max =
        r.max_cycles > 0 ? std::min(r.max_cycles, max_first_cycles) : max_first_cycles;
    for (std::uint64_t n = 1; n <= n_max; ++n) {
      const double mean = chunk_mean_m(r, n);
      if (!(mean > 0)) continue;
      first_chunks += 1;
      const double v = (r.rel_sd * mean) * (r.rel_sd * mean);
      if (first_var < 0 || v < first_var) first_var = v;
    }
  }
  double best = 0;
  const double read_var = read_sd_m * read_sd_m;
  for (std::size_t i = 0; i < count; ++i) {
    const LandingRung& r = rungs[i];
    if (!usable(r)) continue;
    const double sd = r.rel_sd * shortest_moving_m(r);
    const double var = sd * sd + read_var;
    best = std::max(best, grid_landing_probability(0.5 * r.step_m, std::sqrt(var), half_window_m));
    if (first_chunks > 0)
      best = std::max(best, grid_landing_probability(0.5 * r.step_m / first_chunks,
                                                     std::sqrt(var + first_var), half_window_m));
  }
  return best;
}

}  // namespace

LandingReach landing_reach(const LandingRung* rungs, std::size_t count, double half_window_m,
                           double read_sd_m, std::uint64_t max_first_cycles, int tries) {
  LandingReach out;
  out.try_probability = try_probability(rungs, count, half_window_m, read_sd_m, max_first_cycles);
  out.arrival_probability =
      1.0 - std::pow(1.0 - out.try_probability, static_cast<double>(std::max(tries, 1)));
  return out;
}

double least_half_window_m(const LandingRung* rungs, std::size_t count, double read_sd_m,
                           std::uint64_t max_first_cycles, int tries) {
  double hi = read_sd_m;
  for (std::size_t i = 0; i < count; ++i)
    if (usable(rungs[i])) hi = std::max(hi, rungs[i].step_m + shortest_moving_m(rungs[i]));
  const auto meets = [&](double w) {
    return landing_reach(rungs, count, w, read_sd_m, max_first_cycles, tries).reachable();
  };
  if (!(hi > 0)) return 0;
  double lo = 0;
  for (int k = 0; k < 60 && !meets(hi); ++k) {  // scatter wider than the grid: widen
    lo = hi;
    hi *= 2;
  }
  if (!meets(hi)) return 0;  // !meets(lo) (a window of nothing), meets(hi)
  while (hi - lo > 0.01 * hi) {
    const double mid = 0.5 * (lo + hi);
    (meets(mid) ? hi : lo) = mid;
  }
  return hi;
}

LandingPlan score_chunk(double error_m, const LandingLimits& limits, const LandingRung* rungs,
                        std::size_t index, std::uint64_t cycles) {
  return scored(rungs[index], static_cast<int>(index), cycles, std::fabs(error_m), limits, 0.0,
                0.0);
}

LandingPlan best_single_chunk(double error_m, const LandingLimits& limits, const LandingRung* rungs,
                              std::size_t count) {
  return single(error_m, limits, rungs, count, 0.0, 0.0, 0.0);
}

LandingPlan plan_landing(double error_m, const LandingLimits& limits, const LandingRung* rungs,
                         std::size_t count) {
  LandingPlan best = single(error_m, limits, rungs, count, 0.0, 0.0, 0.0);
  const int sign = error_m >= 0 ? 1 : -1;
  const double distance = std::fabs(error_m);
  for (std::size_t i = 0; i < count; ++i) {
    const LandingRung& r = rungs[i];
    if (!usable(r)) continue;
    const std::uint64_t n_max = r.max_cycles > 0 ? std::min(r.max_cycles, limits.max_first_cycles)
                                                 : limits.max_first_cycles;
    for (std::uint64_t n = 1; n <= n_max; ++n) {
      const double mean = chunk_mean_m(r, n);
      if (!(mean > 0)) continue;
      const double sd = chunk_sd_m(r, n, mean);
      const double most = chunk_most_m(r, n, mean);
      if (most > room_m(limits, r.direction)) break;
      if (r.direction == sign && most - distance > limits.max_pass_steps * r.step_m) break;
      const double moved = r.direction * mean;
      const double rest = error_m - moved;
      // A first chunk that lands by itself is a single chunk's business.
      if (std::fabs(rest) <= limits.half_window_m) continue;
      LandingPlan p = single(rest, limits, rungs, count, sd * sd,
                             chunk_time_s(r, n, limits.chunk_overhead_s), moved);
      if (!(p.probability > 0)) continue;
      p.second = p.first;
      p.first = {static_cast<int>(i), n};
      if (better(p, best)) best = p;
    }
  }
  return best;
}

}  // namespace idm::control
