// The recorder's mark on a dataset (an extension of docs/sweep-dataset.md, recording/README.md):
// DATASET/plan.yaml holds the grid as planned and how the recording ended. The writer puts it
// there with `status: in_progress` before the first trial and rewrites it with `complete` or
// `stopped` when the sweep ends, each time whole (temporary name, fsync, rename), so a sweep cut
// off by a crash, SIGKILL or a power loss still says `in_progress`: no code has to run for the
// mark to be right. A dataset without plan.yaml (another lab, another simulator) is read exactly
// as before: the format does not require the file.
#pragma once

#include <string>
#include <vector>

#include "model/stage.h"

namespace idm::recording {

struct TrialInfo;

enum class SweepStatus {
  Unmarked,    // no plan.yaml: nothing is known about what was planned
  InProgress,  // the recorder started and did not finish (killed, crashed, still running)
  Complete,    // the recorder went through the whole plan (trials that failed may be missing)
  Stopped,     // the recorder ended early on purpose (STOP, the daemon stopping); `note` says why
  Failed,      // the recorder ended early on an error (a write failed, the motion gate refused a
               // trial, the end of travel); `note` says which
};
// "unmarked", "in_progress", "complete", "stopped", "failed"
const char* status_name(SweepStatus status);

// One cell of the grid as planned: the values its trials carry in sweep.csv, and how many.
struct PlannedCell {
  double freq_hz = 0.0;
  double duty = 0.0;
  double stroke_m = 0.0;
  int trials = 0;
};

struct SweepPlanFile {
  SweepStatus status = SweepStatus::InProgress;
  std::vector<PlannedCell> cells;
  std::string note;  // why a sweep stopped (one line), optional
  std::string axis;  // the name of the axis that played the sweep (one line), optional
};

// A planned cell with fewer trials in sweep.csv than planned.
struct MissingCell {
  PlannedCell planned;
  int recorded = 0;  // trials of the cell in sweep.csv (0: the cell is missing entirely)
};

// What the mark says about a dataset, and what sweep.csv holds against it.
struct SweepProgress {
  SweepStatus status = SweepStatus::Unmarked;
  std::vector<PlannedCell> planned;  // empty when unmarked
  std::vector<MissingCell> missing;  // planned order
  std::string note;
  std::string axis;  // "" when the mark names no axis
  bool interrupted() const {
    return status == SweepStatus::InProgress || status == SweepStatus::Stopped ||
           status == SweepStatus::Failed;
  }
  bool marked() const { return status != SweepStatus::Unmarked; }
};

// File name of the mark inside DATASET/.
constexpr const char* kPlanFile = "plan.yaml";

// Text of plan.yaml (numbers in the shortest form that reads back exactly).
std::string plan_yaml(const SweepPlanFile& plan);

// Reads DATASET/plan.yaml; every error names the file, the line and the key. Throws InputError.
SweepPlanFile read_plan_file(const std::string& path);

// Checks a plan before anything is written (cells with values the format allows, trials >= 1, no
// cell twice). Throws InputError naming the cell.
void validate_plan(const std::vector<PlannedCell>& cells, const std::string& where);

// The planned cells whose trials in `trials` are fewer than planned. A trial belongs to the planned
// cell with the same frequency, duty and stroke (relative difference below 1e-9).
std::vector<MissingCell> missing_cells(const std::vector<PlannedCell>& planned,
                                       const std::vector<TrialInfo>& trials);

// Whether a trial belongs to a planned cell (the comparison missing_cells uses).
bool same_cell(const PlannedCell& cell, double freq_hz, double duty, double stroke_m);

}  // namespace idm::recording
