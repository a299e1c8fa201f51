#include "control/planner.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

namespace idm::control {

const model::ParamTable<PlannerConfig>& planner_params() {
  using model::integer;
  using model::real;
  static const model::ParamTable<PlannerConfig> table({
      real<PlannerConfig>("resolution_m", "m", {0, 1e-6, true}, "one interferometer count (from the interferometer)",
                          [](auto& c) -> auto& { return c.resolution_m; }),
      real<PlannerConfig>("final_class_slack", "1", {1, 10},
                          "the last burst may use any cell within this factor of the finest step",
                          [](auto& c) -> auto& { return c.final_class_slack; }),
      integer<PlannerConfig>("final_approach_steps", "count", 2, 1000,
                             "the last burst covers about this many of its steps",
                             [](auto& c) -> auto& { return c.final_approach_steps; }),
      integer<PlannerConfig>("max_bursts", "count", 1, 1000000, "most bursts in one plan",
                             [](auto& c) -> auto& { return c.max_bursts; }),
  });
  return table;
}

void validate(const PlannerConfig& c, const std::string& where) { planner_params().validate(c, where); }

bool Plan::within_final_step() const {
  return std::fabs(residual_m()) <= final_step_m * (1 + 1e-9);
}

std::uint64_t Plan::total_cycles() const {
  std::uint64_t n = 0;
  for (const Burst& b : bursts) n += b.cycles;
  return n;
}

double Plan::duration_s() const {
  double t = 0;
  for (const Burst& b : bursts) t += b.duration_s();
  return t;
}

namespace {
std::uint64_t clamp_cycles(double n, std::uint64_t max_cycles) {
  if (!(n >= 1)) return 1;
  if (n >= static_cast<double>(max_cycles)) return max_cycles;
  return static_cast<std::uint64_t>(n);
}
}  // namespace

Planner::Planner(const RegionMap& map, PlannerConfig config) : map_(map), config_(config) {
  validate(config_);
  for (std::size_t i : map_.usable_cells()) {
    const RegionCell& c = map_.cells()[i];
    const int sign = c.direction();
    const double along_min = sign * c.step_min_m;
    const double along_max = sign * c.step_max_m;
    Entry e{};
    e.step_m = sign * c.step_m;
    e.step_hi_m = std::max(along_min, along_max);
    e.single_m = sign * c.single_burst_m;
    e.single_hi_m = std::max(sign * c.single_burst_min_m, sign * c.single_burst_max_m);
    e.period_s = c.period_s();
    e.max_cycles = c.max_cycles;
    e.cell = i;
    if (!(e.step_m > 0)) continue;  // a usable cell always moves its way; kept as a guard
    (sign > 0 ? positive_ : negative_).all.push_back(e);
  }
  for (Direction* dir : {&positive_, &negative_}) {
    std::sort(dir->all.begin(), dir->all.end(), [](const Entry& a, const Entry& b) {
      if (a.step_m != b.step_m) return a.step_m > b.step_m;
      if (a.period_s != b.period_s) return a.period_s < b.period_s;
      return a.cell < b.cell;
    });
    if (dir->all.empty()) continue;
    const double finest = dir->all.back().step_m;
    // The resolution where the map steps within it, else a little above the finest step.
    dir->final_step_bound_m =
        finest <= config_.resolution_m ? config_.resolution_m : config_.final_class_slack * finest;
    dir->smallest_move_m = std::numeric_limits<double>::infinity();
    for (const Entry& e : dir->all) {
      if (e.step_m <= dir->final_step_bound_m) dir->last.push_back(e);
      // The first positive displacement single + (n-1) step of this cell.
      const std::uint64_t n =
          e.single_m > 0 ? 1 : clamp_cycles(2 + std::floor(-e.single_m / e.step_m), e.max_cycles);
      if (e.displacement_m(n) > 0)
        dir->smallest_move_m = std::min(dir->smallest_move_m, e.displacement_m(n));
    }
    if (std::isinf(dir->smallest_move_m)) dir->smallest_move_m = 0;  // none moves forward
    dir->approach = dir->all;
    std::stable_sort(
        dir->approach.begin(), dir->approach.end(),
        [](const Entry& a, const Entry& b) { return a.rate_bound_m() > b.rate_bound_m(); });
  }
}

double Planner::largest_step_m(int sign) const {
  const Direction& d = direction(sign);
  return d.all.empty() ? 0.0 : d.all.front().step_m;
}

double Planner::finest_step_m(int sign) const {
  const Direction& d = direction(sign);
  return d.all.empty() ? 0.0 : d.all.back().step_m;
}

double Planner::final_step_bound_m(int sign) const {
  return direction(sign).final_step_bound_m;
}

Burst Planner::make_burst(const Entry& e, std::uint64_t cycles, int sign) const {
  const RegionCell& c = map_.cells()[e.cell];
  Burst b;
  b.freq_hz = c.freq_hz;
  b.duty = c.duty;
  b.stroke_m = c.stroke_m;
  b.period_samples = c.period_samples;
  b.extension_samples = c.extension_samples;
  b.cycles = cycles;
  b.step_m = c.step_m;
  b.displacement_m = sign * e.displacement_m(cycles);
  b.cell_index = e.cell;
  return b;
}

void Planner::plan(double distance_m, Plan& out) const {
  out.target_m = distance_m;
  out.bursts.clear();
  out.predicted_m = 0;
  out.final_step_m = 0;
  const double k = config_.final_approach_steps;
  double remaining = distance_m;
  for (int b = 0; b < config_.max_bursts && remaining != 0.0; ++b) {
    const int sign = remaining > 0 ? 1 : -1;
    const Direction& dir = direction(sign);
    if (dir.all.empty()) break;
    const double a = std::fabs(remaining);
    const double bound = dir.final_step_bound_m;
    if (a <= 0.5 * bound) break;

    const Entry* chosen = nullptr;
    std::uint64_t cycles = 0;
    if (a > k * bound) {
      // Approach: the burst that stops at least `leave` short of the target for every mu of the
      // interval and makes the most progress per cycle (the largest safe steps for the bulk); ties
      // go to more progress, then to the shorter burst. Entries are sorted by the bound
      // max(step, single) on their progress per cycle, so the scan stops early.
      const double leave = 0.5 * k * bound;
      double best_rate = 0;
      double best_progress = 0;
      double best_time = 0;
      for (const Entry& e : dir.approach) {
        if (e.rate_bound_m() < best_rate) break;
        const double room = a - leave - e.single_hi_m;
        if (room < 0) continue;
        const std::uint64_t n = clamp_cycles(1 + std::floor(room / e.step_hi_m), e.max_cycles);
        const double progress = e.displacement_m(n);
        if (!(progress > 0)) continue;
        const double rate = progress / static_cast<double>(n);
        const double time = static_cast<double>(n) * e.period_s;
        const bool better =
            chosen == nullptr || rate > best_rate ||
            (rate == best_rate &&
             (progress > best_progress || (progress == best_progress && time < best_time)));
        if (!better) continue;
        chosen = &e;
        cycles = n;
        best_rate = rate;
        best_progress = progress;
        best_time = time;
      }
    }
    if (chosen == nullptr) {
      // Last burst: a step within the final class, the cycles that land nearest the target.
      // Preferred: landing within half its own step; among those the fewest cycles, then the
      // shortest burst, then the smallest error. Otherwise the smallest error that still improves.
      // If no cell of the final class comes closer (their one-cycle bursts all overshoot by more
      // than the distance), the same choice among all usable cells of the direction.
      bool best_good = false;
      double best_err = a;
      double best_time = 0;
      auto consider = [&](const Entry& e) {
        const std::uint64_t n =
            clamp_cycles(1 + std::round((a - e.single_m) / e.step_m), e.max_cycles);
        const double err = std::fabs(a - e.displacement_m(n));
        if (!(err < a)) return;
        const bool good = err <= 0.5 * e.step_m * (1 + 1e-9);
        const double time = static_cast<double>(n) * e.period_s;
        bool better;
        if (chosen == nullptr) {
          better = true;
        } else if (good != best_good) {
          better = good;
        } else if (good) {
          better = n != cycles ? n < cycles : time != best_time ? time < best_time : err < best_err;
        } else {
          better = err != best_err ? err < best_err : n < cycles;
        }
        if (!better) return;
        chosen = &e;
        cycles = n;
        best_good = good;
        best_err = err;
        best_time = time;
      };
      for (const Entry& e : dir.last) consider(e);
      if (chosen == nullptr) {
        for (const Entry& e : dir.all) consider(e);
      }
      if (chosen == nullptr) break;
    }
    out.bursts.push_back(make_burst(*chosen, cycles, sign));
    out.predicted_m += out.bursts.back().displacement_m;
    remaining = distance_m - out.predicted_m;
  }
  if (!out.bursts.empty()) {
    out.final_step_m = std::fabs(out.bursts.back().step_m);
  } else if (distance_m != 0.0) {
    const Direction& dir = direction(distance_m > 0 ? 1 : -1);
    out.final_step_m = std::fabs(distance_m) <= 0.5 * dir.final_step_bound_m || dir.all.empty()
                           ? dir.final_step_bound_m
                           : dir.smallest_move_m;
  }
}

Plan Planner::plan(double distance_m) const {
  Plan p;
  plan(distance_m, p);
  return p;
}

}  // namespace idm::control
