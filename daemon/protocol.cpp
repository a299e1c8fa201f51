#include "daemon/protocol.h"

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <exception>
#include <limits>

#include "model/text_list.h"
#include "model/yaml_util.h"

namespace idm::daemon {

namespace ec = error_code;
using model::is_blank;
using model::trim;

namespace {

char upper(char c) {
  return (c >= 'a' && c <= 'z') ? static_cast<char>(c - 'a' + 'A') : c;
}
bool is_alpha(char c) {
  return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z');
}
bool is_digit(char c) {
  return c >= '0' && c <= '9';
}

bool iequals(std::string_view a, std::string_view b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i)
    if (upper(a[i]) != upper(b[i])) return false;
  return true;
}

}  // namespace

// User text echoed in an error: printable ASCII only, at most 40 characters.
std::string echo(std::string_view text) {
  std::string out;
  for (char c : text.substr(0, 40)) out += (c >= 0x20 && c < 0x7f) ? c : '?';
  if (text.size() > 40) out += "...";
  return "'" + out + "'";
}

std::string replace_controls(std::string_view text) {
  std::string out(text);
  for (char& c : out)
    if (static_cast<unsigned char>(c) < 0x20 || static_cast<unsigned char>(c) >= 0x7f) c = ' ';
  return out;
}

// ---------------------------------------------------------------------------------------------
// Pure functions

const char* standard_error_text(int code) {
  switch (code) {
    case ec::kNoError:
      return "No error";
    case ec::kCommandError:
      return "Command error";
    case ec::kInvalidCharacter:
      return "Invalid character";
    case ec::kSyntaxError:
      return "Syntax error";
    case ec::kDataTypeError:
      return "Data type error";
    case ec::kParameterNotAllowed:
      return "Parameter not allowed";
    case ec::kMissingParameter:
      return "Missing parameter";
    case ec::kUndefinedHeader:
      return "Undefined header";
    case ec::kHeaderSuffixOutOfRange:
      return "Header suffix out of range";
    case ec::kNumericDataError:
      return "Numeric data error";
    case ec::kExecutionError:
      return "Execution error";
    case ec::kCommandProtected:
      return "Command protected";
    case ec::kSettingsConflict:
      return "Settings conflict";
    case ec::kDataOutOfRange:
      return "Data out of range";
    case ec::kDataCorruptOrStale:
      return "Data corrupt or stale";
    case ec::kMoveStoppedByOther:
      return "Motion stopped by another client";
    case ec::kMassStorageError:
      return "Mass storage error";
    case ec::kHardwareError:
      return "Hardware error";
    case ec::kHardwareMissing:
      return "Hardware missing";
    case ec::kQueueOverflow:
      return "Queue overflow";
    case ec::kInputBufferOverrun:
      return "Input buffer overrun";
    default:
      for (const DeviceFault& f : kDeviceFaults)
        if (f.code == code) return f.text;
      for (const MoveResultCode& r : kMoveResults)
        if (r.code == code) return r.text;
      return "Error";
  }
}

CommandError make_error(int code, std::string_view detail) {
  const std::string_view standard = standard_error_text(code);
  std::string text;
  if (detail.empty())
    text = standard;
  else if (detail.size() >= standard.size() && iequals(detail.substr(0, standard.size()), standard))
    text = detail;
  else
    text = std::string(standard) + "; " + std::string(detail);
  text = replace_controls(text);
  if (text.size() > kMaxErrorTextBytes) text.resize(kMaxErrorTextBytes);
  return {code, text};
}

std::string quote(std::string_view text) {
  std::string out = "\"";
  for (char c : text) {
    out += c;
    if (c == '"') out += '"';
  }
  return out + "\"";
}

std::string format_error(const CommandError& error) {
  return std::to_string(error.code) + "," + quote(error.text);
}

std::string format_value(double value) {
  if (std::isnan(value)) return "9.91e+37";
  if (std::isinf(value)) return value > 0 ? "9.9e+37" : "-9.9e+37";
  char buf[40];
  const auto r = std::to_chars(buf, buf + sizeof buf, value, std::chars_format::general, 12);
  return std::string(buf, r.ptr);
}

bool looks_like_query(std::string_view line) {
  std::size_t i = 0;
  while (i < line.size() && is_blank(line[i])) ++i;
  std::size_t end = i;
  while (end < line.size() && !is_blank(line[end]) && line[end] != '\r' && line[end] != '\n') ++end;
  return end > i && end <= kMaxLineBytes && line[end - 1] == '?';
}

namespace {

bool is_token_char(char c) {
  return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '-';
}

// "GET /x HTTP/1.1": a request line's method (any upper-case token before a blank) is one a
// client of HTTP sends; no command of the protocol is called that.
bool opens_with_http_method(std::string_view line) {
  static constexpr std::string_view kMethods[] = {"GET",   "HEAD",    "POST",    "PUT",   "DELETE",
                                                  "PATCH", "OPTIONS", "CONNECT", "TRACE", "PRI"};
  const std::size_t blank = line.find(' ');
  if (blank == std::string_view::npos) return false;
  const std::string_view method = line.substr(0, blank);
  for (std::string_view m : kMethods)
    if (method == m) return true;
  return false;
}

// "... HTTP/1.1" or "... HTTP/2": the end of any request line, whatever its method.
bool ends_with_http_version(std::string_view line) {
  const std::size_t at = line.rfind(" HTTP/");
  if (at == std::string_view::npos) return false;
  const std::string_view version = line.substr(at + 6);
  if (version.empty() || version.size() > 3) return false;
  for (char c : version)
    if (!((c >= '0' && c <= '9') || c == '.')) return false;
  return version.front() != '.' && version.back() != '.';
}

// "Host: ...", "Origin: ...": a request header a browser (or curl) sends. The names are matched
// whole and case-insensitively; none is a keyword of the protocol.
bool opens_with_http_header(std::string_view line) {
  static constexpr std::string_view kHeaders[] = {"host",
                                                  "origin",
                                                  "referer",
                                                  "user-agent",
                                                  "accept",
                                                  "accept-encoding",
                                                  "accept-language",
                                                  "content-type",
                                                  "content-length",
                                                  "connection",
                                                  "cookie",
                                                  "upgrade",
                                                  "transfer-encoding",
                                                  "cache-control",
                                                  "pragma",
                                                  "authorization",
                                                  "upgrade-insecure-requests",
                                                  "dnt",
                                                  "priority",
                                                  "te",
                                                  "x-requested-with"};
  std::size_t n = 0;
  while (n < line.size() && is_token_char(line[n])) ++n;
  if (n == 0 || n >= line.size() || line[n] != ':') return false;
  const std::string_view name = line.substr(0, n);
  if (name.size() > 4 && (iequals(name.substr(0, 4), "sec-"))) return true;  // Sec-Fetch-*, ...
  for (std::string_view h : kHeaders)
    if (iequals(name, h)) return true;
  return false;
}

}  // namespace

bool looks_like_http(std::string_view line) {
  if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
  return opens_with_http_method(line) || ends_with_http_version(line) ||
         opens_with_http_header(line);
}

namespace {

// -101 at the first control character or byte outside printable ASCII (a tab is allowed).
CommandError check_characters(std::string_view line) {
  for (std::size_t i = 0; i < line.size(); ++i) {
    const auto b = static_cast<unsigned char>(line[i]);
    if ((b < 0x20 && b != '\t') || b >= 0x7f) {
      char detail[64];
      std::snprintf(detail, sizeof detail, "byte 0x%02X at column %zu", b, i + 1);
      return make_error(ec::kInvalidCharacter, detail);
    }
  }
  return {};
}

// A header without its '?' and leading ':': *NAME, or KEY{:KEY} with KEY = letter {letter |
// digit | _}.
bool header_well_formed(std::string_view header) {
  if (header.empty()) return false;
  if (header.front() == '*') {
    bool ok = header.size() > 1;
    for (char c : header.substr(1)) ok = ok && is_alpha(c);
    return ok;
  }
  bool ok = true, at_start = true;
  for (char c : header) {
    if (c == ':') {
      ok = ok && !at_start;
      at_start = true;
    } else if (at_start) {
      ok = ok && is_alpha(c);
      at_start = false;
    } else {
      ok = ok && (is_alpha(c) || is_digit(c) || c == '_');
    }
  }
  return ok && !at_start;
}

// The arguments after the header: split on commas outside "..." strings ("" inside one is a
// quote); a quoted argument is marked as such.
CommandError split_arguments(std::string_view rest, ParsedLine& out) {
  std::string current;
  bool in_string = false, was_string = false, text_after_string = false;
  auto finish = [&]() -> CommandError {
    std::string_view arg = current;
    if (!was_string) arg = trim(arg);
    if (arg.empty() && !was_string)
      return make_error(ec::kSyntaxError, "empty argument " + std::to_string(out.args.size() + 1));
    if (text_after_string)
      return make_error(ec::kSyntaxError, "text after a quoted string in argument " +
                                              std::to_string(out.args.size() + 1));
    out.args.emplace_back(arg);
    out.quoted.push_back(was_string);
    current.clear();
    was_string = text_after_string = false;
    return {};
  };
  for (std::size_t i = 0; i < rest.size(); ++i) {
    const char c = rest[i];
    if (in_string) {
      if (c != '"') {
        current += c;
      } else if (i + 1 < rest.size() && rest[i + 1] == '"') {
        current += '"';
        ++i;
      } else {
        in_string = false;
      }
    } else if (c == ',') {
      if (CommandError e = finish(); !e.ok()) return e;
    } else if (c == '"' && trim(current).empty() && !was_string) {
      current.clear();
      in_string = was_string = true;
    } else if (was_string) {
      if (!is_blank(c)) text_after_string = true;
    } else {
      current += c;
    }
  }
  if (in_string) return make_error(ec::kSyntaxError, "unterminated string");
  return finish();
}

}  // namespace

CommandError parse_line(std::string_view line, ParsedLine& out) {
  out = ParsedLine{};
  if (CommandError e = check_characters(line); !e.ok()) return e;
  line = trim(line);
  if (line.empty()) return {};
  std::size_t end = 0;
  while (end < line.size() && !is_blank(line[end])) ++end;
  std::string_view header = line.substr(0, end);
  const std::string_view shown = header;
  if (!header.empty() && header.back() == '?') {
    out.query = true;
    header.remove_suffix(1);
  }
  if (!header.empty() && header.front() == ':') header.remove_prefix(1);
  if (!header_well_formed(header))
    return make_error(ec::kSyntaxError, "malformed header " + echo(shown));
  out.header = std::string(header);
  const std::string_view rest = trim(line.substr(end));
  if (rest.empty()) return {};
  return split_arguments(rest, out);
}

bool keyword_matches(std::string_view pattern, std::string_view word) {
  std::size_t short_len = 0;
  while (short_len < pattern.size() && !(pattern[short_len] >= 'a' && pattern[short_len] <= 'z'))
    ++short_len;
  return iequals(word, pattern) || iequals(word, pattern.substr(0, short_len));
}

namespace {

struct PatternKeyword {
  std::string_view keyword;
  bool optional;
};

// Fixed capacity, no allocation: a header is matched against the table for every line. No pattern
// has more than kMaxKeywords keywords, so a header with more matches none.
constexpr std::size_t kMaxKeywords = 8;
template <typename T>
struct SmallList {
  std::array<T, kMaxKeywords> items{};
  std::size_t count = 0;
  bool overflow = false;
  void push_back(const T& v) {
    if (count < kMaxKeywords)
      items[count++] = v;
    else
      overflow = true;
  }
  std::size_t size() const { return count; }
  const T& operator[](std::size_t i) const { return items[i]; }
};

SmallList<PatternKeyword> split_pattern(std::string_view pattern) {
  SmallList<PatternKeyword> out;
  std::size_t i = 0;
  while (i < pattern.size()) {
    bool optional = false;
    if (pattern[i] == '[') {
      optional = true;
      ++i;
    }
    if (i < pattern.size() && pattern[i] == ':') ++i;
    std::size_t end = i;
    while (end < pattern.size() && pattern[end] != ':' && pattern[end] != '[' &&
           pattern[end] != ']')
      ++end;
    out.push_back({pattern.substr(i, end - i), optional});
    i = end;
    if (i < pattern.size() && pattern[i] == ']') ++i;
  }
  return out;
}

bool match_from(const SmallList<PatternKeyword>& pattern, std::size_t p,
                const SmallList<std::string_view>& words, std::size_t w) {
  if (p == pattern.size()) return w == words.size();
  if (w < words.size() && keyword_matches(pattern[p].keyword, words[w]) &&
      match_from(pattern, p + 1, words, w + 1))
    return true;
  return pattern[p].optional && match_from(pattern, p + 1, words, w);
}

}  // namespace

bool header_matches(std::string_view pattern, std::string_view header) {
  if (!header.empty() && header.front() == ':') header.remove_prefix(1);
  if (!pattern.empty() && pattern.front() == '*') return iequals(pattern, header);
  SmallList<std::string_view> words;
  std::size_t start = 0;
  for (std::size_t i = 0; i <= header.size(); ++i) {
    if (i == header.size() || header[i] == ':') {
      words.push_back(header.substr(start, i - start));
      start = i + 1;
    }
  }
  if (words.overflow) return false;
  return match_from(split_pattern(pattern), 0, words, 0);
}

CommandError parse_number(std::string_view text, std::string_view what, double& value) {
  const std::string_view t = trim(text);
  const auto bad = [&](std::string_view why) {
    return make_error(ec::kNumericDataError,
                      std::string(what) + ": " + echo(t) + " " + std::string(why));
  };
  // [+|-] (digits [. [digits]] | . digits) [(e|E) [+|-] digits]
  std::size_t i = 0;
  if (i < t.size() && (t[i] == '+' || t[i] == '-')) ++i;
  std::size_t mantissa_digits = 0;
  while (i < t.size() && is_digit(t[i])) ++i, ++mantissa_digits;
  if (i < t.size() && t[i] == '.') {
    ++i;
    while (i < t.size() && is_digit(t[i])) ++i, ++mantissa_digits;
  }
  bool ok = mantissa_digits > 0;
  if (ok && i < t.size() && (t[i] == 'e' || t[i] == 'E')) {
    ++i;
    if (i < t.size() && (t[i] == '+' || t[i] == '-')) ++i;
    std::size_t exponent_digits = 0;
    while (i < t.size() && is_digit(t[i])) ++i, ++exponent_digits;
    ok = exponent_digits > 0;
  }
  if (!ok || i != t.size()) return bad("is not a number");
  // The grammar is checked above; the value read as every reader of ours reads one (a number
  // below the smallest normal double reads as the nearest double).
  double v = 0;
  switch (model::parse_decimal(t, v)) {
    case model::NumberText::Ok:
      value = v;
      return {};
    case model::NumberText::NotANumber:
      return bad("is not a number");
    case model::NumberText::NotFinite:
      break;
  }
  return bad("is not finite (out of the range of a double)");
}

CommandError parse_integer(std::string_view text, std::string_view what, std::int64_t lo,
                           std::int64_t hi, std::int64_t& value) {
  double v = 0;
  if (CommandError e = parse_number(text, what, v); !e.ok()) return e;
  if (v != std::floor(v))
    return make_error(ec::kDataOutOfRange,
                      std::string(what) + ": " + model::format_number(v) + " is not an integer");
  if (v < static_cast<double>(lo) || v > static_cast<double>(hi))
    return make_error(ec::kDataOutOfRange, std::string(what) + ": " + model::format_number(v) +
                                               " is out of range, allowed [" + std::to_string(lo) +
                                               ", " + std::to_string(hi) + "]");
  value = static_cast<std::int64_t>(v);
  return {};
}

CommandError parse_list(std::string_view text, std::string_view what, std::vector<double>& values) {
  values.clear();
  const std::string_view t = trim(text);
  if (t.find(':') != std::string_view::npos) {
    std::string_view parts[3];
    if (!model::split_range(t, parts))
      return make_error(ec::kSyntaxError,
                        std::string(what) + ": " + echo(t) + " is not start:stop:step");
    double range[3] = {};  // start, stop, step
    for (int i = 0; i < 3; ++i)
      if (CommandError e = parse_number(parts[i], what, range[i]); !e.ok()) return e;
    switch (model::expand_range(range[0], range[1], range[2], kMaxListValues, values)) {
      case model::RangeError::None:
        return {};
      case model::RangeError::BadRange:
        return make_error(ec::kDataOutOfRange,
                          std::string(what) + ": " + echo(t) + " needs step > 0 and stop >= start");
      case model::RangeError::TooMany:
        break;
    }
    return make_error(ec::kDataOutOfRange, std::string(what) + ": " + echo(t) + " has more than " +
                                               std::to_string(kMaxListValues) + " values");
  }
  std::size_t start = 0;
  for (std::size_t i = 0; i <= t.size(); ++i) {
    if (i < t.size() && t[i] != ';') continue;
    const std::string_view item = trim(t.substr(start, i - start));
    if (item.empty())
      return make_error(ec::kSyntaxError, std::string(what) + ": empty item in " + echo(t));
    if (values.size() == kMaxListValues)
      return make_error(ec::kDataOutOfRange, std::string(what) + ": more than " +
                                                 std::to_string(kMaxListValues) + " values");
    double v = 0;
    if (CommandError e = parse_number(item, what, v); !e.ok()) return e;
    values.push_back(v);
    start = i + 1;
  }
  return {};
}

CommandError fault_error(const std::string& fault_name) {
  if (fault_name.empty() || fault_name == "none") return {};
  for (const DeviceFault& f : kDeviceFaults)
    if (fault_name == f.name) return make_error(f.code, "motion ended in fault " + fault_name);
  return make_error(ec::kExecutionError, "motion ended in fault " + fault_name);
}

// ---------------------------------------------------------------------------------------------
// ErrorQueue

ErrorQueue::ErrorQueue(std::size_t capacity) : capacity_(capacity < 2 ? 2 : capacity) {}

void ErrorQueue::push(CommandError error) {
  if (error.ok()) return;
  last_code_ = error.code;
  if (queue_.size() < capacity_) {
    queue_.push_back(std::move(error));
  } else if (queue_.back().code != ec::kQueueOverflow) {
    queue_.back() = make_error(ec::kQueueOverflow);
    last_code_ = ec::kQueueOverflow;
  }
}

CommandError ErrorQueue::pop() {
  if (queue_.empty()) return {ec::kNoError, standard_error_text(ec::kNoError)};
  CommandError e = std::move(queue_.front());
  queue_.pop_front();
  return e;
}

void ErrorQueue::clear() {
  queue_.clear();
  last_code_ = ec::kNoError;
}

}  // namespace idm::daemon
