// The JSON of specs/gap-report.md (and of `idm-gap validate`), and writing files whole: every file
// goes to a temporary name in its directory, is flushed to disk and renamed over the final name,
// so a reader never sees half a report.
//
// Extensions to the spec (extending, not contradicting): the baseline's "alpha", per cell
// "stroke_m", "held_out_trials", "first_step_m", "transient_cycles", "reverse_m",
// "model_region_after", "residual_after"; per candidate "order" among the params of the amplifier,
// "train_gap" and, when implausible, "why"; a top-level "not_identifiable": [{"effect", "needs"}]
// and "selection": the forward-selection steps; "where" also carries "summary_after".
#pragma once

#include <string>

#include "analysis/selection.h"

namespace idm::analysis {

std::string gap_report_json(const SweepCells& sweep, const Diagnosis& d, const std::string& dataset);

// Writes `content` to `path` whole (temporary name, fsync, rename). Throws std::system_error
// naming the file.
void write_file_atomic(const std::string& path, const std::string& content);

// JSON helpers shared by the report writers.
std::string json_string(const std::string& s);
std::string json_number(double v);

}  // namespace idm::analysis
