#include "recording/dataset.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

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
#include <optional>
#include <stdexcept>
#include <string_view>
#include <system_error>
#include <unordered_map>
#include <utility>

#include "recording/durable_file.h"

namespace idm::recording {

namespace fs = std::filesystem;

namespace {

constexpr const char* kSweepFile = "sweep.csv";
constexpr const char* kStageFile = "stage.yaml";
constexpr const char* kTrialsDir = "trials";

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
constexpr std::array<const char*, kSweepColumnCount> kSweepColumns = {
    "trial", "freq_hz", "duty", "stroke_m", "cycles", "sample_rate_hz", "guide_pos_m", "file"};
constexpr std::array<const char*, 3> kTrialColumns = {"t_s", "xi_cmd_m", "x_m"};
constexpr double kInf = std::numeric_limits<double>::infinity();

// ---------------------------------------------------------------- numbers

// Shortest text that reads back to the same double.
std::string format_number(double value) {
  char buf[32];
  const auto [end, ec] = std::to_chars(buf, buf + sizeof buf, value);
  return ec == std::errc() ? std::string(buf, end) : std::string("?");
}

void append_number(std::string& out, double value) {
  char buf[32];
  const auto [end, ec] = std::to_chars(buf, buf + sizeof buf, value);
  out.append(buf, ec == std::errc() ? end : buf);
}

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

std::string read_text_file(const std::string& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw InputError(path + ": cannot open file (" + std::strerror(errno) + ")");
  struct stat info {};
  if (::fstat(fd, &info) != 0 || !S_ISREG(info.st_mode)) {
    ::close(fd);
    throw InputError(path + ": not a regular file");
  }
  std::string text(static_cast<std::size_t>(info.st_size), '\0');
  std::size_t got = 0;
  while (got < text.size()) {
    const ssize_t n = ::read(fd, text.data() + got, text.size() - got);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) {
      const int error = errno;
      ::close(fd);
      throw InputError(path + ": cannot read file (" + std::strerror(error) + ")");
    }
    if (n == 0) break;
    got += static_cast<std::size_t>(n);
  }
  ::close(fd);
  text.resize(got);
  return text;
}

bool is_blank(char c) {
  return c == ' ' || c == '\t';
}

std::string_view trim(std::string_view s) {
  while (!s.empty() && is_blank(s.front())) s.remove_prefix(1);
  while (!s.empty() && is_blank(s.back())) s.remove_suffix(1);
  return s;
}

// A CSV file read whole: a header line, then rows. Fields are separated by commas, trimmed of
// spaces and tabs, and may be quoted ("a,b", "say ""x""") within one line. CRLF or LF line
// endings, an optional UTF-8 byte order mark, trailing empty lines.
class CsvFile {
 public:
  explicit CsvFile(std::string path) : path_(std::move(path)), text_(read_text_file(path_)) {
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

// ---------------------------------------------------------------- checks (reader and writer)

struct Problem {
  const char* column;
  std::string message;
};

std::string in_quotes(const std::string& s) {
  return "'" + s + "'";
}

// Why `file` is not a path inside the dataset, or nothing.
std::optional<std::string> file_problem(const std::string& file) {
  if (file.empty()) return "empty path";
  const fs::path p(file);
  if (p.has_root_path())
    return in_quotes(file) + " is an absolute path, expected a path relative to the dataset";
  for (const fs::path& part : p)
    if (part == "..") return in_quotes(file) + " leaves the dataset directory ('..')";
  if (p.filename().empty() || p.filename() == ".")
    return in_quotes(file) + " names a directory, expected a file";
  return std::nullopt;
}

std::optional<Problem> range_problem(const char* column, double value, double lo, double hi,
                                     bool hi_open, const char* allowed) {
  if (std::isfinite(value) && value > lo && (hi_open ? value < hi : value <= hi))
    return std::nullopt;
  if (!std::isfinite(value)) return Problem{column, format_number(value) + " is not finite"};
  return Problem{column, format_number(value) + " is out of range, allowed " + allowed};
}

// The first value of a row that the format does not allow, or nothing.
std::optional<Problem> trial_problem(const TrialInfo& t) {
  if (trim(t.id).empty()) return Problem{"trial", "empty trial id"};
  if (t.id.find_first_of("\r\n") != std::string::npos)
    return Problem{"trial", "the trial id contains a line break"};
  if (auto p = range_problem("freq_hz", t.freq_hz, 0.0, kInf, true, "(0, inf)")) return p;
  if (auto p = range_problem("duty", t.duty, 0.0, 1.0, true, "(0, 1)")) return p;
  if (auto p = range_problem("stroke_m", t.stroke_m, 0.0, kInf, true, "(0, inf)")) return p;
  if (t.cycles < 1)
    return Problem{"cycles", std::to_string(t.cycles) + " is out of range, allowed >= 1"};
  if (auto p = range_problem("sample_rate_hz", t.sample_rate_hz, 0.0, kInf, true, "(0, inf)"))
    return p;
  if (!std::isfinite(t.guide_pos_m))
    return Problem{"guide_pos_m", format_number(t.guide_pos_m) + " is not finite"};
  if (t.file.find_first_of("\r\n") != std::string::npos)
    return Problem{"file", "the path contains a line break"};
  if (auto p = file_problem(t.file)) return Problem{"file", *p};
  return std::nullopt;
}

// CSV field as the reader will read it back: quoted when it has a comma, a quote or blanks at
// its ends (which an unquoted field loses).
void append_text_field(std::string& out, const std::string& text) {
  const bool needs_quotes = text.find_first_of(",\"") != std::string::npos ||
                            (!text.empty() && (is_blank(text.front()) || is_blank(text.back())));
  if (!needs_quotes) {
    out += text;
    return;
  }
  out.push_back('"');
  for (const char c : text) {
    if (c == '"') out.push_back('"');
    out.push_back(c);
  }
  out.push_back('"');
}

bool is_plain_file_name(const std::string& name) {
  if (name.empty() || name.front() == '.') return false;
  return std::all_of(name.begin(), name.end(), [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '.' ||
           c == '_' || c == '-' || c == '+';
  });
}

}  // namespace

// ---------------------------------------------------------------- reading

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
  out.stage = model::load_stage_file((fs::path(dir) / kStageFile).string(),
                                     {.strict = false, .require_dataset_keys = true});

  CsvFile csv((fs::path(dir) / kSweepFile).string());
  const auto col = csv.read_header(kSweepColumns);
  auto column_of = [&](const char* name) {
    for (std::size_t i = 0; i < kSweepColumnCount; ++i)
      if (std::strcmp(kSweepColumns[i], name) == 0) return col[i];
    return col[kTrial];
  };

  std::unordered_map<std::string, std::size_t> line_of_id;
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
  CsvFile csv(path);
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

// ---------------------------------------------------------------- writing

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

DatasetWriter::DatasetWriter(std::string dir, const model::StageFile& stage)
    : DatasetWriter(std::move(dir), stage, {}) {}

DatasetWriter::DatasetWriter(std::string dir, const model::StageFile& stage,
                             std::vector<PlannedCell> planned, std::string axis) {
  const fs::path root(dir);
  if (fs::exists(root / kSweepFile))
    throw InputError(dir +
                     ": already holds a sweep (sweep.csv); write a new sweep to a new "
                     "directory");
  model::validate(stage.stage, "stage");
  model::validate(stage.interferometer, "interferometer");
  validate_plan(planned, dir);
  planned_ = std::move(planned);
  axis_ = std::move(axis);
  dataset_.path = std::move(dir);
  dataset_.stage = stage;
  create_directory_durably(root);
  create_directory_durably(root / kTrialsDir);
  // stage.yaml first: once sweep.csv exists the dataset is complete.
  write_file_durably(root / kStageFile, model::to_yaml(stage));
  // The mark before sweep.csv: a dataset that has trials is never unmarked by accident.
  if (!planned_.empty()) write_plan(SweepStatus::InProgress, "");
  write_sweep_csv();
}

void DatasetWriter::write_plan(SweepStatus status, const std::string& note) const {
  write_file_durably(fs::path(dataset_.path) / kPlanFile, plan_yaml({status, planned_, note, axis_}));
}

void DatasetWriter::finish(SweepStatus status, const std::string& note) {
  if (status != SweepStatus::Complete && status != SweepStatus::Stopped)
    throw std::invalid_argument("DatasetWriter::finish: the status must be Complete or Stopped");
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
  write_file_durably(fs::path(dataset_.path) / kSweepFile, text);
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

  const std::size_t n = series.t_s.size();
  if (n == 0) reject("no samples");
  if (series.xi_cmd_m.size() != n || series.x_m.size() != n)
    reject("columns of different lengths (t_s " + std::to_string(n) + ", xi_cmd_m " +
           std::to_string(series.xi_cmd_m.size()) + ", x_m " + std::to_string(series.x_m.size()) +
           ")");
  for (std::size_t i = 0; i < n; ++i) {
    const struct {
      const char* name;
      double value;
    } values[] = {{"t_s", series.t_s[i]}, {"xi_cmd_m", series.xi_cmd_m[i]}, {"x_m", series.x_m[i]}};
    for (const auto& v : values)
      if (!std::isfinite(v.value))
        reject(std::string(v.name) + "[" + std::to_string(i) + "] is " + format_number(v.value) +
               ", not a finite number");
    if (i > 0 && !(series.t_s[i] > series.t_s[i - 1]))
      reject("t_s[" + std::to_string(i) + "] = " + format_number(series.t_s[i]) +
             " does not increase (t_s[" + std::to_string(i - 1) +
             "] = " + format_number(series.t_s[i - 1]) + ")");
  }

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
  const fs::path trial_path = fs::path(dataset_.path) / info.file;
  create_directory_durably(trial_path.parent_path());
  write_file_durably(trial_path, text);

  dataset_.trials.push_back(std::move(info));
  try {
    write_sweep_csv();
  } catch (...) {
    // sweep.csv still lists the trials before this one; the new trial file is not part of the
    // dataset, so it goes.
    dataset_.trials.pop_back();
    std::error_code ignored;
    fs::remove(trial_path, ignored);
    throw;
  }
  ids_.insert(dataset_.trials.back().id);
  files_.insert(normal_file);
  return dataset_.trials.back();
}

}  // namespace idm::recording
