// The report a person looks at (idm-gap diagnose --report DIR): SVG plots written by hand (no
// plotting library) and report.html showing them with the text summary. Axes carry round-number
// ticks (1, 2, 5 times a power of ten) and their units.
//
//   steps.svg        the paper's axes (Fig. 13): steady step against duty, one line per
//                    frequency; measured (held-out and training trials, mean) and the model after
//                    the diagnosis side by side, one row per stroke; cells carrying the gap ringed
//   regions.svg      measured and model (baseline, and after the diagnosis) region maps over
//                    (frequency, duty), one row per stroke, like the paper's Fig. 11
//   gap_before.svg,  maps over (frequency, duty) per stroke and direction: the baseline's held-out
//   effect_gap.svg,  residual, the named effects' footprint (effect_gap), the trial-to-trial
//   spread_excess.svg, spread beyond the model's, and what is left after the diagnosis
//   gap_after.svg
//   ranking.svg      each candidate effect's shrink of the held-out gap
//   report.html      all of the above with the summary
// Every file is written whole (temporary name, then rename).
#pragma once

#include <string>
#include <vector>

#include "analysis/selection.h"

namespace idm::analysis {

// Round-number ticks covering [lo, hi]: steps of 1, 2 or 5 times a power of ten, about `count` of
// them; every tick printed with the same number of decimals and never as "-0".
std::vector<double> nice_ticks(double lo, double hi, int count);
std::string tick_label(double value, double step);

std::string steps_svg(const SweepCells& sweep, const Diagnosis& d);
std::string regions_svg(const SweepCells& sweep, const Diagnosis& d);
// A map of one value per cell (in the gap's unit), one panel per stroke and direction; grid
// positions without a cell and values that are not finite are hatched grey ("no data" in the
// legend), never white (a value of 0). With `when_empty` and no value above 0, that sentence is
// written across the panels ("no cell shows a spread excess") instead of a map left blank.
std::string cell_map_svg(const SweepCells& sweep, const std::vector<double>& values,
                         const std::string& title, const std::string& legend,
                         const std::string& when_empty = "");
std::string ranking_svg(const Diagnosis& d);

// Writes every file above into `dir` (created if missing). Returns the path of report.html.
std::string write_report(const SweepCells& sweep, const Diagnosis& d, const std::string& summary,
                         const std::string& dir);

}  // namespace idm::analysis
