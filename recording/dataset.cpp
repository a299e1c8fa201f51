// The dataset reader: read_dataset, read_trial (dataset.h); the writer is dataset_writer.cpp.
#include "recording/dataset.h"

#include <algorithm>
#include <array>
#include <cerrno>
#include <charconv>
#include <climits>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <deque>
#include <filesystem>
#include <limits>
#include <map>
#include <optional>
#include <stdexcept>
#include <string_view>
#include <system_error>
#include <unordered_map>
#include <utility>

#include "model/yaml_util.h"
#include "recording/dataset_format.h"
#include "recording/dataset_limits.h"

namespace idm::recording {

namespace fs = std::filesystem;
using namespace format;  // the parts of the format the reader and the writer share

namespace {

enum class NumberStatus { Ok, Empty, NotNumber, NotFinite };

// Any decimal or exponent form ("20", "2.035e-05", "+.5", "1E3"). Field already trimmed.
NumberStatus parse_number(std::string_view text, double& value) {
  if (text.empty()) return NumberStatus::Empty;
  const char* first = text.data();
  const char* last = first + text.size();
  if (*first == '+') {
    ++first;
    if (first == last || *first == '+' || *first == '-') return NumberStatus::NotNumber;
  }
  auto [end, ec] = std::from_chars(first, last, value, std::chars_format::general);
  if (ec == std::errc::result_out_of_range) {
    // Below the smallest double (1e-400) reads as 0; beyond the largest it is not finite.
    long double wide = 0.0L;
    const auto [wide_end, wide_ec] = std::from_chars(first, last, wide, std::chars_format::general);
    if (wide_ec != std::errc() || wide_end != last || !(std::fabs(wide) < 1.0L))
      return NumberStatus::NotFinite;
    value = static_cast<double>(wide);
    end = wide_end;
    ec = wide_ec;
  }
  if (ec != std::errc() || end != last) return NumberStatus::NotNumber;
  if (!std::isfinite(value)) return NumberStatus::NotFinite;
  return NumberStatus::Ok;
}

std::string number_problem(NumberStatus status, std::string_view text) {
  switch (status) {
    case NumberStatus::Empty:
      return "empty value, expected a number";
    case NumberStatus::NotNumber:
      return "'" + std::string(text) + "' is not a number";
    case NumberStatus::NotFinite:
      return "'" + std::string(text) + "' is not a finite number";
    case NumberStatus::Ok:
      break;
  }
  return {};
}

// ---------------------------------------------------------------- CSV

// A CSV file read whole: a header line, then rows. Fields are separated by commas, trimmed of
// spaces and tabs, and may be quoted ("a,b", "say ""x""") within one line. CRLF or LF line
// endings, an optional UTF-8 byte order mark, trailing empty lines.
class CsvFile {
 public:
  CsvFile(std::string path, std::size_t max_bytes)
      : path_(std::move(path)), text_(model::read_regular_file(path_, max_bytes)) {
    if (std::string_view(text_).substr(0, 3) == "\xEF\xBB\xBF") pos_ = 3;
  }

  const std::string& path() const { return path_; }
  const std::string& text() const { return text_; }

  // Moves to the next row; false at the end of the data.
  bool next_row() {
    while (pos_ < text_.size()) {
      const std::size_t nl = text_.find('\n', pos_);
      const std::size_t end = nl == std::string::npos ? text_.size() : nl;
      std::string_view line(text_.data() + pos_, end - pos_);
      pos_ = nl == std::string::npos ? text_.size() : nl + 1;
      ++line_;
      if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
      if (trim(line).empty()) {
        if (rest_is_blank()) {
          pos_ = text_.size();
          return false;
        }
        fail_line("empty line before the end of the data");
      }
      split(line);
      return true;
    }
    return false;
  }

  std::size_t line() const { return line_; }
  const std::vector<std::string_view>& fields() const { return fields_; }

  // Reads the header: the index of each required column, in the order given. Other columns
  // are ignored.
  template <std::size_t N>
  std::array<std::size_t, N> read_header(const std::array<const char*, N>& required) {
    if (!next_row()) throw InputError(path_ + ":1: empty file, expected a header line");
    header_names_.assign(fields_.begin(), fields_.end());
    const std::size_t none = header_names_.size();
    std::array<std::size_t, N> index;
    for (std::size_t r = 0; r < N; ++r) {
      index[r] = none;
      for (std::size_t c = 0; c < header_names_.size(); ++c) {
        if (header_names_[c] != required[r]) continue;
        if (index[r] != none)
          fail(c, "column '" + header_names_[c] + "' appears twice (also column " +
                      std::to_string(index[r] + 1) + ")");
        index[r] = c;
      }
      if (index[r] == none) {
        std::string list;
        for (const char* name : required) list += (list.empty() ? "" : ", ") + std::string(name);
        fail_line("missing required column '" + std::string(required[r]) + "' (required: " + list +
                  ")");
      }
    }
    return index;
  }

  // Checks that the current row has one field per header column.
  void check_field_count() const {
    const std::size_t n = fields_.size();
    const std::size_t want = header_names_.size();
    if (n < want)
      fail(n, "missing value (the row has " + std::to_string(n) + " fields, the header " +
                  std::to_string(want) + ")");
    if (n > want)
      fail(want,
           "the row has " + std::to_string(n) + " fields, the header " + std::to_string(want));
  }

  double number(std::size_t column) const {
    double value = 0.0;
    const NumberStatus status = parse_number(fields_[column], value);
    if (status != NumberStatus::Ok) fail(column, number_problem(status, fields_[column]));
    return value;
  }

  // "PATH:LINE:COLUMN (NAME): MESSAGE" (column 0-based here, 1-based in the text).
  [[noreturn]] void fail(std::size_t column, const std::string& message) const {
    std::string where = path_ + ":" + std::to_string(line_) + ":" + std::to_string(column + 1);
    if (column < header_names_.size()) where += " (" + header_names_[column] + ")";
    throw InputError(where + ": " + message);
  }

  [[noreturn]] void fail_line(const std::string& message) const {
    throw InputError(path_ + ":" + std::to_string(line_) + ": " + message);
  }

 private:
  bool rest_is_blank() const {
    for (std::size_t i = pos_; i < text_.size(); ++i) {
      const char c = text_[i];
      if (!is_blank(c) && c != '\r' && c != '\n') return false;
    }
    return true;
  }

  void split(std::string_view line) {
    fields_.clear();
    unquoted_.clear();
    std::size_t i = 0;
    for (;;) {
      std::size_t start = i;
      while (start < line.size() && is_blank(line[start])) ++start;
      std::size_t next = 0;  // index of the separator after the field, or line.size()
      if (start < line.size() && line[start] == '"') {
        std::string value;
        bool escaped = false;
        std::size_t j = start + 1;
        for (;;) {
          const std::size_t q = line.find('"', j);
          if (q == std::string_view::npos)
            fail(fields_.size(), "unterminated quote (a field cannot span lines)");
          value.append(line.substr(j, q - j));
          if (q + 1 < line.size() && line[q + 1] == '"') {
            value.push_back('"');
            escaped = true;
            j = q + 2;
            continue;
          }
          j = q + 1;
          break;
        }
        while (j < line.size() && is_blank(line[j])) ++j;
        if (j < line.size() && line[j] != ',')
          fail(fields_.size(), "unexpected text after the closing quote");
        if (escaped) {
          unquoted_.push_back(std::move(value));
          fields_.push_back(unquoted_.back());
        } else {
          const std::size_t len = value.size();
          fields_.push_back(line.substr(start + 1, len));
        }
        next = j;
      } else {
        next = std::min(line.find(',', start), line.size());
        fields_.push_back(trim(line.substr(start, next - start)));
      }
      if (next >= line.size()) break;
      i = next + 1;
    }
  }

  std::string path_;
  std::string text_;
  std::size_t pos_ = 0;
  std::size_t line_ = 0;
  std::vector<std::string_view> fields_;
  std::deque<std::string> unquoted_;  // fields that had "" escapes (stable addresses)
  std::vector<std::string> header_names_;
};

}  // namespace

std::string Dataset::trial_path(std::size_t index) const {
  return (fs::path(path) / trials.at(index).file).string();
}

Dataset read_dataset(const std::string& dir) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec))
    throw InputError(dir + ": not a dataset directory (" +
                     (fs::exists(dir, ec) ? "not a directory" : "does not exist") + ")");
  Dataset out;
  out.path = dir;
  const std::string stage_path = (fs::path(dir) / kStageFile).string();
  out.stage = model::parse_stage_yaml(
      model::load_yaml_file(stage_path, {kMaxYamlFileBytes, model::YamlLimits{}.max_nodes}),
      stage_path, {.strict = false, .require_dataset_keys = true});

  CsvFile csv((fs::path(dir) / kSweepFile).string(), kMaxSweepFileBytes);
  const auto col = csv.read_header(kSweepColumns);
  auto column_of = [&](const char* name) {
    for (std::size_t i = 0; i < kSweepColumnCount; ++i)
      if (std::strcmp(kSweepColumns[i], name) == 0) return col[i];
    return col[kTrial];
  };

  std::unordered_map<std::string, std::size_t> line_of_id;
  std::map<std::array<double, 3>, int> trials_of_cell;
  while (csv.next_row()) {
    csv.check_field_count();
    const auto& f = csv.fields();
    TrialInfo t;
    t.id = std::string(f[col[kTrial]]);
    t.freq_hz = csv.number(col[kFreq]);
    t.duty = csv.number(col[kDuty]);
    t.stroke_m = csv.number(col[kStroke]);
    const double cycles = csv.number(col[kCycles]);
    if (cycles != std::floor(cycles) || cycles < INT_MIN || cycles > INT_MAX)
      csv.fail(col[kCycles], "'" + std::string(f[col[kCycles]]) + "' is not a whole number");
    t.cycles = static_cast<int>(cycles);
    t.sample_rate_hz = csv.number(col[kRate]);
    t.guide_pos_m = csv.number(col[kGuide]);
    t.file = std::string(f[col[kFile]]);
    if (auto p = trial_problem(t)) csv.fail(column_of(p->column), p->message);

    const auto [it, inserted] = line_of_id.emplace(t.id, csv.line());
    if (!inserted)
      csv.fail(col[kTrial],
               in_quotes(t.id) + " repeats the trial id of line " + std::to_string(it->second));
    const fs::path trial_file = fs::path(dir) / t.file;
    if (!fs::exists(trial_file, ec))
      csv.fail(col[kFile], in_quotes(t.file) + " does not exist (" + trial_file.string() + ")");
    if (!fs::is_regular_file(trial_file, ec))
      csv.fail(col[kFile], in_quotes(t.file) + " is not a regular file");
    if (++trials_of_cell[{t.freq_hz, t.duty, t.stroke_m}] > kMaxTrialsPerCell)
      csv.fail(col[kTrial], "more than " + std::to_string(kMaxTrialsPerCell) +
                                " trials of one cell (" + format_number(t.freq_hz) + " Hz, duty " +
                                format_number(t.duty) + ", stroke " + format_number(t.stroke_m) +
                                " m), allowed at most " + std::to_string(kMaxTrialsPerCell));
    out.trials.push_back(std::move(t));
  }
  const fs::path plan_path = fs::path(dir) / kPlanFile;
  if (fs::exists(plan_path, ec)) {
    const SweepPlanFile plan = read_plan_file(plan_path.string());
    out.progress.status = plan.status;
    out.progress.planned = plan.cells;
    out.progress.note = plan.note;
    out.progress.axis = plan.axis;
    out.progress.missing = missing_cells(plan.cells, out.trials);
  }
  return out;
}

TrialSeries read_trial_file(const std::string& path) {
  CsvFile csv(path, kMaxTrialFileBytes);
  const auto col = csv.read_header(kTrialColumns);
  TrialSeries out;
  const std::size_t lines =
      static_cast<std::size_t>(std::count(csv.text().begin(), csv.text().end(), '\n'));
  out.t_s.reserve(lines);
  out.xi_cmd_m.reserve(lines);
  out.x_m.reserve(lines);
  std::string_view previous_t;  // the previous row's t_s as written (views into the file text)
  while (csv.next_row()) {
    csv.check_field_count();
    const double t = csv.number(col[0]);
    if (!out.t_s.empty() && !(t > out.t_s.back()))
      csv.fail(col[0], "time " + std::string(csv.fields()[col[0]]) +
                           " does not increase (previous row: " + std::string(previous_t) + ")");
    previous_t = csv.fields()[col[0]];
    out.t_s.push_back(t);
    out.xi_cmd_m.push_back(csv.number(col[1]));
    out.x_m.push_back(csv.number(col[2]));
  }
  if (out.t_s.empty()) throw InputError(path + ":2: no samples after the header");
  return out;
}

TrialSeries read_trial(const Dataset& dataset, std::size_t index) {
  if (index >= dataset.trials.size())
    throw std::out_of_range("read_trial: index " + std::to_string(index) + " of " +
                            std::to_string(dataset.trials.size()) + " trials");
  return read_trial_file(dataset.trial_path(index));
}

}  // namespace idm::recording
