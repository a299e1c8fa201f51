// The region map against model/ (Table 1, the paper's Fig. 4), the margin logic under the friction
// uncertainty, the device limits and the burst prediction.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>

#include "control/region_map.h"
#include "model/impulse_model.h"

using namespace idm;
using namespace idm::control;

namespace {

// The one-step set of the ideal model is one interval (lower, upper] of beta for every duty.
// duty < 0.5 (closed form, docs/model.md): one-step iff beta > (1-d) d^2 and, if beta > d^2,
// beta <= (1-d)(1-2d), else beta <= (1-d)^2 d. For d <= (3 - sqrt 5)/2 both (1-d)(1-2d) and
// (1-d)^2 d are >= d^2, so the set is ((1-d) d^2, (1-d)(1-2d)]; above it both are <= d^2 and the
// set is ((1-d) d^2, (1-d)^2 d].
// duty > 0.5, from the event simulation's definition (one-step = at rest at t = d T in the first
// cycle, and not cut-off in the steady cycle): the first slow extension gives the slider
// -beta/d (units of mu g T), which stops within d iff beta <= d^2; the steady cycle (mirror of
// 1 - d) is cut-off iff beta <= d (1-d)^2. So the set is (d (1-d)^2, d^2].
struct BetaInterval {
  double lower, upper;
};
BetaInterval one_step_interval(double d) {
  if (d < 0.5) {
    const double lower = (1 - d) * d * d;
    const double upper =
        d <= (3 - std::sqrt(5.0)) / 2 ? (1 - d) * (1 - 2 * d) : (1 - d) * (1 - d) * d;
    return {lower, upper};
  }
  return {d * (1 - d) * (1 - d), d * d};
}

// A config evaluated as given (no sample clock), for exact (f, duty) points.
RegionMapConfig parameter_device_config(double u) {
  RegionMapConfig c;
  c.limits.output_sample_rate_hz = 0;
  c.limits.max_freq_hz = 5000;
  c.friction_uncertainty = u;
  c.grid.freqs_hz = {100, 200};
  c.grid.duty_step = 0.1;
  c.grid.strokes_m = {c.stage.stroke_m};
  return c;
}

RegionMapConfig small_map_config(double u) {
  RegionMapConfig c;
  c.friction_uncertainty = u;
  c.limits.max_freq_hz = 1500;
  c.grid.freqs_hz = RegionGrid::frequency_steps(25, 1600, 25);  // the last ones above the limit
  c.grid.duty_step = 0.01;
  c.grid.strokes_m = {20.35e-6, 5e-6};
  return c;
}

// The frequency at which Table 1 at full stroke has impulse ratio beta.
double freq_for_beta(const model::StageParams& s, double beta) {
  return std::sqrt(beta / model::impulse_ratio(s, 1.0, s.stroke_m));
}

}  // namespace

TEST(RegionMap, Figure4CasesAtTable1) {
  const RegionMap map(parameter_device_config(0.15));
  struct Case {
    double duty, freq_hz, beta;
    model::Region region;
  };
  const Case cases[] = {
      {0.10, 200, 0.054, model::Region::OneStep},   {0.40, 200, 0.054, model::Region::Cutoff},
      {0.35, 600, 0.482, model::Region::MultiStep}, {0.47, 350, 0.164, model::Region::MultiStep},
      {0.40, 300, 0.121, model::Region::OneStep},
  };
  for (const Case& k : cases) {
    SCOPED_TRACE(::testing::Message() << "duty " << k.duty << " f " << k.freq_hz);
    const RegionCell c = map.at(k.freq_hz, k.duty, 20.35e-6);
    EXPECT_NEAR(c.beta, k.beta, 1e-3);
    EXPECT_EQ(c.region, k.region);
    EXPECT_EQ(c.region,
              model::region(model::impulse_ratio(map.config().stage, k.freq_hz, 20.35e-6), k.duty));
    EXPECT_DOUBLE_EQ(
        c.step_m, model::steady_step_corrected_m(map.config().stage, k.freq_hz, k.duty, 20.35e-6));
    EXPECT_EQ(c.robust_one_step, c.region == model::Region::OneStep);
  }
  // (0.10, 200 Hz) moves negative with about 0.35 * 0.258 * 20.35 um / 0.9 - ... < 2 um.
  const RegionCell a = map.at(200, 0.10, 20.35e-6);
  EXPECT_LT(a.step_m, -1e-6);
  EXPECT_EQ(a.direction(), -1);
  // Its mirror drives positive and is one-step (beta 0.054 in (0.9 * 0.01, 0.81]).
  const RegionCell mirror = map.at(200, 0.90, 20.35e-6);
  EXPECT_EQ(mirror.region, model::Region::OneStep);
  EXPECT_DOUBLE_EQ(mirror.step_m, -a.step_m);
  EXPECT_EQ(mirror.direction(), 1);
}

TEST(RegionMap, Figure4eIsRobustAt15PercentButNot20) {
  // (0.40, 300 Hz): beta 0.121 in (0.096, 0.144]: mu may rise by beta/0.096 - 1 = 26 % and fall
  // by 1 - beta/0.144 = 16 % before the cell leaves one-step.
  const double beta = model::impulse_ratio(model::StageParams{}, 300, 20.35e-6);
  const BetaInterval iv = one_step_interval(0.40);
  const RegionCell at15 = RegionMap(parameter_device_config(0.15)).at(300, 0.40, 20.35e-6);
  EXPECT_NEAR(at15.margin_mu_increase, beta / iv.lower - 1, 1e-9);
  EXPECT_NEAR(at15.margin_mu_decrease, 1 - beta / iv.upper, 1e-9);
  EXPECT_NEAR(at15.margin(), 0.16, 0.01);
  EXPECT_TRUE(at15.robust_one_step);
  const RegionCell at20 = RegionMap(parameter_device_config(0.20)).at(300, 0.40, 20.35e-6);
  EXPECT_EQ(at20.region, model::Region::OneStep);
  EXPECT_FALSE(at20.robust_one_step);
}

TEST(RegionMap, CellNearCutoffIsRobustAt1PercentNotAt15) {
  const model::StageParams table1;
  const double d = 0.10;
  const double f = freq_for_beta(table1, 1.05 * one_step_interval(d).lower);  // 5 % above cut-off
  const RegionCell loose = RegionMap(parameter_device_config(0.01)).at(f, d, table1.stroke_m);
  const RegionCell tight = RegionMap(parameter_device_config(0.15)).at(f, d, table1.stroke_m);
  EXPECT_EQ(loose.region, model::Region::OneStep);
  EXPECT_NEAR(loose.margin_mu_increase, 0.05, 1e-9);
  EXPECT_NEAR(tight.margin_mu_increase, 0.05, 1e-9);
  EXPECT_TRUE(loose.robust_one_step);
  EXPECT_FALSE(tight.robust_one_step);
  // 15 % more friction puts it in cut-off: the step there is 0.
  EXPECT_EQ(model::region(loose.beta / 1.15, d), model::Region::Cutoff);
  EXPECT_LT(tight.step_min_m, tight.step_m);
  EXPECT_LT(tight.step_m, 0.0);
  EXPECT_EQ(tight.step_max_m, 0.0);
}

TEST(RegionMap, CellNearMultiStepIsRobustAt1PercentNotAt15ForPositiveDuty) {
  const model::StageParams table1;
  const double d = 0.80;
  const double f = freq_for_beta(table1, 0.97 * one_step_interval(d).upper);  // 3 % below d^2
  const RegionCell loose = RegionMap(parameter_device_config(0.01)).at(f, d, table1.stroke_m);
  const RegionCell tight = RegionMap(parameter_device_config(0.15)).at(f, d, table1.stroke_m);
  EXPECT_EQ(loose.region, model::Region::OneStep);
  EXPECT_NEAR(loose.margin_mu_decrease, 0.03, 1e-9);
  EXPECT_TRUE(loose.robust_one_step);
  EXPECT_FALSE(tight.robust_one_step);
  EXPECT_GT(loose.step_m, 0);
  EXPECT_EQ(model::region(loose.beta / (1 - 0.15), d), model::Region::MultiStep);
}

TEST(RegionMap, EveryCellAgreesWithModelRegion) {
  const RegionMap map(small_map_config(0.15));
  const model::StageParams& s = map.config().stage;
  ASSERT_EQ(map.cells().size(),
            map.freqs_hz().size() * map.duties().size() * map.strokes_m().size());
  std::size_t reverse_checked = 0;
  for (const RegionCell& c : map.cells()) {
    const double beta = model::impulse_ratio(s, c.freq_hz, c.stroke_m);
    ASSERT_DOUBLE_EQ(c.beta, beta);
    ASSERT_EQ(c.region, model::region(beta, c.duty)) << c.freq_hz << " " << c.duty;
    ASSERT_DOUBLE_EQ(c.step_m, model::steady_step_corrected_m(s, c.freq_hz, c.duty, c.stroke_m));
    if (c.duty > 0.5) {
      ASSERT_EQ(c.region, model::region_by_event_simulation(beta, c.duty));
      ++reverse_checked;
    }
  }
  EXPECT_GT(reverse_checked, 1000u);
  // Every region occurs, in both directions.
  for (model::Region r : {model::Region::Cutoff, model::Region::OneStep, model::Region::MultiStep})
    EXPECT_GT(map.count(r), 100u) << model::region_name(r);
}

TEST(RegionMap, MarginsMatchTheOneStepInterval) {
  const RegionMap map(small_map_config(0.15));
  const double limit = map.config().margin_search_limit;
  std::size_t one_step = 0;
  for (const RegionCell& c : map.cells()) {
    if (c.region != model::Region::OneStep) {
      EXPECT_EQ(c.margin(), 0.0);
      EXPECT_FALSE(c.robust_one_step);
      continue;
    }
    ++one_step;
    const BetaInterval iv = one_step_interval(c.duty);
    ASSERT_GT(c.beta, iv.lower);
    ASSERT_LE(c.beta, iv.upper * (1 + 1e-12));
    SCOPED_TRACE(::testing::Message() << "f " << c.freq_hz << " duty " << c.duty);
    EXPECT_NEAR(c.margin_mu_increase, std::min(limit, c.beta / iv.lower - 1), 1e-9);
    EXPECT_NEAR(c.margin_mu_decrease, std::min(limit, 1 - c.beta / iv.upper), 1e-9);
  }
  EXPECT_GT(one_step, 1000u);
}

TEST(RegionMap, RobustMeansOneStepOverTheWholeFrictionInterval) {
  const double u = 0.15;
  const RegionMap map(small_map_config(u));
  std::size_t robust = 0, fragile = 0;
  for (const RegionCell& c : map.cells()) {
    if (c.robust_one_step) {
      ++robust;
      // Dense samples of mu over the interval: one-step everywhere.
      for (int i = 0; i <= 200; ++i) {
        const double e = -u + 2 * u * i / 200.0;
        ASSERT_EQ(model::region(c.beta / (1 + e), c.duty), model::Region::OneStep)
            << "f " << c.freq_hz << " duty " << c.duty << " mu change " << e;
      }
      const double lo = std::min(c.step_min_m, c.step_max_m);
      EXPECT_LE(c.step_min_m, c.step_m);
      EXPECT_GE(c.step_max_m, c.step_m);
      EXPECT_EQ(std::signbit(lo), std::signbit(c.step_m));
    } else if (c.region == model::Region::OneStep) {
      ++fragile;
      // One end of the interval leaves one-step (the set is an interval of beta).
      const bool leaves = model::region(c.beta / (1 + u), c.duty) != model::Region::OneStep ||
                          model::region(c.beta / (1 - u), c.duty) != model::Region::OneStep;
      EXPECT_TRUE(leaves) << "f " << c.freq_hz << " duty " << c.duty;
    }
  }
  EXPECT_GT(robust, 500u);
  EXPECT_GT(fragile, 100u);
}

TEST(RegionMap, StepRangeIsEq22AtTheEndsOfTheFrictionInterval) {
  const double u = 0.15;
  const RegionMap map(parameter_device_config(u));
  model::StageParams lo_mu = map.config().stage, hi_mu = map.config().stage;
  lo_mu.friction_coefficient *= 1 - u;
  hi_mu.friction_coefficient *= 1 + u;
  for (double d : {0.1, 0.2, 0.8, 0.9}) {
    const RegionCell c = map.at(200, d, 20.35e-6);
    ASSERT_TRUE(c.robust_one_step) << d;
    const double a = model::steady_step_corrected_m(lo_mu, 200, d, 20.35e-6);
    const double b = model::steady_step_corrected_m(hi_mu, 200, d, 20.35e-6);
    EXPECT_DOUBLE_EQ(c.step_min_m, std::min(a, b));
    EXPECT_DOUBLE_EQ(c.step_max_m, std::max(a, b));
    // Less friction, larger step (eq 22: the friction term works against the impulse).
    EXPECT_GT(std::fabs(a), std::fabs(b));
  }
}

TEST(RegionMap, BurstPredictionIsTheEventSimulationTimesAlpha) {
  const RegionMap map(small_map_config(0.15));
  const model::StageParams& s = map.config().stage;
  std::size_t checked = 0;
  for (std::size_t n = 0; n < map.usable_cells().size(); n += 37) {
    const RegionCell& c = map.cells()[map.usable_cells()[n]];
    for (int cycles = 1; cycles <= 4; ++cycles) {
      const double ideal = burst_displacement_ideal_m(s, c.freq_hz, c.duty, c.stroke_m, cycles);
      EXPECT_NEAR(c.burst_displacement_m(static_cast<std::uint64_t>(cycles)),
                  s.step_correction * ideal, 1e-15 + 1e-9 * std::fabs(ideal));
    }
    if (c.duty < 0.5) {
      // Independently: the burst ends at rest at N T (one-step), then the corner from the
      // retraction rate S/((1-d)T) to 0 gives the slider m/(M+m) times that, the way it moved.
      const model::TriangleWave w{c.freq_hz, c.duty, c.stroke_m, 3};
      const std::vector<double> x = model::cycle_end_positions_m(s, w);
      const double v = s.mass_ratio() * c.stroke_m / w.retraction_s();
      const double tail = -v * v / (2 * s.friction_decel_m_s2());
      EXPECT_NEAR(burst_displacement_ideal_m(s, c.freq_hz, c.duty, c.stroke_m, 3), x[2] + tail,
                  1e-15);
      EXPECT_NEAR(x[2] - x[1], model::steady_step_ideal_m(s, c.freq_hz, c.duty, c.stroke_m), 1e-15);
    }
    ++checked;
  }
  EXPECT_GT(checked, 20u);
}

TEST(RegionMap, DeviceLimitsAndSampleClock) {
  RegionMapConfig cfg = small_map_config(0.15);
  cfg.limits.max_burst_samples = 20001;
  const RegionMap map(cfg);
  const double rate = cfg.limits.output_sample_rate_hz;
  for (const RegionCell& c : map.cells()) {
    if (c.freq_hz > cfg.limits.max_freq_hz * (1 + 1e-12)) {
      EXPECT_TRUE(c.limit_violations & limit_violation::kFreqAboveMax);
      EXPECT_FALSE(c.usable());
      continue;
    }
    // Snapped: whole samples per period and per extension.
    ASSERT_EQ(c.limit_violations, 0u) << describe_limit_violations(c.limit_violations);
    EXPECT_NEAR(rate / c.freq_hz, c.period_samples, 1e-9);
    EXPECT_NEAR(c.duty * c.period_samples, c.extension_samples, 1e-9);
    EXPECT_EQ(c.max_cycles,
              std::min<std::uint64_t>(cfg.limits.max_burst_cycles, 20000 / c.period_samples));
  }
  for (std::size_t i : map.usable_cells()) EXPECT_TRUE(map.cells()[i].usable());
  // No waveform twice among the usable cells.
  for (std::size_t j = 1; j < map.usable_cells().size(); ++j) {
    for (std::size_t i = 0; i < j; i += 97) {
      const RegionCell& a = map.cells()[map.usable_cells()[i]];
      const RegionCell& b = map.cells()[map.usable_cells()[j]];
      EXPECT_FALSE(a.freq_hz == b.freq_hz && a.duty == b.duty && a.stroke_m == b.stroke_m);
    }
  }

  // 600 Hz is 166.67 samples at 100 kHz: off the clock as given; playable snaps it to 167.
  const RegionCell off = map.at(600, 0.3, 20.35e-6);
  EXPECT_TRUE(off.limit_violations & limit_violation::kOffSampleClock);
  EXPECT_EQ(describe_limit_violations(off.limit_violations), "off sample clock");
  const RegionCell snapped = map.playable(600, 0.3, 20.35e-6);
  EXPECT_EQ(snapped.period_samples, 167u);
  EXPECT_EQ(snapped.extension_samples, 50u);
  EXPECT_DOUBLE_EQ(snapped.freq_hz, rate / 167);
  EXPECT_DOUBLE_EQ(snapped.duty, 50.0 / 167);
  EXPECT_EQ(snapped.limit_violations, 0u);
  // Stroke outside the device's range, frequency above its maximum.
  const RegionCell far = map.at(2000, 0.2, 30e-6);
  EXPECT_TRUE(far.limit_violations & limit_violation::kStrokeOutOfRange);
  EXPECT_TRUE(far.limit_violations & limit_violation::kFreqAboveMax);
  EXPECT_FALSE(far.usable());
  // A burst longer than the device holds: one cycle of 10 Hz needs 10001 samples (with the final
  // 0), one of 20 Hz 5001.
  cfg.limits.max_burst_samples = 5001;
  cfg.limits.min_freq_hz = 5;
  cfg.grid.freqs_hz = {10, 20};
  const RegionMap tiny(cfg);
  const RegionCell slow = tiny.at(10, 0.1, 20.35e-6);
  EXPECT_TRUE(slow.limit_violations & limit_violation::kBurstTooLong);
  EXPECT_EQ(tiny.at(20, 0.1, 20.35e-6).max_cycles, 1u);
}

TEST(RegionMap, SnapToSampleClock) {
  const ClockedWave w = snap_to_sample_clock(1e5, 333, 0.1);
  EXPECT_EQ(w.period_samples, 300u);
  EXPECT_EQ(w.extension_samples, 30u);
  EXPECT_DOUBLE_EQ(w.freq_hz, 1e5 / 300);
  EXPECT_DOUBLE_EQ(w.duty, 0.1);
  // The extension keeps at least one sample and leaves one for the retraction.
  EXPECT_EQ(snap_to_sample_clock(1e5, 10000, 0.01).extension_samples, 1u);
  EXPECT_EQ(snap_to_sample_clock(1e5, 10000, 0.99).extension_samples, 9u);
}

TEST(RegionMap, GridHelpers) {
  const auto f = RegionGrid::frequency_steps(50, 200, 50);
  EXPECT_EQ(f, (std::vector<double>{50, 100, 150, 200}));
  const auto s = RegionGrid::stroke_steps(1e-6, 8e-6, 4);
  ASSERT_EQ(s.size(), 4u);
  EXPECT_DOUBLE_EQ(s[0], 8e-6);
  EXPECT_DOUBLE_EQ(s[1], 4e-6);
  EXPECT_DOUBLE_EQ(s[2], 2e-6);
  EXPECT_DOUBLE_EQ(s[3], 1e-6);
  RegionGrid g;
  g.duty_step = 0.1;
  const auto d = g.duties();
  ASSERT_EQ(d.size(), 8u);  // 0.1 .. 0.9 without 0.5
  EXPECT_TRUE(std::none_of(d.begin(), d.end(), [](double x) { return std::fabs(x - 0.5) < 1e-9; }));
  DeviceLimits lim;
  lim.max_freq_hz = 1000;
  const RegionGrid cover = RegionGrid::covering(lim, 100, 0.01, 3);
  EXPECT_EQ(cover.freqs_hz.front(), 100);
  EXPECT_EQ(cover.freqs_hz.back(), 1000);
  EXPECT_EQ(cover.strokes_m.size(), 3u);
  EXPECT_DOUBLE_EQ(cover.strokes_m.back(), lim.min_stroke_m);
}

TEST(RegionMap, BadConfigNamesTheKey) {
  auto message_of = [](const RegionMapConfig& c) -> std::string {
    try {
      RegionMap map(c);
    } catch (const model::InputError& e) {
      return e.what();
    }
    return "";
  };
  RegionMapConfig c = parameter_device_config(0.15);
  c.friction_uncertainty = -0.1;
  EXPECT_NE(message_of(c).find("region_map.friction_uncertainty: -0.1"), std::string::npos)
      << message_of(c);
  c = parameter_device_config(0.6);
  EXPECT_NE(message_of(c).find("friction_uncertainty"), std::string::npos);
  c = parameter_device_config(0.15);
  c.grid.freqs_hz.clear();
  EXPECT_NE(message_of(c).find("region_map.grid.freqs_hz: empty"), std::string::npos);
  c = parameter_device_config(0.15);
  c.limits.max_stroke_m = 0.5e-6;
  EXPECT_NE(message_of(c).find("region_map.limits.max_stroke_m"), std::string::npos);
  c = parameter_device_config(0.15);
  c.limits.output_sample_rate_hz = 3000;  // below twice the 5 kHz limit
  EXPECT_NE(message_of(c).find("output_sample_rate_hz"), std::string::npos);
  c = parameter_device_config(0.15);
  c.stage.friction_coefficient = 0;
  EXPECT_NE(message_of(c).find("region_map.stage"), std::string::npos) << message_of(c);
}
