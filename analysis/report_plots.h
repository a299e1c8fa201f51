// The report a person looks at (idm-gap diagnose --report DIR): SVG plots written by hand (no
// plotting library) and report.html showing them with the text summary.
//
//   regions.svg      measured and model (baseline, and after the diagnosis) region maps over
//                    (frequency, duty), one row per stroke, like the paper's Fig. 11
//   steps.svg        steady step against duty, one colour per frequency, measured (points) and the
//                    model after the diagnosis (lines), like Fig. 13
//   gap_before.svg,  the held-out residual of every cell before and after the diagnosis
//   gap_after.svg
//   ranking.svg      each candidate effect's shrink of the held-out gap
//   report.html      all of the above with the summary
// Every file is written whole (temporary name, then rename).
#pragma once

#include <string>

#include "analysis/selection.h"

namespace idm::analysis {

std::string regions_svg(const SweepCells& sweep, const Diagnosis& d);
std::string steps_svg(const SweepCells& sweep, const Diagnosis& d);
std::string gap_map_svg(const SweepCells& sweep, const GapEvaluation& eval, const std::string& title);
std::string ranking_svg(const Diagnosis& d);

// Writes every file above into `dir` (created if missing). Returns the path of report.html.
std::string write_report(const SweepCells& sweep, const Diagnosis& d, const std::string& summary,
                         const std::string& dir);

}  // namespace idm::analysis
