// The gap of the baseline (impulse model, fitted correction factor) on held-out trials, and the plant
// rate a model is scored at.
#include <gtest/gtest.h>

#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <random>

#include "analysis/gap.h"
#include "analysis/prediction.h"
#include "model/simulation.h"
#include "model/waveform.h"
#include "analysis/simulated_sweep.h"

using namespace idm;
using namespace idm::analysis;

namespace {
std::string make_sweep(const std::string& name, const model::SimConfig& sim) {
  const auto dir = std::filesystem::temp_directory_path() / (name + "_" + std::to_string(getpid()));
  std::filesystem::remove_all(dir);
  SweepPlan plan;
  plan.freqs_hz = {100, 200, 300, 400, 500, 600, 700, 800};
  plan.duties = {0.05, 0.15, 0.25, 0.35, 0.45};
  plan.trials = 3;
  plan.cycles = 8;
  plan.sample_rate_hz = 20e3;
  plan.seed = 11;
  run_simulated_sweep(model::StageFile{}, sim, plan, dir.string());
  return dir.string();
}
}  // namespace

TEST(Gap, IdealStageIsWithinTheNoiseOfTheBaseline) {
  model::SimConfig sim;
  sim.noise_m = 2e-9;
  const std::string dir = make_sweep("gap_ideal", sim);
  const SweepCells cells = collect_cells(recording::read_dataset(dir));
  EXPECT_NEAR(cells.reading_sd_m, std::sqrt(4e-18 + 9.8906e-9 * 9.8906e-9 / 12), 1.5e-9);
  const GapEvaluation base = baseline_gap(cells);
  EXPECT_NEAR(base.step_scale, 1.0, 0.01);
  EXPECT_LT(base.gap, 2.0) << where_summary(base);
  std::filesystem::remove_all(dir);
}

TEST(Gap, AmplifierSampleSweepPartsFromTheBaselineAtHighFrequency) {
  const SweepCells cells = collect_cells(recording::read_dataset(std::string(IDM_SHARED_DIR) + "/data/sample-sweep-amplifier"));
  ASSERT_EQ(cells.cells.size(), 160u);
  const GapEvaluation base = baseline_gap(cells);
  EXPECT_GT(base.gap, 3.0);
  int high = 0, low = 0;
  for (const CellResidual& r : base.cells)
    if (r.significant) (r.key.freq_hz >= 400 ? high : low)++;
  EXPECT_GT(high, low) << where_summary(base);
}

TEST(Gap, TooSmallASweepSaysSo) {
  model::SimConfig sim;
  const auto dir = std::filesystem::temp_directory_path() / ("gap_small_" + std::to_string(getpid()));
  std::filesystem::remove_all(dir);
  SweepPlan plan;
  plan.freqs_hz = {100};
  plan.duties = {0.05};
  plan.trials = 2;
  plan.cycles = 4;
  run_simulated_sweep(model::StageFile{}, sim, plan, dir.string());
  try {
    collect_cells(recording::read_dataset(dir.string()));
    ADD_FAILURE() << "no error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("too small to diagnose"), std::string::npos) << e.what();
  }
  std::filesystem::remove_all(dir);
}

// log(chi2_k / k): closed forms (psi(1/2) = -gamma - 2 log 2, psi'(1/2) = pi^2 / 2, psi(1) =
// -gamma, psi'(1) = pi^2 / 6), the large-k limit, and a Monte Carlo check of the recurrence.
TEST(Gap, LogSampleVarianceMoments) {
  constexpr double kGamma = 0.5772156649015329;
  const LogVarianceMoments one = log_sample_variance_moments(1);
  EXPECT_NEAR(one.mean, -kGamma - 2 * std::log(2.0) + std::log(2.0), 1e-12);  // -1.2704
  EXPECT_NEAR(one.sd, M_PI / std::sqrt(2.0), 1e-12);                          // 2.2214
  const LogVarianceMoments two = log_sample_variance_moments(2);
  EXPECT_NEAR(two.mean, -kGamma, 1e-12);
  EXPECT_NEAR(two.sd, M_PI / std::sqrt(6.0), 1e-12);
  const LogVarianceMoments many = log_sample_variance_moments(2000);
  EXPECT_NEAR(many.mean, -1.0 / 2000, 1e-6);
  EXPECT_NEAR(many.sd, std::sqrt(2.0 / 2000), 1e-5);
  EXPECT_EQ(log_sample_variance_moments(0).sd, 0.0);
  // k = 5 by sampling: 200,000 sample variances of 6 normal values.
  std::mt19937_64 rng(11);
  std::normal_distribution<double> n01;
  double sum = 0, sum2 = 0;
  const int reps = 200000;
  for (int r = 0; r < reps; ++r) {
    double x[6], mean = 0, ss = 0;
    for (double& v : x) mean += (v = n01(rng)) / 6;
    for (double v : x) ss += (v - mean) * (v - mean);
    const double l = std::log(ss / 5);
    sum += l;
    sum2 += l * l;
  }
  const double mc_mean = sum / reps, mc_sd = std::sqrt(sum2 / reps - mc_mean * mc_mean);
  const LogVarianceMoments five = log_sample_variance_moments(5);
  EXPECT_NEAR(five.mean, mc_mean, 0.005);
  EXPECT_NEAR(five.sd, mc_sd, 0.005);
}

// The rate a candidate is scored at resolves the stick-slip transitions under a smoothed command:
// a steady step there is within 2 nm a cycle of a 16 MHz integration, where the search rate
// (20 x the cutoff, the data's 100 kHz samples) is off by more than 5 nm in some cell.
TEST(Prediction, AnAmplifierIsScoredAtAConvergedPlantRate) {
  model::SimConfig sim;
  sim.effects.push_back(model::complete_effect({"amplifier", {{"cutoff_hz", 3000}, {"order", 2}}}, "test"));
  auto step_per_cycle_nm = [&](double rate_hz, double freq_hz, double duty) {
    model::SimConfig s = sim;
    s.internal_rate_hz = rate_hz;
    model::InterferometerParams exact;
    exact.resolution_m = 1e-12;
    const model::StageFile stage;
    model::SimulatedStage plant(stage.stage, exact, s);
    const model::TriangleWave w{freq_hz, duty, stage.stage.stroke_m, 12};
    model::TrialSamples out;
    plant.run_burst(w, 100e3, 0, 0, out);
    return out.x_m.back() / 12 * 1e9;
  };
  double worst_scored = 0, worst_search = 0;
  for (double f : {500.0, 800.0})
    for (double duty : {0.1, 0.3}) {
      const double fine = step_per_cycle_nm(16e6, f, duty);
      worst_scored = std::max(worst_scored, std::fabs(step_per_cycle_nm(internal_rate_for(sim), f, duty) - fine));
      worst_search = std::max(worst_search, std::fabs(step_per_cycle_nm(search_rate_for(sim), f, duty) - fine));
    }
  EXPECT_LT(worst_scored, 2.0);
  EXPECT_GT(worst_search, 5.0);
}
