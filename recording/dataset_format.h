// The parts of the dataset format that the reader (dataset.cpp) and the writer
// (dataset_writer.cpp) share: file and column names, numbers as text, the checks of a sweep.csv
// row. Internal to idm_recording.
#pragma once

#include <array>
#include <cstddef>
#include <optional>
#include <string>
#include <string_view>

#include "model/range.h"
#include "model/text_list.h"
#include "recording/dataset.h"

namespace idm::recording::format {

inline constexpr const char* kSweepFile = "sweep.csv";
inline constexpr const char* kStageFile = "stage.yaml";
inline constexpr const char* kTrialsDir = "trials";

// The columns of sweep.csv, in the order the writer writes them.
enum SweepColumn {
  kTrial,
  kFreq,
  kDuty,
  kStroke,
  kCycles,
  kRate,
  kGuide,
  kFile,
  kSweepColumnCount
};
inline constexpr std::array<const char*, kSweepColumnCount> kSweepColumns = {
    "trial", "freq_hz", "duty", "stroke_m", "cycles", "sample_rate_hz", "guide_pos_m", "file"};
inline constexpr std::array<const char*, 3> kTrialColumns = {"t_s", "xi_cmd_m", "x_m"};

// Shortest text that reads back to the same double; append_number: the same, appended to out.
std::string format_number(double value);
void append_number(std::string& out, double value);

// The blanks a CSV field is trimmed of: spaces and tabs.
using model::is_blank;
using model::trim;

std::string in_quotes(const std::string& s);

// A value the format does not allow: its column and why.
struct Problem {
  const char* column;
  std::string message;
};

// Why `file` is not a path inside the dataset, or nothing.
std::optional<std::string> file_problem(const std::string& file);
// A value outside `range` (recording/dataset_limits.h, the stage table), or nothing.
std::optional<Problem> range_problem(const char* column, double value, const model::Range& range);
// The first value of a row that the format does not allow, or nothing: the ranges of
// dataset_limits.h, the stage's stroke range.
std::optional<Problem> trial_problem(const TrialInfo& t);

// CSV field as the reader will read it back: quoted when it has a comma, a quote or blanks at
// its ends (which an unquoted field loses).
void append_text_field(std::string& out, const std::string& text);

// Letters, digits, '.', '_', '-', '+', not starting with '.': a trial id that names its file.
bool is_plain_file_name(const std::string& name);

}  // namespace idm::recording::format
