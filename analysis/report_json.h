// The JSON of docs/gap-report.md (with its extension: unexplained, ambiguous, not_identifiable,
// intervals, effect_gap, spread_excess) and of `idm-gap validate`, and writing files whole (every
// file goes to a temporary name in its directory, is flushed to disk and renamed over the final
// name, so a reader never sees half a report).
//
// Further extensions (extending, not contradicting): "dataset_status" (the recorder's mark,
// recording/README.md, the cells left out and, as "trials_left_out" [{"file", "why"}], the trials
// whose files could not be used); the baseline's fitted "friction_coefficient" and
// "systematic_gap"; per cell "stroke_m", "held_out_trials", "first_step_m", "transient_cycles",
// "reverse_m", "model_step_after_m", "model_region_after", "residual_after"; per candidate
// "train_gap" and, when implausible, "why"; "where" also carries "summary_after" and the
// significant cells with their stroke; a top-level "not_identifiable" with "needs" and "selection"
// (the forward and backward steps); the diagnosis also carries the joint fit's "step_correction"
// and "friction_coefficient", the unexplained part's "systematic_gap", "cells_with_stroke" and
// "closest", and each ambiguity's "chosen", "alternative" and their gaps.
#pragma once

#include <string>

#include "analysis/selection.h"

namespace idm::analysis {

std::string gap_report_json(const SweepCells& sweep, const Diagnosis& d,
                            const std::string& dataset);

// Writes `content` to `path` whole (temporary name, fsync, rename). Throws std::system_error
// naming the file.
void write_file_atomic(const std::string& path, const std::string& content);

// JSON helpers shared by the report writers.
std::string json_string(const std::string& s);
std::string json_number(double v);

}  // namespace idm::analysis
