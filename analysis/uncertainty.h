// How sure a fit is: an interval for every fitted parameter from the held-out trials, and the
// sweep that would tell two sets of effects apart.
//
// Intervals: the profile of the held-out chi-square (the number of cells times the held-out gap
// squared) around the fit, alpha and mu refitted on the training trials at every point. The
// profile is the quadratic through a few points around the optimum in the fit's coordinates
// (steps chosen so that the chi-square rises by a measurable amount); an interval holds the
// parameters whose held-out chi-square is within 3.84 (95 %) of the minimum, times the reduced
// chi-square when that is above 1 (a model that misses by more than the noise is less sure). A
// coordinate the held-out data does not constrain spans its whole plausible range.
#pragma once

#include <string>
#include <vector>

#include "analysis/candidates.h"

namespace idm::analysis {

struct ParameterInterval {
  std::string param;  // the effect's parameter, as reported (docs/gap-report.md)
  double value = 0, lo = 0, hi = 0;
  bool limited_by_range = false;  // an end is the plausible range's, not the data's
};

struct ParameterIntervals {
  std::string effect;
  std::vector<ParameterInterval> params;
};

// Intervals of every fitted parameter of `fit` (one entry per member; explicit-grid members get
// the grid values the held-out data cannot tell apart). `scoring`: evaluate at the scoring rate
// (else the search rate, for candidates not named).
std::vector<ParameterIntervals> parameter_intervals(const SweepCells& sweep,
                                                    const std::vector<CandidateSpec>& library,
                                                    const SetFit& fit, const FittedModel& baseline,
                                                    int threads, bool scoring);

// Where two fitted sets part most: cells of a wider grid (this sweep's frequencies up to 3 times
// the highest, duties 0.02-0.45 and their mirrors, the sweep's strokes) predicted by both,
// compared in units of one trial's step noise over sqrt(trials a cell). A sentence naming the
// frequencies, duties and strokes where they part by the most, and by how much against this sweep.
std::string separating_sweep(const SweepCells& sweep, const SetFit& a, const SetFit& b,
                             int threads);

}  // namespace idm::analysis
