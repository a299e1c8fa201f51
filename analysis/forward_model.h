// What a model predicts for every cell of a sweep, read exactly as the measurement is read.
//
// The model runs a burst from rest through the ideal triangle (every velocity corner stepped to
// exactly, whatever the plant and its effects) and is read at the sample instants the cell's own
// trials were read at (Cell::read_t_s), by the same rule (features_from_marks), so model and
// measurement are compared by one procedure and nothing depends on the simulator's grid. Only the
// rest instants are visited, so a plant without an actuator chain is an event simulation (corners
// and readings); once the steps have repeated for three cycles with the slider in the same state
// the rest of the burst is the same cycle again and is not simulated.
//
// Friction that varies from trial to trial (friction_spread) is predicted as the distribution it
// gives the trials: a trial's friction coefficient is mu (1 + relative_sd z), z standard normal,
// integrated by kSpreadTrials equally weighted normal quantiles (their steps, their mean and their
// spread). In a search, under an actuator chain or a compliant actuator (expensive plants), the
// spread acts through the plant without them: step(mu_k) = full(mu) + cheap(mu_k) - cheap(mu), so
// a chain runs once a cell; a score simulates every quantile whole.
#pragma once

#include <vector>

#include "analysis/gap_cells.h"
#include "model/simulation.h"

namespace idm::analysis {

// A model of the stage a sweep is predicted with.
struct ModelConfig {
  model::StageParams stage;                // stage.yaml, with the friction coefficient in use
  std::vector<model::EffectSpec> effects;  // completed (model::complete_effect)
  double chain_rate_hz = 0;                // plant rate under an actuator chain; 0: score_rate_hz
  bool search =
      false;  // the cheaper numerics of a search (Stribeck: 2 % of its velocity a step, not 0.5 %)
};

struct CellPrediction {
  double steady_step_m = 0;  // mean over the predicted trials
  double step_sd_m = 0;      // trial-to-trial spread of the steady step (0 without a spread)
  // With a friction spread: the step of each quadrature point (spread_quadrature(), in its order),
  // the distribution a trial's step is scored against (gap.h); empty without a spread.
  std::vector<double> trial_steps_m;
  double first_step_m = 0;
  int transient_cycles = 0;
  model::Region region = model::Region::Cutoff;  // majority over the predicted trials
  // d(steady step)/d(mu) of the ideal model at this cell: how the step follows a small change of
  // the friction coefficient (the baseline's friction is fitted through it, gap.h).
  double mu_slope_m = 0;
};

// Quadrature points (model trials) per cell when the friction varies along the guide.
constexpr int kSpreadTrials = 6;

// `count` equally weighted points of a standard normal: its quantiles at (k + 1/2) / count,
// rescaled so that their mean square is 1 (the mean and the variance of the normal), ascending.
std::vector<double> normal_points(int count);
// The friction spread's quadrature: normal_points(kSpreadTrials); a trial's friction coefficient
// at point z is mu (1 + mean_shift + relative_sd z).
const std::vector<double>& spread_quadrature();

// Plant rate a model with an actuator chain is scored at: a smoothed command breaks the slider
// loose between two plant steps, and the rigid plant finds that moment to within a step (steady
// steps within ~1.5 nm of a 16 MHz integration at 2 MHz).
constexpr double kScoreRateHz = 2e6;
// The rate a model is scored at: kScoreRateHz under a chain that breaks the slider loose (an
// amplifier, hysteresis, a DAC); creep alone, a slow drift, is converged at 200 kHz (within 0.1 nm
// of 16 MHz).
double score_rate_hz(const std::vector<model::EffectSpec>& effects);
// The cheaper rate fits search at (kScoreRateHz when nothing smooths the command): an amplifier's
// cutoff 20 times over, hysteresis 500 kHz, creep (slow) 100 kHz, a DAC twice its clock. The
// winner is polished and scored at kScoreRateHz.
double search_rate_hz(const std::vector<model::EffectSpec>& effects);

// The prediction of one cell and of every cell (spread over `threads` threads, 0: all cores).
CellPrediction predict_cell(const SweepCells& sweep, const ModelConfig& model, const Cell& cell);
std::vector<CellPrediction> predict_sweep(const SweepCells& sweep, const ModelConfig& model,
                                          int threads);

// The positions of one burst at the cell's reading instants (marks[0] = 0 at the start), from rest
// at x = 0 on the plant of `stage` with `sim` (noise-free). Exposed for tests.
std::vector<double> simulate_marks(const model::StageParams& stage, const model::SimConfig& sim,
                                   const Cell& cell, double tolerance_m, bool search = false);

}  // namespace idm::analysis
