// Where the gap lies, in the effect's own terms.
//
// Per cell (docs/gap-report.md, extension):
// * effect_gap: how far the named effects move the cell's prediction: the fitted model with them
//   against the same model without them (same alpha and mu), normalized like the residual (the
//   mean in units of the cell's held-out uncertainty, the spread as a log variance ratio, 3 for a
//   region label that changes);
// * spread_excess: the trial-to-trial spread of all the cell's trials beyond the one the model
//   predicts (noise and the model's own spread), as a log variance ratio in units of its sampling
//   error, 0 when not wider;
// * remainder: the cell's held-out residual after the named effects;
// * departure: the cell's held-out residual against the stage as stage.yaml describes it (the
//   impulse model at its mu, alpha 1, no effect). Where nothing is named this locates what the
//   data shows: a calibration of alpha and mu can absorb a gain-like distortion the library does
//   not have into a residual spread over other cells, the departure from the stage's own
//   description cannot.
// The summary says in words where a per-cell quantity is largest and what pattern it follows:
// rank correlations with frequency, with the fast phase's share of the period, with stroke,
// the ratio between the two directions, and with closeness to a region boundary of the impulse
// model.
#pragma once

#include <string>
#include <vector>

#include "analysis/gap.h"

namespace idm::analysis {

struct CellWhere {
  double effect_gap = 0;
  double spread_excess = 0;
  double remainder = 0;
  double departure = 0;
};

struct WhereReport {
  std::vector<CellWhere> cells;            // sweep order
  std::vector<CellKey> significant_cells;  // the baseline's significant cells
  std::string
      summary;  // the pattern of effect_gap (of the baseline's residual when nothing is named)
  std::string summary_after;      // the pattern of what is left after the named effects
  std::string summary_departure;  // the pattern of the departure from stage.yaml's stage
};

// `after`: the named set's fitted model; `without`: the same model's predictions with the named
// effects removed (nullptr when nothing is named: effect_gap is then 0); `described`: the
// predictions of nominal_model(sweep), the stage as stage.yaml describes it.
WhereReport where_of(const SweepCells& sweep, const FittedModel& baseline, const FittedModel& after,
                     const std::vector<CellPrediction>* without,
                     const std::vector<CellPrediction>& described);

// Where `values` (one per cell, >= 0) are largest and what pattern they follow, as one or two
// sentences; `what` names the quantity ("the named effects' footprint").
std::string pattern_summary(const SweepCells& sweep, const std::vector<double>& values,
                            const std::string& what);

// Spearman's rank correlation (ties get their mean rank); 0 when either side is constant.
double spearman(const std::vector<double>& a, const std::vector<double>& b);

// The normalized change of a cell's prediction (mean, spread and label) between two models, in
// the units of the held-out residual of `cell` (CellResidual::se_m and its trials).
double prediction_change(const CellResidual& cell, double step_a_m, double sd_a_m,
                         model::Region region_a, double step_b_m, double sd_b_m,
                         model::Region region_b, double reading_sd_m);

}  // namespace idm::analysis
