#include "recording/dataset_format.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <system_error>

#include "recording/dataset_limits.h"

namespace idm::recording::format {

namespace fs = std::filesystem;

namespace {

// A value of `column` outside (lo, hi] ((lo, hi) when hi_open), or not finite; `allowed` says
// the range in the message.
std::optional<Problem> range_problem(const char* column, double value, double lo, double hi,
                                     bool hi_open, const char* allowed) {
  if (std::isfinite(value) && value > lo && (hi_open ? value < hi : value <= hi))
    return std::nullopt;
  if (!std::isfinite(value)) return Problem{column, format_number(value) + " is not finite"};
  return Problem{column, format_number(value) + " is out of range, allowed " + allowed};
}

}  // namespace

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

std::string in_quotes(const std::string& s) {
  return "'" + s + "'";
}

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

std::optional<Problem> range_problem(const char* column, double value, const model::Range& range) {
  if (range.contains(value)) return std::nullopt;
  if (!std::isfinite(value)) return Problem{column, format_number(value) + " is not finite"};
  return Problem{column, format_number(value) + " is out of range, allowed " + range.text()};
}

std::optional<Problem> trial_problem(const TrialInfo& t) {
  if (trim(t.id).empty()) return Problem{"trial", "empty trial id"};
  if (t.id.find_first_of("\r\n") != std::string::npos)
    return Problem{"trial", "the trial id contains a line break"};
  if (auto p = range_problem("freq_hz", t.freq_hz, kFreqRangeHz)) return p;
  if (auto p = range_problem("duty", t.duty, 0.0, 1.0, true, "(0, 1)")) return p;
  if (auto p = range_problem("stroke_m", t.stroke_m, model::stage_key_range("stroke_m"))) return p;
  if (t.cycles < 1 || t.cycles > kMaxCycles)
    return Problem{"cycles", std::to_string(t.cycles) + " is out of range, allowed [1, " +
                                 std::to_string(kMaxCycles) + "]"};
  if (auto p = range_problem("sample_rate_hz", t.sample_rate_hz, kSampleRateRangeHz)) return p;
  if (!std::isfinite(t.guide_pos_m))
    return Problem{"guide_pos_m", format_number(t.guide_pos_m) + " is not finite"};
  if (t.file.find_first_of("\r\n") != std::string::npos)
    return Problem{"file", "the path contains a line break"};
  if (auto p = file_problem(t.file)) return Problem{"file", *p};
  return std::nullopt;
}

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

}  // namespace idm::recording::format
