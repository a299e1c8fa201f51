// How far a model and the measured sweep part, cell by cell, on held-out (or training) trials.
//
// A model's steps are calibrated on the training trials before they are compared: the paper's
// correction factor alpha (a scale on every step) and the friction coefficient mu, the two
// parameters of the impulse model's steady step that stage.yaml cannot pin down (eq 22: alpha mu
// and alpha m S / (M + m)). mu enters linearized around the mu the model was simulated at
// (CellPrediction::mu_slope_m, the ideal model's slope), so both come from one weighted linear
// least-squares fit; fit_model uses that only to propose a mu, which it simulates and keeps when
// the training gap falls.
//
// Residual of a cell (docs/gap-report.md): the mean steady step against the model's, in units of
// its uncertainty (the cell's trial-to-trial spread, never less than the noise on a step,
// sqrt(2) * reading_sd, over sqrt(trials), and the model's own error, kModelErrorM and
// kModelErrorRel); a spread different from the one expected (noise and
// the model's spread) is itself a gap, scored as the log ratio of the variances in units of its
// exact sampling error (log_sample_variance_moments); a region label the model gets wrong counts 3.
// A model with a friction spread predicts a distribution of a trial's step
// (CellPrediction::trial_steps_m), often lopsided near a region boundary: there each trial is
// scored by its normal score under that distribution, Phi^-1(F(step)), the mean of the scores in
// units of 1/sqrt(trials) (of their own spread when wider) and their spread against 1 the same way.
// `gap` is the root mean square over the cells: about 1 means "within the noise".
#pragma once

#include <string>
#include <vector>

#include "analysis/forward_model.h"

namespace idm::analysis {

// The baseline parameters fitted with every model: step = alpha (s + (mu - mu_sim) slope).
struct Calibration {
  double alpha = 1;     // the paper's correction factor (a scale on the model's steps)
  double mu = 0.4;      // friction coefficient
  double mu_sim = 0.4;  // the friction coefficient the predictions were simulated at
  double step(const CellPrediction& p) const { return step_at(p.steady_step_m, p.mu_slope_m); }
  double step_at(double step_m, double mu_slope_m) const {
    return alpha * (step_m + (mu - mu_sim) * mu_slope_m);
  }
};

struct CellResidual {
  CellKey key;
  int trials = 0;  // trials of the evaluated set
  double measured_step_m = 0, measured_step_sd_m = 0, model_step_m = 0, model_step_sd_m = 0;
  model::Region measured_region = model::Region::Cutoff, model_region = model::Region::Cutoff;
  double mean_z = 0;    // (measured - model mean) / its uncertainty, signed
  double spread_z = 0;  // log variance ratio in units of its sampling sd, signed (> 0: wider)
  double label = 0;     // 3 when the region labels differ
  double se_m = 0;      // the uncertainty of the cell's mean step the residual is in units of
  double residual = 0;  // sqrt(mean_z^2 + spread_z^2 + label^2)
  bool significant = false;
};

struct GapEvaluation {
  double gap = 0;
  Calibration calibration;
  std::vector<CellResidual> cells;
};

enum class TrialSet { Train, Test };

// The parts of a gap: the root mean square over the cells of mean_z, of spread_z and of the label
// term; they add in squares to the gap. An effect can act on one part alone (a spread of the
// friction on the trials' spread).
struct GapParts {
  double mean = 0, spread = 0, label = 0;
};
GapParts gap_parts(const GapEvaluation& evaluation);

constexpr double kSignificantResidual = 3.0;
// The unit every gap and residual is printed with: the standard uncertainty of what it compares (a
// cell's mean step, its spread), so 1 is "within the noise" and 3 significant.
inline constexpr const char* kGapUnit = "σ";
// How far a prediction is trusted: 1 nm and 0.1 % of the step, added to the uncertainty of a
// cell's mean step. A smoothed command integrated at the scoring rate is within ~2 nm of a
// converged integration, and two simulators of the same physics differ by as much; the noise of a
// held-out mean is 2-4 nm.
constexpr double kModelErrorM = 1e-9;
constexpr double kModelErrorRel = 1e-3;

// Mean and standard deviation of log(s^2 / sigma^2) for a sample variance s^2 with `dof` degrees
// of freedom from a normal population (log of chi2_dof / dof): psi(dof/2) - log(dof/2) and
// sqrt(psi'(dof/2)); for dof = 1: -1.27 and 2.22, for many: -1/dof and sqrt(2/dof).
struct LogVarianceMoments {
  double mean = 0, sd = 0;
};
LogVarianceMoments log_sample_variance_moments(int dof);

// alpha and mu that best fit the training trials: weighted least squares of the measured steady
// steps against the calibrated predictions (each cell by the inverse of its step variance, so a
// cell whose steps scatter does not pull the fit off the cells that pin it). With `fit_mu` false,
// or when the sweep cannot tell mu from alpha, mu stays at mu_sim. A change of mu is limited to
// 30 % a call (the linearization holds near mu_sim), and mu to model::kMaxFrictionCoefficient.
Calibration fit_calibration(const SweepCells& sweep, const std::vector<CellPrediction>& predictions,
                            double mu_sim, bool fit_mu = true);

// Residuals and the gap of calibrated predictions, on held-out trials (default) or training ones.
GapEvaluation evaluate_gap(const SweepCells& sweep, const std::vector<CellPrediction>& predictions,
                           const Calibration& calibration, TrialSet set = TrialSet::Test);

// A model fitted to the training trials: predictions, the calibration, and the held-out and
// training evaluations. mu: up to `rounds` proposals of the linearized fit, each simulated and
// kept only when it lowers the training gap; alpha is fitted alone at the kept mu.
struct FittedModel {
  ModelConfig model;  // model.stage.friction_coefficient: the mu the predictions were simulated at
  std::vector<CellPrediction> predictions;
  Calibration calibration;
  GapEvaluation train, test;
};
FittedModel fit_model(const SweepCells& sweep, ModelConfig model, int threads, int rounds = 2);

// What the training and the held-out residuals of one model share, in noise units: the root of
// the mean over cells of (train component x held-out component), summed over the mean, spread and
// label components (noise is independent between the two sets, a model's error is not).
double systematic_gap(const FittedModel& model);

// The baseline of the diagnosis: the ideal impulse model (rigid actuator, Coulomb friction) with
// alpha and mu fitted on training trials.
FittedModel fit_baseline(const SweepCells& sweep, int threads);

// The model of the stage as stage.yaml gives it (no effects, the scoring rate).
ModelConfig nominal_model(const SweepCells& sweep);

}  // namespace idm::analysis
