// The sweep dataset of docs/sweep-dataset.md: reading it (from the daemon, the simulated stage or
// anywhere else) and writing it crash-safe, one trial at a time.
//
//   DATASET/sweep.csv      one row per trial (TrialInfo)
//   DATASET/stage.yaml     nominal stage parameters (model::StageFile)
//   DATASET/trials/*.csv   one time series per trial (TrialSeries)
//   DATASET/plan.yaml      optional: the recorder's plan and how the recording ended
//                          (sweep_plan.h; an extension of the format, recording/README.md)
//
// Every error in the input is a model::InputError that names the file, the line and the column:
// "DATASET/trials/x.csv:17:3 (x_m): 'nan' is not a finite number".
#pragma once

#include <cstddef>
#include <string>
#include <unordered_set>
#include <vector>

#include "model/stage.h"
#include "recording/durable_file.h"
#include "recording/sweep_plan.h"

namespace idm::recording {

using model::InputError;

// One row of sweep.csv.
struct TrialInfo {
  std::string id;               // column `trial`: unique id of the trial
  double freq_hz = 0.0;         // waveform frequency f = 1/T, > 0
  double duty = 0.0;            // duty ratio of the extension phase, 0 < duty < 1
  double stroke_m = 0.0;        // commanded stroke S, > 0
  int cycles = 0;               // triangular cycles commanded, >= 1
  double sample_rate_hz = 0.0;  // sample rate of the trial file, > 0
  double guide_pos_m = 0.0;     // interferometer position of the slider when the trial started
  std::string file;             // trial file, relative to DATASET/ (stays inside it)
};

// One trial file: equal-length columns, t_s strictly increasing, every value finite.
struct TrialSeries {
  std::vector<double> t_s;       // time; 0 is the start of the first extension phase
  std::vector<double> xi_cmd_m;  // commanded actuator elongation
  std::vector<double> x_m;       // slider position from the interferometer (absolute)

  std::size_t size() const { return t_s.size(); }
};

struct Dataset {
  std::string path;               // DATASET/ as given
  model::StageFile stage;         // stage.yaml
  std::vector<TrialInfo> trials;  // sweep.csv, in file order
  SweepProgress progress;         // plan.yaml against sweep.csv (Unmarked without plan.yaml)

  // path/trials[index].file
  std::string trial_path(std::size_t index) const;
};

// Reads sweep.csv and stage.yaml and checks that every trial file exists; the trial files
// themselves are read on demand by read_trial. With a plan.yaml, `progress` says whether the
// recording was interrupted and which planned cells have fewer trials than planned; without one it
// is Unmarked and nothing else changes. Throws InputError.
Dataset read_dataset(const std::string& dir);

// Reads the time series of dataset.trials[index]. Throws InputError (std::out_of_range for a bad
// index).
TrialSeries read_trial(const Dataset& dataset, std::size_t index);

// Reads one trial file by path (header with t_s, xi_cmd_m, x_m in any order; extra columns
// ignored). Throws InputError.
TrialSeries read_trial_file(const std::string& path);

// The name a trial gets when the writer chooses it, like the sample's "f100_d0.050_s20.35um_t0":
// frequency (shortest fixed notation), duty to 3 decimals, stroke in um to 2 decimals, trial index.
std::string trial_name(double freq_hz, double duty, double stroke_m, int index);

// Writes a dataset trial by trial. The constructor creates DATASET/ and DATASET/trials/ and writes
// stage.yaml and a sweep.csv with no rows; add_trial writes the trial file, then rewrites
// sweep.csv. Every file is written to a temporary name in its directory, fsynced, renamed over the
// final name and the directory fsynced, so an interrupted sweep leaves a valid dataset of the
// trials that finished, and a failed write leaves the previous files as they were.
// Numbers are written in the shortest form that reads back to the same double.
//
// Bad arguments (out-of-range values, non-finite samples, a repeated id) throw InputError before
// anything is written; file system failures throw std::system_error naming the file.
//
// With a plan (the second constructor) the writer also marks the dataset (sweep_plan.h): plan.yaml
// says `in_progress` from before the first trial until finish() rewrites it, so a sweep that never
// reaches finish() (SIGKILL, a crash, a power loss) reads back as interrupted, with its missing
// cells. The daemon's recorder:
//
//   DatasetWriter w(dir, stage, planned_cells, axis_name);   // every (f, duty, stroke) the sweep
//   will play,
//                                                 // with the values its trials will carry
//   for each trial: w.add_trial(info, series);    // failed trials are simply not added
//   w.finish(SweepStatus::Complete);              // or Stopped with a note ("STOP", an error)
class DatasetWriter {
 public:
  // `dir` may exist but must not already hold a sweep.csv. No mark: the dataset looks like one
  // from any other source (finish() does nothing).
  DatasetWriter(const std::string& dir, const model::StageFile& stage);
  // Marks the dataset in progress with `planned` (checked first: InputError for a bad cell);
  // `axis`, when not empty, is the name of the axis that plays the sweep (plan.yaml's `axis`).
  DatasetWriter(const std::string& dir, const model::StageFile& stage,
                const std::vector<PlannedCell>& planned, std::string axis = "");
  // The same into a directory already held open (the daemon's: created below its data_dir with
  // openat, so that nothing another user swaps into the path afterwards is followed); `shown` is
  // its path for messages and Dataset::path. Every file is written relative to it.
  DatasetWriter(DirFd dir, std::string shown, const model::StageFile& stage,
                std::vector<PlannedCell> planned, std::string axis = "");

  DatasetWriter(const DatasetWriter&) = delete;
  DatasetWriter& operator=(const DatasetWriter&) = delete;
  DatasetWriter(DatasetWriter&&) = default;
  DatasetWriter& operator=(DatasetWriter&&) = default;
  ~DatasetWriter() = default;

  // Adds one trial. An empty info.id becomes trial_name(f, duty, stroke, next free index); an
  // empty info.file becomes "trials/<id>.csv" (the id must then be a plain file name).
  // Returns the row as written to sweep.csv (valid until the next add_trial).
  const TrialInfo& add_trial(TrialInfo info, const TrialSeries& series);

  // Ends the recording: plan.yaml gets `status` (Complete, Stopped or Failed; `note`, one line,
  // says why a sweep stopped or failed). Once finished, add_trial throws std::logic_error. Without
  // a plan, only that.
  void finish(SweepStatus status = SweepStatus::Complete, const std::string& note = "");
  bool finished() const { return finished_; }

  // What has been written so far (read_trial works on it).
  const Dataset& dataset() const { return dataset_; }

 private:
  static DirFd open_root(const std::string& dir, const model::StageFile& stage,
                         const std::vector<PlannedCell>& planned);
  void write_sweep_csv() const;
  void write_plan(SweepStatus status, const std::string& note) const;

  DirFd dir_;
  Dataset dataset_;
  std::unordered_set<std::string> ids_;    // ids in dataset_.trials
  std::unordered_set<std::string> files_;  // their files, lexically normalized
  std::vector<PlannedCell> planned_;       // empty: no mark
  std::string axis_;                       // plan.yaml's axis ("" none)
  bool finished_ = false;
};

}  // namespace idm::recording
