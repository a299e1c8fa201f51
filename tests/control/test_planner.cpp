// The planner: a property test over random targets and random plausible stages (every burst from a
// robustly one-step cell within the device limits, the prediction within the final step of the
// target), fewest cycles, direction, resolution and limits.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <random>
#include <string>

#include "control/planner.h"
#include "model/impulse_model.h"

using namespace idm;
using namespace idm::control;

namespace {

RegionMapConfig table1_config(double u) {
  RegionMapConfig c;
  c.friction_uncertainty = u;
  c.limits.max_freq_hz = 2000;
  c.limits.min_stroke_m = 1e-6;
  c.limits.max_stroke_m = 20.35e-6;
  c.grid = RegionGrid::covering(c.limits, 20, 0.01, 4);
  return c;
}

// Independent of the map: every burst is playable by the device and one-step for every mu of the
// stated interval (201 samples); the prediction is the event simulation times alpha.
void check_burst(const RegionMapConfig& cfg, const Burst& b, int sign) {
  const DeviceLimits& lim = cfg.limits;
  EXPECT_GE(b.freq_hz, lim.min_freq_hz * (1 - 1e-12));
  EXPECT_LE(b.freq_hz, lim.max_freq_hz * (1 + 1e-12));
  EXPECT_GE(b.stroke_m, lim.min_stroke_m * (1 - 1e-12));
  EXPECT_LE(b.stroke_m, lim.max_stroke_m * (1 + 1e-12));
  EXPECT_GE(b.cycles, 1u);
  EXPECT_LE(b.cycles, lim.max_burst_cycles);
  if (lim.output_sample_rate_hz > 0) {
    EXPECT_NEAR(lim.output_sample_rate_hz / b.freq_hz, b.period_samples, 1e-9);
    EXPECT_NEAR(b.duty * b.period_samples, b.extension_samples, 1e-9);
    if (lim.max_burst_samples > 0) {
      EXPECT_LE(b.cycles * b.period_samples + 1, lim.max_burst_samples);
    }
  }
  // duty > 0.5 drives positive.
  EXPECT_EQ(b.duty > 0.5, sign > 0) << "duty " << b.duty;
  EXPECT_EQ(b.step_m > 0, sign > 0);
  const model::StageParams& s = cfg.stage;
  const double u = cfg.friction_uncertainty;
  const double beta = model::impulse_ratio(s, b.freq_hz, b.stroke_m);
  for (int i = 0; i <= 200; ++i) {
    const double mu_change = -u + 2 * u * i / 200.0;
    ASSERT_EQ(model::region(beta / (1 + mu_change), b.duty), model::Region::OneStep)
        << "f " << b.freq_hz << " duty " << b.duty << " stroke " << b.stroke_m << " mu change "
        << mu_change;
  }
  const double ideal =
      burst_displacement_ideal_m(s, b.freq_hz, b.duty, b.stroke_m, static_cast<int>(b.cycles));
  EXPECT_NEAR(b.displacement_m, s.step_correction * ideal, 1e-15 + 1e-9 * std::fabs(ideal));
}

// Whether some usable cell moving `sign` has a burst of N >= 1 cycles that comes closer than
// `distance` (> 0) to the target; only cells with |step| <= max_step_m count.
bool some_burst_comes_closer(const Planner& planner, int sign, double distance, double max_step_m) {
  for (std::size_t i : planner.map().usable_cells()) {
    const RegionCell& c = planner.map().cells()[i];
    if (c.direction() != sign || std::fabs(c.step_m) > max_step_m) continue;
    for (std::uint64_t n = 1; n <= std::min<std::uint64_t>(c.max_cycles, 64); ++n) {
      const double d = sign * c.burst_displacement_m(n);
      if (d > 0 && d < 2 * distance * (1 - 1e-12)) return true;
    }
  }
  return false;
}

void check_plan(const Planner& planner, const Plan& p) {
  const RegionMapConfig& cfg = planner.map().config();
  double remaining = p.target_m;
  double before_last = p.target_m;
  double sum = 0;
  for (const Burst& b : p.bursts) {
    const RegionCell& c = planner.map().cells().at(b.cell_index);
    EXPECT_TRUE(c.usable());
    EXPECT_EQ(c.freq_hz, b.freq_hz);
    EXPECT_EQ(c.duty, b.duty);
    EXPECT_EQ(c.stroke_m, b.stroke_m);
    check_burst(cfg, b, remaining > 0 ? 1 : -1);
    before_last = remaining;
    sum += b.displacement_m;
    remaining = p.target_m - sum;
  }
  EXPECT_NEAR(p.predicted_m, sum, 1e-18);
  EXPECT_TRUE(p.within_final_step()) << "target " << p.target_m << " predicted " << p.predicted_m
                                     << " final step " << p.final_step_m;
  const int sign = p.target_m > 0 ? 1 : -1;
  if (!p.bursts.empty()) {
    // The last burst steps no more than the final class allows (the resolution where possible),
    // unless no burst of the final class would have come closer.
    const int last_sign = p.bursts.back().step_m > 0 ? 1 : -1;
    const double bound = planner.final_step_bound_m(last_sign);
    if (std::fabs(p.bursts.back().step_m) > bound * (1 + 1e-12)) {
      EXPECT_FALSE(some_burst_comes_closer(planner, last_sign, std::fabs(before_last), bound))
          << "last step " << p.bursts.back().step_m << " above the final class " << bound;
    } else if (planner.finest_step_m(last_sign) <= planner.config().resolution_m) {
      EXPECT_LE(std::fabs(p.bursts.back().step_m), planner.config().resolution_m);
    }
    // The first burst heads for the target.
    EXPECT_EQ(p.bursts.front().duty > 0.5, sign > 0);
  } else if (std::fabs(p.target_m) > 0.5 * planner.final_step_bound_m(sign)) {
    // Nothing to do is only right when no usable burst would come closer.
    EXPECT_FALSE(some_burst_comes_closer(planner, sign, std::fabs(p.target_m), 1.0));
  }
}

// A plausible stage and device, drawn from `rng`.
RegionMapConfig random_config(std::mt19937_64& rng) {
  auto uniform = [&rng](double lo, double hi) {
    return std::uniform_real_distribution<double>(lo, hi)(rng);
  };
  RegionMapConfig c;
  c.stage.slider_mass_kg = uniform(0.05, 0.5);
  c.stage.counter_mass_kg = uniform(0.01, 0.2);
  c.stage.friction_coefficient = uniform(0.2, 0.6);
  c.stage.stroke_m = uniform(5e-6, 30e-6);
  c.stage.step_correction = uniform(0.2, 0.6);
  c.friction_uncertainty = uniform(0.05, 0.2);
  const double max_freqs[] = {1000, 2000, 3000};
  const double clocks[] = {0, 1e5, 2.5e5};
  c.limits.max_freq_hz = max_freqs[rng() % 3];
  c.limits.output_sample_rate_hz = clocks[rng() % 3];
  c.limits.min_freq_hz = 10;
  c.limits.max_stroke_m = c.stage.stroke_m;
  c.limits.min_stroke_m = c.stage.stroke_m / 8;
  c.limits.max_burst_cycles = (rng() % 2) ? 1000000 : 500;
  c.grid = RegionGrid::covering(c.limits, 20, 0.01, 3);
  return c;
}

}  // namespace

TEST(Planner, PropertyEveryBurstRobustWithinLimitsAndPredictionWithinFinalStep) {
  std::mt19937_64 rng(20110066);
  std::size_t plans = 0, bursts = 0, empty = 0;
  for (int stage = 0; stage < 24; ++stage) {
    const RegionMapConfig cfg = random_config(rng);
    SCOPED_TRACE(::testing::Message()
                 << "stage " << stage << ": M " << cfg.stage.slider_mass_kg << " m "
                 << cfg.stage.counter_mass_kg << " mu " << cfg.stage.friction_coefficient << " S "
                 << cfg.stage.stroke_m << " alpha " << cfg.stage.step_correction << " u "
                 << cfg.friction_uncertainty << " fmax " << cfg.limits.max_freq_hz << " clock "
                 << cfg.limits.output_sample_rate_hz);
    const RegionMap map(cfg);
    const Planner planner(map);
    ASSERT_GT(planner.largest_step_m(1), 0);
    ASSERT_GT(planner.largest_step_m(-1), 0);
    for (int k = 0; k < 80; ++k) {
      const double magnitude =
          std::pow(10.0, std::uniform_real_distribution<double>(-8, std::log10(5e-3))(rng));
      const double target = (rng() % 2 ? 1 : -1) * magnitude;
      SCOPED_TRACE(::testing::Message() << "target " << target);
      const Plan p = planner.plan(target);
      check_plan(planner, p);
      // Deterministic.
      const Plan again = planner.plan(target);
      ASSERT_EQ(again.bursts.size(), p.bursts.size());
      for (std::size_t i = 0; i < p.bursts.size(); ++i) {
        EXPECT_EQ(again.bursts[i].cell_index, p.bursts[i].cell_index);
        EXPECT_EQ(again.bursts[i].cycles, p.bursts[i].cycles);
      }
      ++plans;
      bursts += p.bursts.size();
      empty += p.bursts.empty();
    }
  }
  EXPECT_EQ(plans, 24u * 80u);
  EXPECT_GT(bursts, 2 * plans);
  EXPECT_LT(empty, plans / 10);
}

TEST(Planner, FewestCyclesForALongMove) {
  const RegionMap map(table1_config(0.15));
  const Planner planner(map);
  const double target = 100e-6;
  const Plan p = planner.plan(target);
  check_plan(planner, p);
  const double largest = planner.largest_step_m(1);
  ASSERT_GT(largest, 1.5e-6);  // about alpha m S / ((M+m)(1-d)) at Table 1
  ASSERT_GE(p.bursts.size(), 2u);
  // The bulk is done with (nearly) the largest safe step ...
  EXPECT_GE(p.bursts.front().step_m, 0.95 * largest);
  EXPECT_GT(p.bursts.front().displacement_m, 0.9 * target);
  // ... so the cycles are close to the lower bound target / largest step.
  const auto bound = static_cast<std::uint64_t>(std::ceil(target / largest));
  EXPECT_GE(p.total_cycles() + 1, bound);
  EXPECT_LE(p.total_cycles(), bound + planner.config().final_approach_steps + 4);
  // Finer steps as the target nears: no later burst steps more than the first.
  for (const Burst& b : p.bursts) EXPECT_LE(b.step_m, p.bursts.front().step_m);
  EXPECT_LT(p.bursts.back().step_m, 0.05 * largest);
}

TEST(Planner, DutyAboveHalfForPositiveBelowForNegative) {
  const RegionMap map(table1_config(0.15));
  const Planner planner(map);
  for (double target : {3e-7, 2e-6, 4.2e-5, 1e-3}) {
    const Plan up = planner.plan(target);
    const Plan down = planner.plan(-target);
    ASSERT_FALSE(up.bursts.empty());
    ASSERT_FALSE(down.bursts.empty());
    EXPECT_GT(up.bursts.front().duty, 0.5);
    EXPECT_GT(up.bursts.front().displacement_m, 0);
    EXPECT_LT(down.bursts.front().duty, 0.5);
    EXPECT_LT(down.bursts.front().displacement_m, 0);
    check_plan(planner, up);
    check_plan(planner, down);
  }
}

TEST(Planner, LastBurstStepsWithinTheResolutionWhereTheMapAllowsIt) {
  // With 1 % friction uncertainty and strokes down to 0.5 um the map holds steps below one count.
  RegionMapConfig cfg = table1_config(0.01);
  cfg.limits.min_stroke_m = 0.5e-6;
  cfg.grid = RegionGrid::covering(cfg.limits, 20, 0.01, 5);
  const RegionMap map(cfg);
  const Planner planner(map);
  const double count = planner.config().resolution_m;
  ASSERT_LT(planner.finest_step_m(1), count);
  ASSERT_LT(planner.finest_step_m(-1), count);
  for (double target : {-3.7e-8, 1e-7, 1.234e-6, -5.5e-5, 2e-3}) {
    const Plan p = planner.plan(target);
    check_plan(planner, p);
    ASSERT_FALSE(p.bursts.empty());
    EXPECT_LE(std::fabs(p.bursts.back().step_m), count);
    EXPECT_LE(std::fabs(p.residual_m()), 0.5 * count) << target;
  }
  // At 15 % the finest robust step is far above one count: the last burst uses the finest class.
  const RegionMap coarse_map(table1_config(0.15));
  const Planner coarse(coarse_map);
  EXPECT_GT(coarse.finest_step_m(1), count);
  const Plan p = coarse.plan(1.234e-6);
  check_plan(coarse, p);
  EXPECT_LE(p.bursts.back().step_m, coarse.config().final_class_slack * coarse.finest_step_m(1));
}

TEST(Planner, TargetWithinHalfTheFinestStepNeedsNoBurst) {
  const RegionMap map(table1_config(0.15));
  const Planner planner(map);
  const double tiny = 0.4 * planner.final_step_bound_m(1);
  const Plan p = planner.plan(tiny);
  EXPECT_TRUE(p.bursts.empty());
  EXPECT_EQ(p.predicted_m, 0.0);
  EXPECT_TRUE(p.within_final_step());
  EXPECT_TRUE(planner.plan(0.0).bursts.empty());
}

TEST(Planner, RespectsTheBurstLengthLimit) {
  RegionMapConfig cfg = table1_config(0.15);
  cfg.limits.max_burst_samples = 50 * 200 + 1;  // 50 cycles of 500 Hz
  const RegionMap map(cfg);
  const Planner planner(map);
  const Plan p = planner.plan(-2e-3);
  check_plan(planner, p);
  EXPECT_GT(p.bursts.size(), 5u);
  for (const Burst& b : p.bursts)
    EXPECT_LE(b.cycles * b.period_samples + 1, cfg.limits.max_burst_samples);
}

TEST(Planner, NoUsableCellsGivesAnEmptyPlanThatDoesNotReach) {
  // At 3 kHz and full stroke Table 1 has beta 11.9: multi-step at every duty.
  RegionMapConfig cfg = table1_config(0.15);
  cfg.limits.max_freq_hz = 5000;
  cfg.limits.output_sample_rate_hz = 1e6;
  cfg.grid.freqs_hz = {3000, 4000};
  cfg.grid.strokes_m = {20.35e-6};
  const RegionMap map(cfg);
  ASSERT_TRUE(map.usable_cells().empty());
  const Planner planner(map);
  const Plan p = planner.plan(1e-6);
  EXPECT_TRUE(p.bursts.empty());
  EXPECT_EQ(p.final_step_m, 0.0);
  EXPECT_FALSE(p.within_final_step());
}

TEST(Planner, PlanReusesItsStorage) {
  const RegionMap map(table1_config(0.15));
  const Planner planner(map);
  Plan p;
  planner.plan(1e-3, p);
  const std::size_t capacity = p.bursts.capacity();
  const Burst* data = p.bursts.data();
  planner.plan(-2e-6, p);
  EXPECT_LE(p.bursts.size(), capacity);
  EXPECT_EQ(p.bursts.data(), data);
  EXPECT_EQ(p.target_m, -2e-6);
  check_plan(planner, p);
}

TEST(Planner, BadConfigNamesTheKey) {
  const RegionMap map(table1_config(0.15));
  PlannerConfig c;
  c.resolution_m = 0;
  try {
    Planner planner(map, c);
    FAIL() << "accepted resolution_m = 0";
  } catch (const model::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("planner.resolution_m: 0"), std::string::npos) << e.what();
  }
  c = PlannerConfig{};
  c.final_approach_steps = 1;
  EXPECT_THROW(Planner(map, c), model::InputError);
}
