// The landing plan (control/landing_plan.h) against code written apart from it: the probability
// by numerical integration of the normal density, the plan by enumerating every one- and
// two-chunk plan over drawn rungs.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "control/landing_plan.h"

namespace idm::control {
namespace {

std::uint64_t seed() {
  const char* s = std::getenv("IDM_TEST_SEED");
  return s != nullptr ? std::strtoull(s, nullptr, 10) : std::random_device{}();
}

// Simpson's rule for f over [a, b] with n (even) intervals.
template <class F>
double simpson(F&& f, double a, double b, int n) {
  const double h = (b - a) / n;
  double sum = f(a) + f(b);
  for (int i = 1; i < n; ++i) sum += (i % 2 ? 4 : 2) * f(a + i * h);
  return sum * h / 3;
}

// Simpson's rule over the window of a normal density.
double integrated_probability(double miss, double sd, double half) {
  auto pdf = [&](double x) {
    const double z = (x - miss) / sd;
    return std::exp(-0.5 * z * z) / (sd * std::sqrt(2 * M_PI));
  };
  return simpson(pdf, -half, half, 20000);
}

TEST(LandingPlan, ProbabilityIsTheNormalMassInsideTheWindow) {
  std::mt19937_64 rng(seed());
  std::uniform_real_distribution<double> u(0, 1);
  for (int k = 0; k < 500; ++k) {
    const double half = 1e-9 * (0.5 + 10 * u(rng));
    const double sd = 1e-9 * (0.05 + 30 * u(rng));
    const double miss = 1e-9 * (60 * u(rng) - 30);
    const double p = landing_probability(miss, sd, half);
    EXPECT_NEAR(p, integrated_probability(miss, sd, half), 1e-7)
        << "miss " << miss << " sd " << sd << " half " << half;
    EXPECT_NEAR(p, landing_probability(-miss, sd, half), 1e-12);  // symmetric
  }
  EXPECT_EQ(landing_probability(1e-9, 0, 2e-9), 1.0);  // certain and inside
  EXPECT_EQ(landing_probability(3e-9, 0, 2e-9), 0.0);
  EXPECT_EQ(landing_probability(0, 1e-9, 0), 0.0);  // no window
}

// The plan from first principles: every chunk of every rung with 1..max cycles, every pair
// (first chunks of up to max_first_cycles), every chunk kept to the limits as the header states.
struct Brute {
  const LandingLimits& lim;
  const std::vector<LandingRung>& rungs;

  static double mean(const LandingRung& r, std::uint64_t n) {
    return r.offset_m + static_cast<double>(n) * r.step_m;
  }
  static double est_var(const LandingRung& r, std::uint64_t n) {
    const double k = static_cast<double>(n);
    return std::max(r.p_oo + 2 * k * r.p_os + k * k * r.p_ss, 0.0);
  }
  double room(int dir) const { return lim.room_m[dir > 0 ? 1 : 0]; }
  // Whether chunk (r, n) may be played toward `error` after `moved` (its pessimistic end).
  bool allowed(const LandingRung& r, std::uint64_t n, double error, double moved) const {
    if (r.max_cycles > 0 && n > r.max_cycles) return false;
    const double m = mean(r, n),
                 most = m + r.rel_margin * std::fabs(m) + 2 * std::sqrt(est_var(r, n));
    if (most > room(r.direction) - r.direction * moved) return false;
    const int sign = error >= 0 ? 1 : -1;
    return !(r.direction == sign && most - std::fabs(error) > lim.max_pass_steps * r.step_m);
  }
  // The landing chunk's mean ends within the window, or it has not missed in this move.
  bool aims_inside(const LandingRung& r, std::uint64_t n, double error) const {
    return std::fabs(mean(r, n) - std::fabs(error)) <= lim.half_window_m || n != r.missed_cycles;
  }
  double expected(const LandingPlan& p) const {
    return p.probability > 0 ? p.time_s / p.probability : 1e300;
  }
  // The least expected time over every plan, and whether some plan exists.
  double best(double error, std::uint64_t max_n) const {
    double best_s = 1e300;
    auto time = [&](const LandingRung& r, std::uint64_t n) {
      return static_cast<double>(n) / r.freq_hz + lim.chunk_overhead_s;
    };
    auto var = [&](const LandingRung& r, std::uint64_t n) {
      const double s = r.rel_sd * mean(r, n);
      return s * s + est_var(r, n);
    };
    const double rv = lim.read_sd_m * lim.read_sd_m;
    for (const LandingRung& a : rungs)
      for (std::uint64_t n = 1; n <= max_n; ++n) {
        if (a.direction != (error >= 0 ? 1 : -1) || !allowed(a, n, error, 0) ||
            !aims_inside(a, n, error))
          continue;
        const double p = landing_probability(mean(a, n) - std::fabs(error),
                                             std::sqrt(var(a, n) + rv), lim.half_window_m);
        if (p >= kMinLandingProbability) best_s = std::min(best_s, time(a, n) / p);
      }
    for (const LandingRung& a : rungs)
      for (std::uint64_t n = 1; n <= lim.max_first_cycles; ++n) {
        if (!(mean(a, n) > 0) || !allowed(a, n, error, 0)) continue;
        const double moved = a.direction * mean(a, n);
        const double rest = error - moved;
        if (std::fabs(rest) <= lim.half_window_m) continue;
        for (const LandingRung& b : rungs)
          for (std::uint64_t k = 1; k <= max_n; ++k) {
            if (b.direction != (rest >= 0 ? 1 : -1) || !allowed(b, k, rest, moved) ||
                !aims_inside(b, k, rest))
              continue;
            const double p =
                landing_probability(mean(b, k) - std::fabs(rest),
                                    std::sqrt(var(a, n) + var(b, k) + rv), lim.half_window_m);
            if (p >= kMinLandingProbability)
              best_s = std::min(best_s, (time(a, n) + time(b, k)) / p);
          }
      }
    return best_s;
  }
};

std::string describe(double error, const LandingLimits& lim,
                     const std::vector<LandingRung>& rungs) {
  std::ostringstream o;
  o.precision(17);
  o << "error " << error * 1e9 << " nm, half window " << lim.half_window_m * 1e9 << " nm, room "
    << lim.room_m[0] * 1e9 << " / " << lim.room_m[1] * 1e9 << " nm; rungs (dir offset step sd "
    << "max f):";
  for (const LandingRung& r : rungs)
    o << " [" << r.direction << " " << r.offset_m * 1e9 << " " << r.step_m * 1e9 << " " << r.rel_sd
      << " " << r.max_cycles << " " << r.freq_hz << "]";
  return o.str();
}

TEST(LandingPlan, FindsTheLeastExpectedTimeOfEveryOneAndTwoChunkPlan) {
  const std::uint64_t s = seed();
  std::mt19937_64 rng(s);
  std::uniform_real_distribution<double> u(0, 1);
  int two = 0, none = 0, exact = 0, found = 0;
  for (int k = 0; k < 1000; ++k) {
    LandingLimits lim;
    const double count = u(rng) < 0.5 ? 9.89e-9 : 4.95e-9;
    lim.half_window_m = 0.5 * count;
    lim.read_sd_m = count / std::sqrt(12.0);
    lim.chunk_overhead_s = 5e-3;
    const double error = 1e-9 * (400 * u(rng) - 200);
    // The target lies inside the limits: the room its way is at least the distance.
    for (int dir : {-1, 1}) {
      const double need = (dir > 0) == (error >= 0) ? std::fabs(error) : 0;
      lim.room_m[dir > 0 ? 1 : 0] = need + (u(rng) < 0.3 ? 1e-7 * u(rng) : 1e-3);
    }
    std::vector<LandingRung> rungs(1 + rng() % 8);
    for (LandingRung& r : rungs) {
      r.direction = u(rng) < 0.5 ? -1 : 1;
      r.step_m = 1e-9 * std::exp(std::log(2.0) + u(rng) * std::log(200.0 / 2.0));
      r.offset_m = r.step_m * (2 * u(rng) - 0.8);
      r.rel_sd = u(rng) < 0.3 ? 0.5 : 0.01 + 0.3 * u(rng);
      r.rel_margin = u(rng) < 0.3 ? 1.0 : std::max(0.2, 2 * r.rel_sd);
      // An estimate's covariance (a positive semi-definite 2x2): offset known to 0-100 % of a
      // step, the step to 0-20 %, correlated either way.
      const double so = r.step_m * u(rng), ss = 0.2 * r.step_m * u(rng), rho = 2 * u(rng) - 1;
      r.p_oo = so * so;
      r.p_ss = ss * ss;
      r.p_os = rho * so * ss;
      r.freq_hz = 100 + 1900 * u(rng);
      r.max_cycles = u(rng) < 0.2 ? 1 + rng() % 3 : 0;
      r.missed_cycles = u(rng) < 0.3 ? 1 + rng() % 40 : 0;
    }
    const LandingPlan plan = plan_landing(error, lim, rungs.data(), rungs.size());
    // The brute force over cycles up to where every chunk passes any target of this size.
    const double want = Brute{lim, rungs}.best(error, 400);
    if (want >= 1e300) {
      EXPECT_EQ(plan.probability, 0) << "seed " << s << " case " << k;
      ++none;
      continue;
    }
    const std::string what = "seed " + std::to_string(s) + " case " + std::to_string(k) + ": " +
                             describe(error, lim, rungs);
    ASSERT_GT(plan.probability, 0) << what;
    // It is one of the plans (never better than the best), and the candidate cycles
    // (landing_plan.h) hold the best of every cycle count or come within 5 % of it (where the
    // limits cut a rung's chunks short of its nearest landing, the best can lie a few cycles
    // inside the longest allowed).
    EXPECT_GE(plan.expected_s(), want * (1 - 1e-9)) << what;
    EXPECT_LE(plan.expected_s(), want * 1.05) << what;
    exact += plan.expected_s() <= want * (1 + 1e-9);
    ++found;
    two += plan.two_chunks();
    // The plan as told: its chunks are the rungs' and keep to the limits.
    const Brute brute{lim, rungs};
    const LandingRung& a = rungs.at(static_cast<std::size_t>(plan.first.rung));
    EXPECT_TRUE(brute.allowed(a, plan.first.cycles, error, 0));
    if (plan.two_chunks()) {
      EXPECT_LE(plan.first.cycles, lim.max_first_cycles);
      const double moved = a.direction * Brute::mean(a, plan.first.cycles);
      const LandingRung& b = rungs.at(static_cast<std::size_t>(plan.second.rung));
      EXPECT_TRUE(brute.allowed(b, plan.second.cycles, error - moved, moved));
    } else {
      EXPECT_EQ(a.direction, error >= 0 ? 1 : -1);
    }
  }
  // The draw covers both kinds of plan and cases with none.
  EXPECT_GT(two, 5) << "seed " << s;
  EXPECT_GT(none, 0) << "seed " << s;
  EXPECT_GE(exact, found * 95 / 100) << "seed " << s;
}

TEST(LandingPlan, TwoCoarseRungsOfDifferentStepsLandWhereNeitherCanAlone) {
  // +62.8 nm and -57.3 nm a chunk, each within 1 %: 6 nm from the target with a window of
  // +/- 2.5 nm, neither lands alone; +62.8 then -57.3 ends 0.5 nm off.
  LandingLimits lim;
  lim.half_window_m = 2.47e-9;
  lim.read_sd_m = 1.4e-9;
  lim.chunk_overhead_s = 5e-3;
  std::vector<LandingRung> rungs(2);
  rungs[0] = {
      .direction = 1, .step_m = 62.8e-9, .rel_sd = 0.01, .rel_margin = 0.2, .freq_hz = 1316};
  rungs[1] = {
      .direction = -1, .step_m = 57.3e-9, .rel_sd = 0.01, .rel_margin = 0.2, .freq_hz = 290};
  const double error = 6e-9;
  EXPECT_EQ(best_single_chunk(error, lim, rungs.data(), rungs.size()).probability, 0);
  const LandingPlan p = plan_landing(error, lim, rungs.data(), rungs.size());
  // Through the target would pass it by most of a step: away first (-57.3), then +62.8.
  ASSERT_TRUE(p.two_chunks());
  EXPECT_EQ(p.first.rung, 1);
  EXPECT_EQ(p.first.cycles, 1u);
  EXPECT_EQ(p.second.rung, 0);
  EXPECT_EQ(p.second.cycles, 1u);
  EXPECT_GT(p.probability, 0.6);
  // With no room to back off, there is no plan.
  lim.room_m[0] = 10e-9;
  EXPECT_EQ(plan_landing(error, lim, rungs.data(), rungs.size()).probability, 0);
}

// P(|U + N| <= w) by Simpson's rule over u of the normal mass (integrated_probability) for U
// uniform on [-h, h].
double integrated_grid_probability(double h, double sd, double half) {
  return simpson([&](double u) { return integrated_probability(u, sd, half); }, -h, h, 400) /
         (2 * h);
}

TEST(LandingReach, GridProbabilityIsTheMassOfAUniformPlusANormalInsideTheWindow) {
  std::mt19937_64 rng(seed());
  std::uniform_real_distribution<double> u(0, 1);
  for (int k = 0; k < 12; ++k) {
    const double h = 1e-9 * (0.2 + 40 * u(rng));
    const double sd = 1e-9 * (0.2 + 20 * u(rng));
    const double half = 1e-9 * (0.1 + 10 * u(rng));
    EXPECT_NEAR(grid_landing_probability(h, sd, half), integrated_grid_probability(h, sd, half),
                1e-6)
        << "h " << h << " sd " << sd << " half " << half;
  }
  // The limits: no scatter (the grid alone), no grid (the normal alone), no window.
  EXPECT_DOUBLE_EQ(grid_landing_probability(10e-9, 0, 2e-9), 0.2);
  EXPECT_DOUBLE_EQ(grid_landing_probability(1e-9, 0, 2e-9), 1.0);
  EXPECT_DOUBLE_EQ(grid_landing_probability(0, 3e-9, 2e-9), landing_probability(0, 3e-9, 2e-9));
  EXPECT_EQ(grid_landing_probability(10e-9, 1e-9, 0), 0.0);
}

// Rungs drawn as a stage's fine rungs are: steps of 2-80 nm, a first cycle's offset of -1..+3
// steps, a scatter of 2-30 %.
std::vector<LandingRung> drawn_fine_rungs(std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(0, 1);
  std::vector<LandingRung> rungs(2 + rng() % 6);
  for (LandingRung& r : rungs) {
    r.direction = u(rng) < 0.5 ? -1 : 1;
    r.step_m = 1e-9 * (2 + 78 * u(rng));
    r.offset_m = r.step_m * (4 * u(rng) - 1);
    r.rel_sd = 0.02 + 0.28 * u(rng);
    r.rel_margin = 2 * r.rel_sd;
    r.freq_hz = 200 + 2000 * u(rng);
  }
  return rungs;
}

// What the header promises: optimistic. Over targets drawn anywhere in the final zone, the plan
// the landing plan chooses (one chunk or a vernier) lands on average no more often than one try
// of landing_reach; and the narrowest window it names is met, a narrower one not.
TEST(LandingReach, IsAnOptimisticBoundOfWhatThePlansLand) {
  const std::uint64_t s = seed();
  std::mt19937_64 rng(s);
  std::uniform_real_distribution<double> u(0, 1);
  for (int k = 0; k < 30; ++k) {
    const std::vector<LandingRung> rungs = drawn_fine_rungs(rng);
    LandingLimits lim;
    lim.half_window_m = 1e-9 * (0.05 + 3 * u(rng));
    lim.read_sd_m = 1e-9 * 0.3 * u(rng);
    lim.chunk_overhead_s = 5e-3;
    double finest = 1e300;
    for (const LandingRung& r : rungs) finest = std::min(finest, r.step_m);
    double sum = 0;
    const int targets = 400;
    for (int t = 0; t < targets; ++t) {
      const double error = (u(rng) < 0.5 ? -1 : 1) * finest * (0.5 + 10 * u(rng));
      sum += plan_landing(error, lim, rungs.data(), rungs.size()).probability;
    }
    const LandingReach reach = landing_reach(rungs.data(), rungs.size(), lim.half_window_m,
                                             lim.read_sd_m, lim.max_first_cycles, 11);
    // 400 targets: the mean's own scatter is under 0.025.
    EXPECT_LE(sum / targets, reach.try_probability + 0.03)
        << "seed " << s << " draw " << k << " window " << lim.half_window_m;
    EXPECT_NEAR(reach.arrival_probability, 1 - std::pow(1 - reach.try_probability, 11), 1e-12);
    const double least =
        least_half_window_m(rungs.data(), rungs.size(), lim.read_sd_m, lim.max_first_cycles, 11);
    ASSERT_GT(least, 0);
    EXPECT_TRUE(
        landing_reach(rungs.data(), rungs.size(), least, lim.read_sd_m, lim.max_first_cycles, 11)
            .reachable());
    EXPECT_FALSE(landing_reach(rungs.data(), rungs.size(), 0.98 * least, lim.read_sd_m,
                               lim.max_first_cycles, 11)
                     .reachable());
  }
}

TEST(LandingReach, AWindowFarNarrowerThanTheScatterIsUnreachableAndAWideOneIsNot) {
  // One rung: 20 nm a cycle, 10 % scatter: its shortest moving chunk (one cycle) scatters 2 nm.
  std::vector<LandingRung> rungs(1);
  rungs[0] = {.direction = 1, .step_m = 20e-9, .rel_sd = 0.1, .freq_hz = 1000};
  const auto reach = [&](double half) { return landing_reach(rungs.data(), 1, half, 0, 4, 11); };
  EXPECT_FALSE(reach(0.05e-9).reachable());              // a tenth of a nanometre wide
  EXPECT_TRUE(reach(10e-9).reachable());                 // half a step either side: every try lands
  EXPECT_NEAR(reach(10e-9).try_probability, 1.0, 5e-3);  // but for the scatter at the edges
  // A vernier needs a second rung; with the same rung's first chunks (1-4 cycles, four ends a
  // step apart) the grid it spreads over is a quarter of a step.
  EXPECT_GT(reach(1e-9).try_probability, grid_landing_probability(10e-9, 2e-9, 1e-9));
}

}  // namespace
}  // namespace idm::control
