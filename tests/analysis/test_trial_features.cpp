// Trial features on simulated trials (where the truth is known) and on the shared sample sweep.
#include <gtest/gtest.h>

#include <cmath>

#include "analysis/trial_features.h"
#include "model/simulation.h"

using namespace idm;
using namespace idm::analysis;

namespace {
TrialSeries simulate(const model::TriangleWave& w, double rate_hz, double noise_m,
                     std::uint64_t seed) {
  model::SimConfig c;
  c.noise_m = noise_m;
  model::StageParams s;
  model::InterferometerParams ifm;  // 9.8906 nm
  model::SimulatedStage stage(s, ifm, c);
  stage.reset(0.0123, seed);
  model::TrialSamples out;
  stage.run_burst(w, rate_hz, 0.5e-3, 2 * w.period_s(), out);
  TrialSeries t;
  t.t_s = out.t_s;
  t.xi_cmd_m = out.xi_cmd_m;
  t.x_m = out.x_m;
  return t;
}

bool robust(double beta, double duty) {
  return model::region(beta * 0.97, duty) == model::region(beta, duty) &&
         model::region(beta * 1.03, duty) == model::region(beta, duty);
}
}  // namespace

TEST(TrialFeatures, IdealTrialsShowTheModelsRegionAndStep) {
  const model::StageParams s;
  int checked = 0;
  for (double f : {100.0, 200.0, 350.0, 500.0, 700.0})
    for (double duty : {0.05, 0.15, 0.3, 0.45, 0.55, 0.7, 0.85, 0.95}) {
      const double beta = model::impulse_ratio(s, f, s.stroke_m);
      if (!robust(beta, duty)) continue;
      for (double rate : {20e3, 137e3}) {  // any sample rate, corners off the grid
        const model::TriangleWave w{f, duty, s.stroke_m, 12};
        TrialInfo info;
        info.id = "t";
        info.freq_hz = f;
        info.duty = duty;
        info.stroke_m = s.stroke_m;
        info.cycles = 12;
        info.sample_rate_hz = rate;
        const TrialFeatures tf = trial_features(info, simulate(w, rate, 2e-9, 7), 9.8906e-9, 2e-9);
        const model::Region expect = model::region(beta, duty);
        EXPECT_EQ(tf.region, expect) << f << " Hz duty " << duty << " rate " << rate;
        if (expect == model::Region::OneStep) {
          EXPECT_NEAR(tf.steady_step_m, model::steady_step_ideal_m(s, f, duty, s.stroke_m), 15e-9)
              << f << " " << duty;
        }
        ++checked;
      }
    }
  EXPECT_GT(checked, 40);
}

TEST(TrialFeatures, ReverseMotionOfAFirstCycle) {
  // 300 Hz duty 0.35 (one-step): the first cycle ends 3.5 um on the positive side (reference row)
  const model::StageParams s;
  const model::TriangleWave w{300, 0.35, s.stroke_m, 12};
  TrialInfo info{"t", 300, 0.35, s.stroke_m, 12, 50e3, 0, "x"};
  const TrialFeatures tf = trial_features(info, simulate(w, 50e3, 0, 1), 9.8906e-9, 0);
  EXPECT_LT(tf.steady_step_m, 0);
  EXPECT_GT(tf.reverse_m, 3e-6);
  EXPECT_NEAR(tf.first_step_m, 3.53451366e-06, 10e-9);
}

TEST(TrialFeatures, ATrialThatDoesNotCoverItsBurstIsAnError) {
  TrialSeries t;
  t.t_s = {0, 1e-3};
  t.xi_cmd_m = {0, 0};
  t.x_m = {0, 0};
  TrialInfo info{"short", 100, 0.1, 2e-5, 12, 1000, 0, "x"};
  EXPECT_THROW(trial_features(info, t, 1e-8, 0), InputError);
}

TEST(TrialFeatures, MajorityVote) {
  using model::Region;
  EXPECT_EQ(majority_region({Region::OneStep, Region::OneStep, Region::MultiStep}),
            Region::OneStep);
  EXPECT_EQ(majority_region({Region::Cutoff, Region::MultiStep}), Region::MultiStep);
}

// The sample sweep (tests/data/README.md: an amplifier at 3.5 kHz): at 100 Hz the stage follows
// the impulse model.
TEST(TrialFeatures, SampleSweepAtLowFrequencyFollowsTheModel) {
  const Dataset ds = recording::read_dataset(IDM_SAMPLE_SWEEP_DIR);
  const model::StageParams& s = ds.stage.stage;
  int checked = 0;
  for (std::size_t i = 0; i < ds.trials.size(); ++i) {
    const TrialInfo& info = ds.trials[i];
    if (info.freq_hz != 100 || info.stroke_m < 2e-5) continue;
    const TrialFeatures tf =
        trial_features(info, read_trial(ds, i), ds.stage.interferometer.resolution_m, 3e-9);
    const double beta = model::impulse_ratio(s, info.freq_hz, info.stroke_m);
    if (!robust(beta, info.duty)) continue;
    EXPECT_EQ(tf.region, model::region(beta, info.duty)) << info.id;
    ++checked;
  }
  EXPECT_GE(checked, 20);
}
