// The gap of the baseline (impulse model, fitted correction factor) on held-out trials.
#include <gtest/gtest.h>

#include <unistd.h>

#include <cmath>
#include <filesystem>

#include "analysis/gap.h"
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
