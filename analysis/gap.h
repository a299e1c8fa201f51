// How far a model and the measured sweep part, cell by cell, on held-out (or training) trials.
//
// Residual of a cell (specs/gap-report.md): the mean steady step against the model's, in units of
// its uncertainty (the measured trial-to-trial spread of the cell, all its trials, never less than
// the noise on a step,
// sqrt(2) * reading_sd, over sqrt(trials)); a spread different from the one expected
// (noise and the model's spread) is itself a gap, scored as the log ratio of the variances in units
// of its exact sampling error (log_sample_variance_moments); a region label the model gets wrong counts 3. `gap` is the root mean
// square over the cells: about 1 means "within the noise of the measurement".
#pragma once

#include <string>
#include <vector>

#include "analysis/gap_cells.h"
#include "analysis/prediction.h"

namespace idm::analysis {

struct CellResidual {
  CellKey key;
  int trials = 0;  // trials of the evaluated set
  double measured_step_m = 0, measured_step_sd_m = 0, model_step_m = 0, model_step_sd_m = 0;
  model::Region measured_region = model::Region::Cutoff, model_region = model::Region::Cutoff;
  double residual = 0;
  bool significant = false;
};

struct GapEvaluation {
  double gap = 0;
  double step_scale = 1;  // the fitted correction factor applied to the model's steps
  std::vector<CellResidual> cells;
};

enum class TrialSet { Train, Test };

constexpr double kSignificantResidual = 3.0;

// Mean and standard deviation of log(s^2 / sigma^2) for a sample variance s^2 with `dof` degrees
// of freedom from a normal population (log of chi2_dof / dof): psi(dof/2) - log(dof/2) and
// sqrt(psi'(dof/2)); for dof = 1: -1.27 and 2.22, for many: -1/dof and sqrt(2/dof).
struct LogVarianceMoments {
  double mean = 0, sd = 0;
};
LogVarianceMoments log_sample_variance_moments(int dof);

// The scale (the paper's alpha for the impulse model) that best fits the training trials: least
// squares of measured steady steps against the predictions, over cells the model does not cut off.
double fit_step_scale(const SweepCells& sweep, const std::vector<CellPrediction>& predictions);

// Residuals and the gap of `predictions` (one per cell, unscaled) times `step_scale`, on the
// held-out trials (default) or the training trials.
GapEvaluation evaluate_gap(const SweepCells& sweep, const std::vector<CellPrediction>& predictions,
                           double step_scale, TrialSet set = TrialSet::Test);

// The same for deterministic predictions (one model trial per cell).
double fit_step_scale(const SweepCells& sweep, const std::vector<TrialFeatures>& predictions);
GapEvaluation evaluate_gap(const SweepCells& sweep, const std::vector<TrialFeatures>& predictions,
                           double step_scale);

// The baseline of the diagnosis: the ideal impulse model (rigid actuator, Coulomb friction) with
// its correction factor fitted on training trials.
std::vector<TrialFeatures> predict_all(const SweepCells& sweep, const model::SimConfig& sim);
GapEvaluation baseline_gap(const SweepCells& sweep, int threads = 1);

// One sentence a person can read: where the significant cells lie in (frequency, duty) and region.
std::string where_summary(const GapEvaluation& eval);

}  // namespace idm::analysis
