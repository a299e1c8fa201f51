// The candidate effects of the diagnosis: every effect of the library (model::effect_library())
// added alone to the baseline, its parameters fitted on the training trials within bounds of
// physical plausibility, and scored by the gap it leaves on the held-out trials.
//
// Fitting: the parameters are mapped to [0, 1] (log scale where they span decades), a coarse grid
// finds the basin (the objective is piecewise flat where region labels change), then NLopt's
// bounded derivative-free Subplex (LN_SBPLX) refines it, and a last Subplex with a tenth of the
// step polishes the winner. The objective is the training gap of the model with the effect, its
// step scale (the paper's alpha) refitted at every evaluation.
// A fit is implausible when it ends on a bound of its range (the data asks for more than the
// physics allows, or for no effect at all) or needs a step scale outside (0.05, 2].
#pragma once

#include <map>
#include <string>
#include <vector>

#include "analysis/gap.h"
#include "model/simulation.h"

namespace idm::analysis {

struct FitParam {
  std::string name;
  double lo = 0, hi = 1;  // the plausible range searched
  bool log_scale = false;
};

struct CandidateSpec {
  std::string effect;
  std::vector<FitParam> fit;                               // 1 or 2 fitted parameters
  std::vector<std::map<std::string, double>> variants;     // fixed parameters, each fitted separately
  std::vector<std::vector<double>> grid;                   // explicit grid (integer parameters): no refinement
};

// The candidates for every effect of model::effect_library(), in library order.
const std::vector<CandidateSpec>& candidate_library();

// What the effect's signature needs that the sweep lacks ("a second stroke", "duties above 0.5
// (the other direction)"), or "" when the effect is identifiable from this sweep.
std::string missing_signature(const SweepCells& sweep, const std::string& effect);

struct CandidateResult {
  std::string effect;
  std::map<std::string, double> params;  // the fitted and the fixed parameters, as reported
  double train_gap = 0;                  // objective at the optimum
  double gap = 0;                        // held-out gap with the effect
  double shrink = 0;                     // 1 - gap / gap_before
  double step_scale = 1;
  bool plausible = true;
  std::string note;                      // why not plausible
  int evaluations = 0;
  GapEvaluation eval;                    // held-out residuals with the effect
};

struct FitOptions {
  int threads = 0;       // 0: all cores
  int grid_1d = 9;       // coarse grid points for one parameter
  int grid_2d = 7;       // per axis for two
  int refine_evals = 16; // NLopt evaluations after the grid (one parameter; twice that for two)
  int starts_2d = 3;     // refinements for two parameters: the best grid point and the next
                         // best ones that are not its neighbours
  bool polish = true;    // a last refinement of the winner with a step a tenth as large
};

// The model with `base` effects (already chosen, fixed) plus one candidate, fitted on the training
// trials and scored on the held-out ones against `gap_before`.
CandidateResult fit_candidate(const SweepCells& sweep, const std::vector<model::EffectSpec>& base,
                              const CandidateSpec& spec, double gap_before, const FitOptions& options);

// The configuration a set of effects is simulated with (rigid plant), at the internal rate it is
// scored at (internal_rate_for) or, with `search`, the cheaper one a fit searches at.
model::SimConfig config_with(const std::vector<model::EffectSpec>& effects, bool search = false);

// Predictions, step scale (fitted on training trials) and held-out evaluation of a configuration.
GapEvaluation evaluate_config(const SweepCells& sweep, const model::SimConfig& sim, int threads,
                              TrialSet set = TrialSet::Test);

}  // namespace idm::analysis
