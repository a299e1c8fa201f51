// The sweep as cells of the (frequency, duty, stroke) map: the features of every trial, a split
// into training and held-out trials, the sensor's noise read from the data, and the sample instants
// a model is read at (forward_model.h), so that measurement and model are compared by one
// procedure.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "analysis/trial_features.h"
#include "model/stage.h"
#include "recording/dataset.h"

namespace idm::analysis {

struct CellKey {
  double freq_hz = 0, duty = 0, stroke_m = 0;
  bool operator==(const CellKey&) const = default;
};

struct Cell {
  CellKey key;
  int cycles = 0;
  double sample_rate_hz = 0;
  std::vector<double> read_t_s;  // sample instants of the rest readings (read_instants, 1st trial)
  std::vector<TrialFeatures> train, test;  // even trials train, odd trials are held out
  model::Region measured_region = model::Region::Cutoff;  // committee vote over all trials
  model::Region train_region = model::Region::Cutoff;     // vote of the training trials
  model::Region test_region = model::Region::Cutoff;      // vote of the held-out trials
};

// A trial left out of the diagnosis: its file could not be read (damaged, cut short, too large) or
// does not cover its burst.
struct LeftOutTrial {
  std::string file;  // DATASET/trials/...
  std::string why;   // one line starting with the file: the reader's message (line, column)
};

// What idm-gap diagnoses at most, checked from sweep.csv before a trial file is read (a larger
// sweep is refused naming sweep.csv and the limit): cells (the fit's work grows with them: 80
// cells take 9-150 s, bench/README.md), the rest readings its trials' features hold (cycles + 2 a
// trial, 8 bytes each), and the bytes of its trial files (each read twice, one at a time).
inline constexpr std::size_t kMaxDiagnosedCells = 1000;
inline constexpr std::uintmax_t kMaxHeldReadings = std::uintmax_t{1} << 25;
inline constexpr std::uintmax_t kMaxDiagnosedBytes = std::uintmax_t{4} << 30;

struct SweepCells {
  std::vector<Cell> cells;
  double resolution_m = 0;
  // one position reading: noise and quantization, from the samples at rest (or, with none, from
  // the bursts' second differences)
  double reading_sd_m = 0;
  double noise_m = 0;  // the sensor's noise without quantization (reading_sd_m less one count's)
  std::string name;    // the dataset's path as given (messages, the report)
  model::StageFile stage;
  // The recorder's mark (recording/sweep_plan.h): Unmarked for data from elsewhere;
  // progress.missing lists every planned cell short of its trials. A sweep is diagnosed on the
  // cells it has (`skipped`: cells with fewer trials than a diagnosis needs, left out).
  recording::SweepProgress progress;
  std::vector<CellKey> skipped;
  std::vector<std::size_t> skipped_trials;  // the trials each skipped cell has
  std::vector<LeftOutTrial> damaged;        // trials left out (read from files only), in file order
  int min_trials = 3;                       // the trials a cell needs
};

// Reads every trial and groups them: first checks the sweep against what a diagnosis takes
// (kMaxDiagnosedCells, kMaxHeldReadings, kMaxDiagnosedBytes; InputError naming sweep.csv), then
// streams the trial files twice, one at a time (the noise, then each trial's features), holding
// only features. A trial whose file cannot be read (each error names its file, line and column) or
// does not cover its burst is left out and listed in `damaged`. A cell with fewer than
// `min_trials` trials is left out and listed in `skipped` (a sweep the recorder cut off, or a lab's
// writer that dropped a trial: the format sets no number of trials a cell); a sweep with no cell
// left is refused (InputError: "the sweep is too small to diagnose: ...").
SweepCells collect_cells(const Dataset& dataset, int min_trials = 3);

// The same from a sweep held in memory (validate, tests): trials[i] is the time series of infos[i].
// `name` stands for the dataset's path in messages; `skip_small` leaves out cells with fewer than
// `min_trials` trials instead of refusing the sweep.
SweepCells collect_cells(const model::StageFile& stage, const std::vector<TrialInfo>& infos,
                         const std::vector<TrialSeries>& trials, const std::string& name,
                         int min_trials = 3, bool skip_small = false);

// For a sweep the recorder marked: whether it was cut off, which planned cells are missing or
// short of trials, and which cells the diagnosis left out (a few lines, each ending in a newline);
// for an unmarked sweep the cells left out (one line). "" for a complete sweep with every planned
// trial and for an unmarked one with no cell left out.
std::string progress_summary(const SweepCells& sweep);

}  // namespace idm::analysis
