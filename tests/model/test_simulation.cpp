// The simulated stage: effect library, sim: config, bursts, sensor, and the effects' signatures as
// seen on the slider.
#include <gtest/gtest.h>

#include <cmath>

#include "model/impulse_model.h"
#include "model/simulation.h"

using namespace idm::model;

namespace {
std::string error_of(const std::string& yaml) {
  try {
    parse_sim_yaml(YAML::Load(yaml)["sim"], "idmd.yaml");
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

// Steady step (mean of cycle steps 4..N) of a burst on a simulated stage.
double steady_step(const SimConfig& c, double f, double duty, const StageParams& s = {},
                   double x0 = 0.0) {
  InterferometerParams ifm;
  ifm.resolution_m = 1e-12;
  SimulatedStage stage(s, ifm, c);
  stage.reset(x0, 1);
  TriangleWave w{f, duty, s.stroke_m, 10};
  TrialSamples out;
  const double rate = 100e3;
  stage.run_burst(w, rate, 0, 3 * w.period_s(), out);
  auto at = [&](double t) { return out.x_m[static_cast<std::size_t>(std::lround(t * rate))]; };
  return (at(10 * w.period_s()) - at(4 * w.period_s())) / 6.0;
}
}  // namespace

TEST(EffectLibrary, NamesAndParametersAreThoseOfTheGapReport) {
  const char* names[] = {"amplifier", "actuator_compliance", "hysteresis", "creep",
                         "stribeck",  "friction_spread",     "tilt",       "quantization"};
  ASSERT_EQ(effect_library().size(), 8u);
  for (std::size_t i = 0; i < 8; ++i) EXPECT_STREQ(effect_library()[i].name, names[i]);
  const EffectSpec a = parse_effect_arg("amplifier:cutoff_hz=2500,order=1");
  EXPECT_EQ(a.params.at("cutoff_hz"), 2500);
  EXPECT_EQ(a.params.at("order"), 1);
  EXPECT_EQ(a.params.at("slew_rate_m_s"), 0);  // default
}

TEST(EffectLibrary, BadEffectArgumentsNameTheKeyAndRange) {
  auto err = [](const std::string& arg) {
    try {
      parse_effect_arg(arg);
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_NE(err("wobble").find("unknown effect 'wobble', allowed amplifier, actuator_compliance"),
            std::string::npos);
  EXPECT_NE(
      err("amplifier:cutof_hz=3")
          .find("amplifier.cutof_hz: unknown parameter, allowed order, cutoff_hz, slew_rate_m_s"),
      std::string::npos);
  EXPECT_NE(err("amplifier:order=3").find("amplifier.order: 3 is out of range, allowed [1, 2]"),
            std::string::npos);
  EXPECT_NE(err("tilt:angle_deg=nan").find("tilt.angle_deg"), std::string::npos);
  EXPECT_NE(err("tilt:angle_deg").find("is not key=value"), std::string::npos);
}

TEST(SimConfig, ParsesTheSimSectionAndRejectsUnknownKeys) {
  const SimConfig c = parse_sim_yaml(YAML::Load(R"(
plant: mck
seed: 7
noise_m: 2e-9
effects:
  amplifier: {cutoff_hz: 3000, order: 2}
  stribeck: {static_over_kinetic: 1.15}
)"),
                                     "x.yaml");
  EXPECT_EQ(c.plant, PlantKind::MassDamperSpring);
  EXPECT_EQ(c.seed, 7u);
  EXPECT_DOUBLE_EQ(c.noise_m, 2e-9);
  ASSERT_TRUE(c.has("stribeck"));
  EXPECT_DOUBLE_EQ(c.find("stribeck")->params.at("stribeck_velocity_m_s"), 1e-3);
  EXPECT_EQ(error_of("sim:\n  plant: rigid\n  wobble: 1\n"),
            "idmd.yaml:3: sim.wobble: unknown key, allowed plant, effects, seed, noise_m, "
            "internal_rate_hz, "
            "start_position_m, end_stops_m, reference_mark_m");
  EXPECT_NE(error_of("sim:\n  effects:\n    tilt: {angle_deg: 90}\n").find("idmd.yaml:3"),
            std::string::npos);
  EXPECT_NE(error_of("sim:\n  plant: impulse\n  effects:\n    tilt: {}\n").find("takes no effects"),
            std::string::npos);
  EXPECT_NE(
      error_of("sim:\n  plant: magic\n").find("idmd.yaml:2: sim.plant: unknown plant 'magic'"),
      std::string::npos);
}

TEST(SimulatedStage, IdealBurstMatchesTheImpulseModel) {
  const StageParams s;
  for (double duty : {0.13, 0.33, 0.67, 0.87}) {
    SimConfig c;
    InterferometerParams ifm;
    ifm.resolution_m = 1e-15;
    SimulatedStage stage(s, ifm, c);
    stage.reset(0.0, 1);
    TriangleWave w{250.0, duty, s.stroke_m, 4};  // duty corners off the 20 kHz grid: exact anyway
    TrialSamples out;
    stage.run_burst(w, 20e3, 1e-3, 0.0, out);
    const auto ref = cycle_end_positions_m(s, w);
    ASSERT_EQ(out.t_s.back(), 16e-3);
    EXPECT_NEAR(out.x_m.back(), ref.back(), 1e-12) << duty;
    EXPECT_EQ(out.t_s.front(), -1e-3);
    EXPECT_EQ(out.t_s[20], 0.0);
  }
}

TEST(SimulatedStage, SensorQuantizesAndAddsSeededNoise) {
  const StageParams s;
  InterferometerParams ifm;  // 9.8906 nm
  SimConfig c;
  c.noise_m = 2e-9;
  SimulatedStage a(s, ifm, c), b(s, ifm, c);
  a.reset(0.0123456, 5);
  b.reset(0.0123456, 5);
  double sum = 0, sum2 = 0;
  for (int i = 0; i < 2000; ++i) {
    const double va = a.measured_m(), vb = b.measured_m();
    EXPECT_EQ(va, vb);  // seeded
    const double counts = va / ifm.resolution_m;
    EXPECT_NEAR(counts, std::round(counts), 1e-6);
    sum += va;
    sum2 += va * va;
  }
  const double mean = sum / 2000;
  EXPECT_NEAR(mean, 0.0123456, ifm.resolution_m);
}

// The signatures the gap diagnosis relies on, seen on the slider's steady step.
// A finite bandwidth turns each corner's impulse into a force over ~1/cutoff, during which friction
// takes its share: every step shrinks, and most where the phase is not much longer than 1/cutoff.
TEST(EffectSignatures, AmplifierShrinksSteps) {
  SimConfig base, amp;
  amp.effects.push_back(parse_effect_arg("amplifier:cutoff_hz=3000,order=2"));
  const double r100 = steady_step(amp, 100, 0.1) / steady_step(base, 100, 0.1);
  const double r600 = steady_step(amp, 600, 0.1) / steady_step(base, 600, 0.1);
  const double r800 = steady_step(amp, 800, 0.05) / steady_step(base, 800, 0.05);
  EXPECT_LT(r100, 0.95);
  EXPECT_LT(r600, 0.98);
  EXPECT_LT(r800, 0.98);
  EXPECT_GT(r100, 0.0);
}

TEST(EffectSignatures, ComplianceChangesTheStep) {
  SimConfig rigid, mck;
  mck.plant = PlantKind::MassDamperSpring;
  const double r = steady_step(rigid, 200, 0.1), c = steady_step(mck, 200, 0.1);
  EXPECT_LT(r, 0);
  EXPECT_GT(std::fabs(c - r), 0.02 * std::fabs(r));
}

TEST(EffectSignatures, StribeckChangesTheStep) {
  SimConfig base, strib;
  strib.effects.push_back(
      parse_effect_arg("stribeck:static_over_kinetic=1.5,stribeck_velocity_m_s=1e-3"));
  // more friction at low speed: the slow forward slide after the corner is cut short
  const double b = steady_step(base, 200, 0.1), st = steady_step(strib, 200, 0.1);
  EXPECT_GT(std::fabs(st - b), 0.005 * std::fabs(b));
}

TEST(EffectSignatures, TiltMakesDirectionsAsymmetric) {
  SimConfig base, tilt;
  tilt.effects.push_back(parse_effect_arg("tilt:angle_deg=2"));
  EXPECT_NEAR(steady_step(base, 200, 0.9), -steady_step(base, 200, 0.1), 1e-12);
  EXPECT_LT(steady_step(tilt, 200, 0.9), -steady_step(tilt, 200, 0.1) - 1e-8);
}

TEST(EffectSignatures, FrictionSpreadVariesTheStepAlongTheGuide) {
  SimConfig spread;
  spread.effects.push_back(parse_effect_arg("friction_spread:relative_sd=0.15"));
  double lo = 1, hi = -1;
  for (int i = 0; i < 10; ++i) {
    const double step = steady_step(spread, 300, 0.25, {}, i * 4e-3);
    lo = std::min(lo, step);
    hi = std::max(hi, step);
  }
  EXPECT_GT(hi - lo, 0.1 * std::fabs(lo));
}

TEST(EffectSignatures, HysteresisAndCreepAndDacChangeTheStep) {
  const double base = steady_step(SimConfig{}, 200, 0.1);
  for (const char* e : {"hysteresis:ratio=0.15", "creep:per_decade=0.05",
                        "quantization:bits=6,update_rate_hz=20000"}) {
    SimConfig c;
    c.effects.push_back(parse_effect_arg(e));
    EXPECT_GT(std::fabs(steady_step(c, 200, 0.1) - base), 0.005 * std::fabs(base)) << e;
  }
}
