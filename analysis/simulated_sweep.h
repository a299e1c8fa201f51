// A characterization sweep run on the simulated stage and written in the sweep dataset format:
// the paper's experiment (a grid of frequency, duty and stroke, several trials per cell, each on a
// different stretch of the guide) for idm-model sweep and idm-gap validate.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "model/simulation.h"
#include "recording/dataset.h"
#include "model/stage.h"

namespace idm::analysis {

struct SweepPlan {
  std::vector<double> freqs_hz;
  std::vector<double> duties;
  std::vector<double> strokes_m;  // empty: the stage's stroke
  int trials = 3;
  int cycles = 12;
  double sample_rate_hz = 20e3;
  std::uint64_t seed = 1;
  double guide_length_m = 40e-3;  // trials start anywhere on the guide
  double rest_before_s = 0.5e-3;  // command at rest before t = 0
  int rest_cycles_after = 2;      // settling after the burst, in periods
};

// Checks the plan; throws model::InputError naming the field and the allowed range.
void validate(const SweepPlan& plan);

// Runs the plan on the simulated stage (a fresh start per trial) and hands every trial to `sink`
// in plan order (stroke, frequency, duty, trial); no files. Returns the number of trials.
std::size_t simulate_sweep(const model::StageFile& stage, const model::SimConfig& sim, const SweepPlan& plan,
                           const std::function<void(const recording::TrialInfo&, recording::TrialSeries&&)>& sink);

// Runs the plan on a fresh simulated stage per trial and writes DATASET `out_dir` (crash-safe,
// trial by trial). Returns the number of trials written.
std::size_t run_simulated_sweep(const model::StageFile& stage, const model::SimConfig& sim,
                                const SweepPlan& plan, const std::string& out_dir);

}  // namespace idm::analysis
