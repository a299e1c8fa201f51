// What a model predicts for every cell of a sweep, read exactly as the measurement is read.
//
// The model runs a burst from rest through the ideal triangle (every velocity corner stepped to
// exactly, whatever the plant and its effects), and its slider is "sampled" at the instants the
// cell's own trials are sampled (t = j / sample_rate from t = 0). The same feature extraction as
// for the measurement then reads the steps and the region, with the measurement's tolerances, so
// model and measurement are compared by one procedure and nothing depends on the simulator's
// integration grid. An effect that varies from trial to trial (friction_spread) is predicted as
// the distribution it gives the trials: the friction coefficient of a trial is mu (1 + sd n), n
// standard normal, integrated over n by kSpreadTrials equally weighted normal quantiles; the
// prediction is the mean steady step and its spread.
#pragma once

#include <vector>

#include "analysis/gap_cells.h"
#include "model/simulation.h"

namespace idm::analysis {

struct CellPrediction {
  double steady_step_m = 0;  // mean over the predicted trials
  double step_sd_m = 0;      // trial-to-trial spread of the steady step (0 for a deterministic model)
  double first_step_m = 0;
  double reverse_m = 0;
  int transient_cycles = 0;
  model::Region region = model::Region::Cutoff;  // majority over the predicted trials
};

// Quadrature points (model trials) per cell when the friction varies along the guide.
constexpr int kSpreadTrials = 6;

CellPrediction predict_cell_exact(const SweepCells& sweep, const model::SimConfig& sim, const Cell& cell);

// Every cell, spread over `threads` threads (0: all cores).
std::vector<CellPrediction> predict_sweep(const SweepCells& sweep, const model::SimConfig& sim, int threads);

// The plant rate a configuration with an actuator chain is scored at: one that resolves the
// stick-slip transitions under a smoothed command (steady steps within ~1.5 nm of a 16 MHz
// integration, against up to 36 nm at 100 kHz), and a DAC's update rate twice over.
double internal_rate_for(const model::SimConfig& sim);
// The cheaper rate a fit searches at: the amplifier's cutoff 20 times over, at least 50 kHz (and
// never below the data's sample rate, which the prediction steps at anyway). Parameters found at
// it are scored at internal_rate_for.
double search_rate_for(const model::SimConfig& sim);

}  // namespace idm::analysis
