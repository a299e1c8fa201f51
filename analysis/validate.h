// idm-gap validate: sweeps generated in memory from the simulated stage with one effect hidden at a
// time (and with none), parameters drawn at random from plausible ranges, each diagnosed blind.
// A run is correct when the named set equals the hidden one exactly ("none": nothing named).
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "analysis/selection.h"
#include "analysis/simulated_sweep.h"

namespace idm::analysis {

// The effects validate hides, and "none".
const std::vector<std::string>& validate_effects();

struct ValidateOptions {
  int seeds = 1;                      // runs per effect
  std::uint64_t first_seed = 1;
  std::vector<std::string> effects;   // empty: validate_effects()
  bool quick = false;                 // a smaller grid (duties by 0.1), for CI
  double sample_rate_hz = 0;          // 0: the plan's
  int threads = 0;
};

struct ValidateRun {
  std::string hidden;
  std::map<std::string, double> params;  // hidden effect's parameters as drawn
  std::uint64_t seed = 0;
  std::vector<std::string> named;
  double shrink = 0;        // the hidden effect's candidate (none: the diagnosis's shrink)
  double gap_before = 0, gap_after = 0;
  bool correct = false;
  double seconds = 0;
};

struct ValidateResult {
  std::vector<ValidateRun> runs;
  double accuracy = 0;
  std::map<std::string, std::pair<int, int>> by_effect;  // runs, correct
};

// The plan of a validate sweep: the paper's grid (100-800 Hz; duty 0.05-0.45) and its mirror
// (0.55-0.95), the stage's stroke and half of it, 4 trials per cell, 12 cycles, 200 kHz (the
// fastest rate of the format: the generator plays smoothing effects from the sampled command).
SweepPlan validate_plan(bool quick, std::uint64_t seed);

// The hidden effect's parameters drawn from its plausible range (deterministic in the seed).
model::EffectSpec draw_effect(const std::string& effect, std::uint64_t seed);

// Generates the sweep (in memory) with `hidden` ("none" for no effect) and diagnoses it.
ValidateRun validate_one(const std::string& hidden, std::uint64_t seed, const ValidateOptions& options,
                         Diagnosis* diagnosis = nullptr);

// `progress` (may be null) is called after every run.
ValidateResult run_validate(const ValidateOptions& options, void (*progress)(const ValidateRun&) = nullptr);

std::string validate_json(const ValidateResult& result);

}  // namespace idm::analysis
