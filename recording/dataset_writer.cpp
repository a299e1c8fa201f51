// DatasetWriter: a dataset written crash-safe, trial by trial (dataset.h).
#include <fcntl.h>
#include <sys/stat.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <optional>
#include <stdexcept>
#include <string>
#include <system_error>
#include <utility>

#include "recording/dataset.h"
#include "recording/dataset_format.h"
#include "recording/durable_file.h"

namespace idm::recording {

namespace fs = std::filesystem;
using namespace format;  // the parts of the format the reader and the writer share

namespace {

// Why a trial's time series cannot be written, or nothing: no samples, columns of different
// lengths, a value that is not finite, a time that does not increase.
std::optional<std::string> series_problem(const TrialSeries& series) {
  const std::size_t n = series.t_s.size();
  if (n == 0) return "no samples";
  if (series.xi_cmd_m.size() != n || series.x_m.size() != n)
    return "columns of different lengths (t_s " + std::to_string(n) + ", xi_cmd_m " +
           std::to_string(series.xi_cmd_m.size()) + ", x_m " + std::to_string(series.x_m.size()) +
           ")";
  for (std::size_t i = 0; i < n; ++i) {
    const struct {
      const char* name;
      double value;
    } values[] = {{"t_s", series.t_s[i]}, {"xi_cmd_m", series.xi_cmd_m[i]}, {"x_m", series.x_m[i]}};
    for (const auto& v : values)
      if (!std::isfinite(v.value))
        return std::string(v.name) + "[" + std::to_string(i) + "] is " + format_number(v.value) +
               ", not a finite number";
    if (i > 0 && !(series.t_s[i] > series.t_s[i - 1]))
      return "t_s[" + std::to_string(i) + "] = " + format_number(series.t_s[i]) +
             " does not increase (t_s[" + std::to_string(i - 1) +
             "] = " + format_number(series.t_s[i - 1]) + ")";
  }
  return std::nullopt;
}

// A trial file's text: the header, then t_s, xi_cmd_m and x_m per sample.
std::string trial_csv(const TrialSeries& series) {
  const std::size_t n = series.t_s.size();
  std::string text =
      std::string(kTrialColumns[0]) + "," + kTrialColumns[1] + "," + kTrialColumns[2] + "\n";
  text.reserve(text.size() + n * 64);
  for (std::size_t i = 0; i < n; ++i) {
    append_number(text, series.t_s[i]);
    text.push_back(',');
    append_number(text, series.xi_cmd_m[i]);
    text.push_back(',');
    append_number(text, series.x_m[i]);
    text.push_back('\n');
  }
  return text;
}

}  // namespace

std::string trial_name(double freq_hz, double duty, double stroke_m, int index) {
  // Fixed notation ("100", "2500.5") unless the frequency is too large or small for it.
  char fixed[64];
  const auto [end, ec] =
      std::to_chars(fixed, fixed + sizeof fixed, freq_hz, std::chars_format::fixed);
  const std::string freq = ec == std::errc() ? std::string(fixed, end) : format_number(freq_hz);
  char name[160];
  std::snprintf(name, sizeof name, "f%s_d%.3f_s%.2fum_t%d", freq.c_str(), duty, stroke_m * 1e6,
                index);
  return name;
}

DatasetWriter::DatasetWriter(const std::string& dir, const model::StageFile& stage)
    : DatasetWriter(dir, stage, {}) {}

DatasetWriter::DatasetWriter(const std::string& dir, const model::StageFile& stage,
                             const std::vector<PlannedCell>& planned, std::string axis)
    : DatasetWriter(open_root(dir, stage, planned), dir, stage, planned, std::move(axis)) {}

// Checked before the directory is made: a bad stage or plan leaves nothing behind.
DirFd DatasetWriter::open_root(const std::string& dir, const model::StageFile& stage,
                               const std::vector<PlannedCell>& planned) {
  model::validate(stage.stage, "stage");
  model::validate(stage.interferometer, "interferometer");
  validate_plan(planned, dir);
  create_directory_durably(dir);
  return DirFd::open(dir);
}

DatasetWriter::DatasetWriter(DirFd dir, std::string shown, const model::StageFile& stage,
                             std::vector<PlannedCell> planned, std::string axis)
    : dir_(std::move(dir)) {
  struct stat st {};
  if (::fstatat(dir_.get(), kSweepFile, &st, AT_SYMLINK_NOFOLLOW) == 0)
    throw InputError(shown +
                     ": already holds a sweep (sweep.csv); write a new sweep to a new "
                     "directory");
  model::validate(stage.stage, "stage");
  model::validate(stage.interferometer, "interferometer");
  validate_plan(planned, shown);
  planned_ = std::move(planned);
  axis_ = std::move(axis);
  dataset_.path = std::move(shown);
  dataset_.stage = stage;
  open_directory_at(dir_, kTrialsDir, dataset_.path);
  // stage.yaml first: once sweep.csv exists the dataset is complete.
  write_file_durably_at(dir_, kStageFile, model::to_yaml(stage), dataset_.path);
  // The mark before sweep.csv: a dataset that has trials is never unmarked by accident.
  if (!planned_.empty()) write_plan(SweepStatus::InProgress, "");
  write_sweep_csv();
}

void DatasetWriter::write_plan(SweepStatus status, const std::string& note) const {
  write_file_durably_at(dir_, kPlanFile, plan_yaml({status, planned_, note, axis_}), dataset_.path);
}

void DatasetWriter::finish(SweepStatus status, const std::string& note) {
  if (status != SweepStatus::Complete && status != SweepStatus::Stopped &&
      status != SweepStatus::Failed)
    throw std::invalid_argument(
        "DatasetWriter::finish: the status must be Complete, Stopped or Failed");
  if (finished_) throw std::logic_error("DatasetWriter::finish: " + dataset_.path + " is finished");
  if (!planned_.empty()) write_plan(status, note);
  finished_ = true;
}

void DatasetWriter::write_sweep_csv() const {
  std::string text;
  for (const char* name : kSweepColumns) text += (text.empty() ? "" : ",") + std::string(name);
  text.push_back('\n');
  for (const TrialInfo& t : dataset_.trials) {
    append_text_field(text, t.id);
    for (const double v : {t.freq_hz, t.duty, t.stroke_m}) {
      text.push_back(',');
      append_number(text, v);
    }
    text += ',' + std::to_string(t.cycles);
    for (const double v : {t.sample_rate_hz, t.guide_pos_m}) {
      text.push_back(',');
      append_number(text, v);
    }
    text.push_back(',');
    append_text_field(text, t.file);
    text.push_back('\n');
  }
  write_file_durably_at(dir_, kSweepFile, text, dataset_.path);
}

const TrialInfo& DatasetWriter::add_trial(TrialInfo info, const TrialSeries& series) {
  if (finished_)
    throw std::logic_error("DatasetWriter::add_trial: " + dataset_.path + " is finished");
  auto reject = [&](const std::string& what) {
    throw InputError(dataset_.path + ": trial " + in_quotes(info.id) + ": " + what);
  };
  if (info.id.empty()) {
    for (int k = 0;; ++k) {
      info.id = trial_name(info.freq_hz, info.duty, info.stroke_m, k);
      if (!ids_.count(info.id)) break;
    }
  }
  if (info.file.empty()) {
    if (!is_plain_file_name(info.id))
      reject(
          "cannot name a file after this id; give info.file or an id of letters, digits, "
          "'.', '_', '-', '+'");
    info.file = std::string(kTrialsDir) + "/" + info.id + ".csv";
  }
  if (auto p = trial_problem(info)) reject(std::string(p->column) + ": " + p->message);
  if (ids_.count(info.id)) reject("the id is already in the dataset");
  if (!planned_.empty() &&
      std::none_of(planned_.begin(), planned_.end(), [&](const PlannedCell& c) {
        return same_cell(c, info.freq_hz, info.duty, info.stroke_m);
      }))
    reject("(" + format_number(info.freq_hz) + " Hz, duty " + format_number(info.duty) +
           ", stroke " + format_number(info.stroke_m) +
           " m) is not a planned cell; the plan must hold the values the trials carry");
  const std::string normal_file = fs::path(info.file).lexically_normal().string();
  if (files_.count(normal_file))
    reject("file " + in_quotes(info.file) + " already belongs to another trial");

  if (auto p = series_problem(series)) reject(*p);
  const std::string text = trial_csv(series);
  write_file_durably_at(dir_, normal_file, text, dataset_.path);

  dataset_.trials.push_back(std::move(info));
  try {
    write_sweep_csv();
  } catch (...) {
    // sweep.csv still lists the trials before this one; the new trial file is not part of the
    // dataset, so it goes.
    dataset_.trials.pop_back();
    remove_file_at(dir_, normal_file);
    throw;
  }
  ids_.insert(dataset_.trials.back().id);
  files_.insert(normal_file);
  return dataset_.trials.back();
}

}  // namespace idm::recording
