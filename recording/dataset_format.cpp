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

// "268435456 bytes (256 MiB)".
std::string bytes_text(std::size_t bytes) {
  return std::to_string(bytes) + " bytes (" + std::to_string(bytes >> 20) + " MiB)";
}

// Reads the rest of fd into out (already sized to the file's length); the file may have shrunk.
void read_all(int fd, const std::string& path, std::string& out) {
  std::size_t got = 0;
  while (got < out.size()) {
    const ssize_t n = ::read(fd, out.data() + got, out.size() - got);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) throw InputError(path + ": cannot read file (" + std::strerror(errno) + ")");
    if (n == 0) break;
    got += static_cast<std::size_t>(n);
  }
  out.resize(got);
}

}  // namespace

std::string read_input_file(const std::string& path, std::size_t max_bytes) {
  // O_NONBLOCK: opening a FIFO for reading would wait for a writer
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK | O_NOCTTY);
  if (fd < 0) throw InputError(path + ": cannot open file (" + std::strerror(errno) + ")");
  struct FdCloser {
    int fd;
    explicit FdCloser(int f) : fd(f) {}
    FdCloser(const FdCloser&) = delete;
    FdCloser& operator=(const FdCloser&) = delete;
    FdCloser(FdCloser&&) = delete;
    FdCloser& operator=(FdCloser&&) = delete;
    ~FdCloser() { ::close(fd); }
  } closer(fd);
  struct stat info {};
  if (::fstat(fd, &info) != 0)
    throw InputError(path + ": cannot read file (" + std::strerror(errno) + ")");
  if (!S_ISREG(info.st_mode))
    throw InputError(path + ": not a regular file (" +
                     (S_ISFIFO(info.st_mode)  ? "a FIFO"
                      : S_ISDIR(info.st_mode) ? "a directory"
                                              : "a device or socket") +
                     "), allowed: a regular file");
  const auto size = static_cast<std::size_t>(info.st_size);
  if (size > max_bytes)
    throw InputError(path + ": " + bytes_text(size) + ", more than the reader takes in one file, " +
                     "allowed at most " + bytes_text(max_bytes));
  std::string text(size, '\0');
  read_all(fd, path, text);
  return text;
}

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
