// idm-gap validate: sweeps generated in memory from the simulated stage with known effects hidden,
// each diagnosed blind, and scored.
//
// A case is "none", one library effect ("amplifier"), a pair the data can separate
// ("amplifier+tilt"; every pair of validate_effects() but amplifier+actuator_compliance, the pair
// expected to be ambiguous), an effect of validate's own making that the library does not have
// ("unknown:stroke_saturation", unknown_effects.h), or an effect the sweep cannot show
// ("not_identifiable:tilt": one direction only; "not_identifiable:hysteresis": one stroke).
// Every run draws, from its seed, a stage (slider 0.05-0.5 kg, counter mass 20-50 % of it,
// friction 0.15-0.7, stroke 5-50 um, sensor count 1.2-9.9 nm, noise 0.5-3 nm, nominal K and C),
// a lab's sampling (10-50 kHz, 3-5 trials a cell, 4-8 frequencies up to where the stage's impulse
// ratio reaches 0.25-0.6, 5-8 duties, one or two strokes, one or both directions), and the hidden
// effects' parameters from ranges scaled to that stage and sweep.
//
// A run is correct when the named set equals the expected one exactly (the hidden library
// effects; nothing for "none", an unknown or a not identifiable effect), and for an unknown effect
// only when the report also says "unexplained" (a not identifiable one must be listed as such).
// Also scored: whether the report says "unexplained" (it should not for a library set), the hidden
// effect's shrink, and `where`: the rank correlation over the cells between what the report
// locates (the named effects' effect_gap, or what is left when nothing library-made is hidden)
// and the true footprint of the hidden effects (the noise-free sweep with them against without).
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "analysis/selection.h"
#include "analysis/simulated_sweep.h"

namespace idm::analysis {

// The library effects validate hides.
const std::vector<std::string>& validate_effects();

// The cases of a validate: quick (CI) or full (./idm bench).
std::vector<std::string> validate_cases(bool quick);

// The class of a case: "none", "single", "pair", "unknown", "not_identifiable". Throws
// model::InputError naming the case and the allowed forms for anything else.
std::string case_class(const std::string& case_name);

struct Scenario {
  std::string name;  // the case
  std::string cls;   // its class
  std::uint64_t seed = 0;
  model::StageFile stage;  // as stage.yaml says (the truth: nominal mu and masses)
  model::SimConfig sim;    // the hidden library effects and the noise
  SweepPlan plan;
  std::string unknown;                   // the hidden effect of validate's own making, or ""
  double unknown_strength = 0;           // in [0, 1], its parameters (make_unknown_effect)
  std::map<std::string, double> params;  // every hidden parameter as drawn ("effect.param")
  std::vector<std::string> expected;     // the set a correct diagnosis names
  bool expect_unexplained = false;
  std::string describe() const;  // stage and sampling in one line
};

// The scenario of `case_name` drawn from `seed` (deterministic). `quick`: a small sweep.
Scenario make_scenario(const std::string& case_name, std::uint64_t seed, bool quick);

struct ValidateRun {
  std::string hidden, cls, setup;
  std::map<std::string, double> params;
  std::uint64_t seed = 0;
  std::vector<std::string> named, expected, ambiguous_with, not_identifiable;
  bool correct = false;
  bool unexplained = false, expect_unexplained = false;
  double shrink = 0;  // the diagnosis's (of the named set; none named: of the best candidate)
  double gap_before = 0, gap_after = 0;
  double where_rank = 0;  // Spearman of the report's located cells against the true footprint
  bool where_scored = false;
  // A pair's hidden set itself, at its true parameters (alpha and mu fitted): its held-out gap and
  // the members it does not earn a place for against the other member fitted alone (earns_place,
  // into_noise). Such a member shows in this sweep by less than the selection's rule asks, so a
  // miss that leaves it out is the sweep's limit, not the search's.
  double truth_gap = 0;
  bool truth_scored = false;
  std::vector<std::string> truth_cannot_show;
  bool missed_beyond_sweep = false;  // named the hidden set without just those members
  // Named the hidden set, but its fit leaves a significant remainder where the true set's gap is
  // within the noise (kExplainedGap): the search stopped short of the true parameters.
  bool fit_short = false;
  double seconds = 0;
  std::string error;  // what stopped the run when it threw (it then counts as wrong); "" when none
};

struct ValidateOptions {
  int seeds = 1;
  std::uint64_t first_seed = 1;
  std::vector<std::string> cases;  // empty: validate_cases(quick)
  bool quick = false;
  int threads = 0;
};

struct ClassScore {
  int runs = 0, correct = 0;
  int missed_beyond_sweep = 0;  // runs with ValidateRun::missed_beyond_sweep
  int fit_short = 0;            // runs with ValidateRun::fit_short
  int unexplained_said = 0;     // runs whose report says unexplained
  double shrink_sum = 0, where_sum = 0;
  int where_runs = 0;
};

struct ValidateResult {
  std::vector<ValidateRun> runs;
  double accuracy = 0;
  std::map<std::string, std::pair<int, int>> by_effect;  // case: runs, correct
  std::map<std::string, ClassScore> by_class;
};

// The scenario's sweep, generated in memory with its hidden effects (an effect the library lacks
// included) and grouped into cells.
SweepCells scenario_sweep(const Scenario& scenario);

// The true footprint of the scenario's hidden effects per cell of `cells`: the noise-free sweep
// with them against the same sweep without them (one trial a cell; friction that varies along the
// guide by the predictor's distribution), in the units of `units`'s held-out residual of the cell
// (prediction_change). validate scores a report's where against it.
std::vector<double> true_footprint(const Scenario& scenario, const SweepCells& cells,
                                   const GapEvaluation& units);

// Generates the sweep in memory and diagnoses it. A run that throws is returned with its error
// (and counts as wrong): validate goes on to the next.
ValidateRun validate_one(const Scenario& scenario, int threads, Diagnosis* diagnosis = nullptr);

// `progress` (may be null) is called after every run.
ValidateResult run_validate(const ValidateOptions& options,
                            void (*progress)(const ValidateRun&) = nullptr);

// The JSON of docs/gap-report.md's validate section (with "by_class" and per run "class",
// "expected", "unexplained", "where_rank", "setup").
std::string validate_json(const ValidateResult& result);
// The table of accuracy by class printed after a validate.
std::string validate_table(const ValidateResult& result);

}  // namespace idm::analysis
