#include "daemon/protocol.h"

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
bool is_blank(char c) {
  return c == ' ' || c == '\t';
}

std::string_view trim(std::string_view s) {
  while (!s.empty() && is_blank(s.front())) s.remove_prefix(1);
  while (!s.empty() && is_blank(s.back())) s.remove_suffix(1);
  return s;
}

bool iequals(std::string_view a, std::string_view b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i)
    if (upper(a[i]) != upper(b[i])) return false;
  return true;
}

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

}  // namespace

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
    case ec::kParameterNotAllowed:
      return "Parameter not allowed";
    case ec::kMissingParameter:
      return "Missing parameter";
    case ec::kUndefinedHeader:
      return "Undefined header";
    case ec::kNumericDataError:
      return "Numeric data error";
    case ec::kExecutionError:
      return "Execution error";
    case ec::kSettingsConflict:
      return "Settings conflict";
    case ec::kDataOutOfRange:
      return "Data out of range";
    case ec::kHardwareError:
      return "Hardware error";
    case ec::kQueueOverflow:
      return "Queue overflow";
    case ec::kInputBufferOverrun:
      return "Input buffer overrun";
    case ec::kFaultInvalidSample:
      return "Invalid interferometer sample";
    case ec::kFaultStall:
      return "Stall";
    case ec::kFaultRetryLimit:
      return "Retry limit";
    case ec::kFaultDriver:
      return "Driver error";
    case ec::kFaultNoPlan:
      return "No plan";
    case ec::kSweepFailed:
      return "Sweep failed";
    default:
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

CommandError parse_line(std::string_view line, ParsedLine& out) {
  out = ParsedLine{};
  for (std::size_t i = 0; i < line.size(); ++i) {
    const auto b = static_cast<unsigned char>(line[i]);
    if ((b < 0x20 && b != '\t') || b >= 0x7f) {
      char detail[64];
      std::snprintf(detail, sizeof detail, "byte 0x%02X at column %zu", b, i + 1);
      return make_error(ec::kInvalidCharacter, detail);
    }
  }
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
  // [:]*NAME  or  [:]KEY{:KEY}, KEY = letter {letter | digit | _}
  if (!header.empty() && header.front() == ':') header.remove_prefix(1);
  bool ok = !header.empty();
  if (ok && header.front() == '*') {
    ok = header.size() > 1;
    for (char c : header.substr(1)) ok = ok && is_alpha(c);
  } else if (ok) {
    bool at_start = true;
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
    ok = ok && !at_start;
  }
  if (!ok) return make_error(ec::kSyntaxError, "malformed header " + echo(shown));
  out.header = std::string(header);

  const std::string_view rest = trim(line.substr(end));
  if (rest.empty()) return {};
  // Arguments: split on commas outside "..." strings.
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
    current.clear();
    was_string = text_after_string = false;
    return {};
  };
  for (std::size_t i = 0; i < rest.size(); ++i) {
    const char c = rest[i];
    if (in_string) {
      if (c == '"') {
        if (i + 1 < rest.size() && rest[i + 1] == '"') {
          current += '"';
          ++i;
        } else {
          in_string = false;
        }
      } else {
        current += c;
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
  const char* first = t.data();
  if (*first == '+') ++first;  // from_chars takes no '+'
  double v = 0;
  const auto r = std::from_chars(first, t.data() + t.size(), v, std::chars_format::general);
  if (r.ec == std::errc::result_out_of_range || !std::isfinite(v))
    return bad("is not finite (out of the range of a double)");
  if (r.ec != std::errc() || r.ptr != t.data() + t.size()) return bad("is not a number");
  value = v;
  return {};
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
      case model::RangeError::None: return {};
      case model::RangeError::BadRange:
        return make_error(ec::kDataOutOfRange,
                          std::string(what) + ": " + echo(t) + " needs step > 0 and stop >= start");
      case model::RangeError::TooMany: break;
    }
    return make_error(ec::kDataOutOfRange, std::string(what) + ": " + echo(t) +
                                               " has more than " +
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
  static const struct {
    const char* name;
    int code;
  } kFaults[] = {{"invalid_sample", ec::kFaultInvalidSample},
                 {"stall", ec::kFaultStall},
                 {"retry_limit", ec::kFaultRetryLimit},
                 {"driver", ec::kFaultDriver},
                 {"no_plan", ec::kFaultNoPlan},
                 {"sweep_failed", ec::kSweepFailed}};
  if (fault_name.empty() || fault_name == "none") return {};
  for (const auto& f : kFaults)
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

// ---------------------------------------------------------------------------------------------
// Session: the command table

struct Session::Command {
  CommandInfo info;
  CommandError (Session::*handler)(const Args&, std::string&);
};

const std::vector<Session::Command>& Session::commands() {
  static const std::vector<Command> kCommands = {
      {{"*IDN", true, 0, 0, ""}, &Session::idn},
      {{"*RST", false, 0, 0, ""}, &Session::rst},
      {{"*CLS", false, 0, 0, ""}, &Session::cls},
      {{"*OPC", true, 0, 0, ""}, &Session::opc_query},
      {{"*WAI", false, 0, 0, ""}, &Session::wai},
      {{"*TST", true, 0, 0, ""}, &Session::tst},
      {{"SYSTem:ERRor[:NEXT]", true, 0, 0, ""}, &Session::error_next},
      {{"SYSTem:ERRor:COUNt", true, 0, 0, ""}, &Session::error_count},
      {{"SYSTem:ERRor:ALL", true, 0, 0, ""}, &Session::error_all},
      {{"SYSTem:VERSion", true, 0, 0, ""}, &Session::version},
      {{"SYSTem:LOOP", true, 0, 0, ""}, &Session::loop},
      {{"POSition", true, 0, 0, ""}, &Session::position},
      {{"MOVE[:ABSolute]", false, 1, 1, "<m>"}, &Session::move_absolute},
      {{"MOVE[:ABSolute]", true, 0, 0, ""}, &Session::move_target},
      {{"MOVE:RELative", false, 1, 1, "<m>"}, &Session::move_relative},
      {{"MOVE:DONE", true, 0, 0, ""}, &Session::move_done},
      {{"STOP", false, 0, 0, ""}, &Session::stop},
      {{"ABORt", false, 0, 0, ""}, &Session::stop},
      {{"STEP", false, 1, 4, "<n>[,<duty>,<freq_hz>[,<stroke_m>]]"}, &Session::step},
      {{"REGion", true, 2, 3, "<freq_hz>,<duty>[,<stroke_m>]"}, &Session::region},
      {{"LIMit:LOWer", false, 1, 1, "<m>"}, &Session::limit_lower},
      {{"LIMit:UPPer", false, 1, 1, "<m>"}, &Session::limit_upper},
      {{"LIMit:LOWer", true, 0, 0, ""}, &Session::limit_lower_query},
      {{"LIMit:UPPer", true, 0, 0, ""}, &Session::limit_upper_query},
      {{"LIMit", false, 2, 2, "<lower_m>,<upper_m>"}, &Session::limits},
      {{"LIMit", true, 0, 0, ""}, &Session::limits_query},
      {{"STATus", true, 0, 0, ""}, &Session::status},
      {{"SWEEP", false, 4, 5, "<dir>,<freqs>,<duties>,<trials>[,<cycles>]"}, &Session::sweep},
  };
  return kCommands;
}

const std::vector<CommandInfo>& command_table() {
  static const std::vector<CommandInfo> kTable = [] {
    std::vector<CommandInfo> out;
    for (const auto& c : Session::commands()) out.push_back(c.info);
    return out;
  }();
  return kTable;
}

// ---------------------------------------------------------------------------------------------
// Session: framing

Session::Session(Instrument& instrument) : instrument_(instrument) {}

void Session::receive(std::string_view bytes, std::string& replies) {
  const std::size_t newline = bytes.rfind('\n');
  unterminated_ =
      newline == std::string_view::npos ? unterminated_ + bytes.size() : bytes.size() - newline - 1;
  if (discarding_ && wait_ == Wait::None && newline == std::string_view::npos) return;
  input_.append(bytes);
  process(replies);
}

void Session::end_of_input(std::string& replies) {
  end_of_input_ = true;
  process(replies);
}

void Session::poll(std::string& replies) {
  if (wait_ == Wait::None) return;
  std::string reply = "1";
  try {
    if (!instrument_.motion_done()) return;
  } catch (const std::exception& e) {  // end the wait with the error rather than wait forever
    push(make_error(ec::kExecutionError, e.what()));
    reply.clear();
  }
  if (wait_ == Wait::OpcQuery) replies += reply + "\n";
  wait_ = Wait::None;
  process(replies);
}

void Session::process(std::string& replies) {
  std::size_t pos = 0;
  while (wait_ == Wait::None) {
    const std::size_t newline = input_.find('\n', pos);
    if (newline == std::string::npos) {
      const std::size_t pending = input_.size() - pos;
      if (discarding_) {
        pos = input_.size();
      } else if (pending > kMaxLineBytes + 1) {  // + 1: a CR may still come before the LF
        line_too_long(std::string_view(input_).substr(pos), replies);
        discarding_ = true;
        pos = input_.size();
      } else if (end_of_input_ && pending > 0) {
        std::string_view line = std::string_view(input_).substr(pos);
        pos = input_.size();
        if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
        if (line.size() > kMaxLineBytes)
          line_too_long(line, replies);
        else
          execute_line(line, replies);
        continue;
      }
      break;
    }
    std::string_view line = std::string_view(input_).substr(pos, newline - pos);
    pos = newline + 1;
    if (discarding_) {  // the end of a too-long line, already reported
      discarding_ = false;
      continue;
    }
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    if (line.size() > kMaxLineBytes)
      line_too_long(line, replies);
    else
      execute_line(line, replies);
  }
  input_.erase(0, pos);
}

void Session::line_too_long(std::string_view start, std::string& replies) {
  push(make_error(ec::kInputBufferOverrun,
                  "line longer than " + std::to_string(kMaxLineBytes) + " bytes, discarded"));
  if (looks_like_query(start)) replies += "\n";
}

void Session::push(CommandError error) {
  errors_.push(std::move(error));
}

void Session::started_motion(const CommandError& result) {
  if (result.ok()) motion_started_ = true;
}

// A motion this session started has ended: a fault it ended in goes to this session's queue.
void Session::notice_motion_end() {
  if (!motion_started_ || !instrument_.motion_done()) return;
  motion_started_ = false;
  push(fault_error(instrument_.status().fault));
}

void Session::execute_line(std::string_view line, std::string& replies) {
  try {
    notice_motion_end();
  } catch (const std::exception& e) {
    push(make_error(ec::kExecutionError, e.what()));
  }
  const bool query = looks_like_query(line);
  ParsedLine parsed;
  CommandError error = parse_line(line, parsed);
  if (error.ok() && parsed.header.empty()) return;  // a blank line
  const Command* command = nullptr;
  if (error.ok()) {
    for (const Command& c : commands())
      if (c.info.query == parsed.query && header_matches(c.info.pattern, parsed.header)) {
        command = &c;
        break;
      }
    if (!command)
      error = make_error(ec::kUndefinedHeader, echo(parsed.header + (parsed.query ? "?" : "")));
  }
  if (command) {
    const int n = static_cast<int>(parsed.args.size());
    // Built only for an error: this is the path of every command.
    const auto usage = [command] {
      return std::string("usage: ") + command->info.pattern + (command->info.query ? "?" : "") +
             (command->info.max_args > 0 ? " " : "") + command->info.arguments;
    };
    if (n > command->info.max_args)
      error = make_error(ec::kParameterNotAllowed, usage());
    else if (n < command->info.min_args)
      error = make_error(ec::kMissingParameter, usage());
  }
  std::string reply;
  if (error.ok()) {
    try {
      error = (this->*command->handler)(parsed.args, reply);
    } catch (const std::exception& e) {  // an Instrument that throws must not end the server
      error = make_error(ec::kExecutionError, e.what());
    }
    if (wait_ == Wait::OpcQuery) return;  // the reply comes from poll()
  }
  if (!error.ok()) {
    push(std::move(error));
    reply.clear();
  }
  if (query) replies += replace_controls(reply) + "\n";
}

// ---------------------------------------------------------------------------------------------
// Session: the commands

namespace {

CommandError instrument_error(CommandError e) {
  if (e.ok()) return e;
  return make_error(e.code, e.text);
}

}  // namespace

CommandError Session::idn(const Args&, std::string& reply) {
  reply = instrument_.identity();
  return {};
}

CommandError Session::rst(const Args&, std::string&) {
  errors_.clear();
  motion_started_ = false;
  return instrument_error(instrument_.reset());
}

CommandError Session::cls(const Args&, std::string&) {
  errors_.clear();
  return {};
}

CommandError Session::opc_query(const Args&, std::string& reply) {
  if (instrument_.motion_done())
    reply = "1";
  else
    wait_ = Wait::OpcQuery;
  return {};
}

CommandError Session::wai(const Args&, std::string&) {
  if (!instrument_.motion_done()) wait_ = Wait::Wai;
  return {};
}

CommandError Session::tst(const Args&, std::string& reply) {
  const InstrumentStatus s = instrument_.status();
  reply = (s.position_valid && (s.fault.empty() || s.fault == "none")) ? "0" : "1";
  return {};
}

CommandError Session::error_next(const Args&, std::string& reply) {
  reply = format_error(errors_.pop());
  return {};
}

CommandError Session::error_count(const Args&, std::string& reply) {
  reply = std::to_string(errors_.size());
  return {};
}

CommandError Session::error_all(const Args&, std::string& reply) {
  reply.clear();
  do {
    if (!reply.empty()) reply += ",";
    reply += format_error(errors_.pop());
  } while (!errors_.empty());
  return {};
}

CommandError Session::version(const Args&, std::string& reply) {
  reply = kScpiVersion;
  return {};
}

CommandError Session::loop(const Args&, std::string& reply) {
  const LoopStats s = instrument_.loop_stats();
  reply = "period=" + format_value(s.period_s) + " wakeups=" + std::to_string(s.wakeups) +
          " misses=" + std::to_string(s.deadline_misses) + " min=" + format_value(s.latency_min_s) +
          " avg=" + format_value(s.latency_avg_s) + " max=" + format_value(s.latency_max_s) +
          " bin_width=" + format_value(s.bin_width_s) + " hist=";
  for (std::size_t k = 0; k < std::size(s.bins); ++k) {
    if (k) reply += ";";
    reply += std::to_string(s.bins[k]);
  }
  return {};
}

CommandError Session::position(const Args&, std::string& reply) {
  const InstrumentStatus s = instrument_.status();
  if (!s.position_valid)
    return make_error(ec::kHardwareError, "no valid position (no interferometer reading)");
  reply = format_value(s.position_m);
  return {};
}

CommandError Session::move_absolute(const Args& args, std::string&) {
  double target = 0;
  if (CommandError e = parse_number(args[0], "MOVE:ABSolute target", target); !e.ok()) return e;
  CommandError e = instrument_error(instrument_.move_absolute(target));
  started_motion(e);
  return e;
}

CommandError Session::move_target(const Args&, std::string& reply) {
  reply = format_value(instrument_.status().target_m);
  return {};
}

CommandError Session::move_relative(const Args& args, std::string&) {
  double distance = 0;
  if (CommandError e = parse_number(args[0], "MOVE:RELative distance", distance); !e.ok()) return e;
  CommandError e = instrument_error(instrument_.move_relative(distance));
  started_motion(e);
  return e;
}

CommandError Session::move_done(const Args&, std::string& reply) {
  reply = instrument_.motion_done() ? "1" : "0";
  return {};
}

CommandError Session::stop(const Args&, std::string&) {
  return instrument_error(instrument_.stop());
}

CommandError Session::step(const Args& args, std::string&) {
  if (args.size() == 2)
    return make_error(ec::kMissingParameter, "STEP takes <n> or <n>,<duty>,<freq_hz>[,<stroke_m>]");
  std::int64_t cycles = 0;
  double duty = 0, freq = 0, stroke = 0;
  if (CommandError e = parse_integer(args[0], "STEP cycles", -1000000000, 1000000000, cycles);
      !e.ok())
    return e;
  if (args.size() >= 3) {
    if (CommandError e = parse_number(args[1], "STEP duty", duty); !e.ok()) return e;
    if (CommandError e = parse_number(args[2], "STEP freq_hz", freq); !e.ok()) return e;
  }
  if (args.size() == 4)
    if (CommandError e = parse_number(args[3], "STEP stroke_m", stroke); !e.ok()) return e;
  CommandError e = instrument_error(instrument_.step(cycles, duty, freq, stroke));
  started_motion(e);
  return e;
}

CommandError Session::region(const Args& args, std::string& reply) {
  double freq = 0, duty = 0, stroke = 0;
  if (CommandError e = parse_number(args[0], "REGion freq_hz", freq); !e.ok()) return e;
  if (CommandError e = parse_number(args[1], "REGion duty", duty); !e.ok()) return e;
  if (args.size() == 3)
    if (CommandError e = parse_number(args[2], "REGion stroke_m", stroke); !e.ok()) return e;
  std::string name;
  double step_m = 0;
  if (CommandError e = instrument_.region(freq, duty, stroke, name, step_m); !e.ok())
    return instrument_error(e);
  reply = name + "," + format_value(step_m);
  return {};
}

CommandError Session::limit_lower(const Args& args, std::string&) {
  double lower = 0;
  if (CommandError e = parse_number(args[0], "LIMit:LOWer", lower); !e.ok()) return e;
  return instrument_error(instrument_.set_soft_limits(lower, instrument_.status().soft_upper_m));
}

CommandError Session::limit_upper(const Args& args, std::string&) {
  double upper = 0;
  if (CommandError e = parse_number(args[0], "LIMit:UPPer", upper); !e.ok()) return e;
  return instrument_error(instrument_.set_soft_limits(instrument_.status().soft_lower_m, upper));
}

CommandError Session::limit_lower_query(const Args&, std::string& reply) {
  reply = format_value(instrument_.status().soft_lower_m);
  return {};
}

CommandError Session::limit_upper_query(const Args&, std::string& reply) {
  reply = format_value(instrument_.status().soft_upper_m);
  return {};
}

CommandError Session::limits(const Args& args, std::string&) {
  double lower = 0, upper = 0;
  if (CommandError e = parse_number(args[0], "LIMit lower", lower); !e.ok()) return e;
  if (CommandError e = parse_number(args[1], "LIMit upper", upper); !e.ok()) return e;
  return instrument_error(instrument_.set_soft_limits(lower, upper));
}

CommandError Session::limits_query(const Args&, std::string& reply) {
  const InstrumentStatus s = instrument_.status();
  reply = format_value(s.soft_lower_m) + "," + format_value(s.soft_upper_m);
  return {};
}

CommandError Session::status(const Args&, std::string& reply) {
  const InstrumentStatus s = instrument_.status();
  // key=value words separated by blanks: a value never holds a blank
  const auto word = [](const std::string& w) {
    std::string out = w.empty() ? std::string("none") : w;
    for (char& c : out)
      if (is_blank(c)) c = '_';
    return out;
  };
  reply = "state=" + word(s.state) + " done=" + (s.motion_done ? "1" : "0") +
          " position=" + format_value(s.position_m) +
          " position_valid=" + (s.position_valid ? "1" : "0") +
          " target=" + format_value(s.target_m) + " fault=" + word(s.fault) +
          " lower=" + format_value(s.soft_lower_m) + " upper=" + format_value(s.soft_upper_m) +
          " moves=" + std::to_string(s.moves) + " bursts=" + std::to_string(s.bursts) +
          " cycles=" + std::to_string(s.cycles) + " errors=" + std::to_string(errors_.size()) +
          " last_error=" + std::to_string(errors_.last_code()) +
          " daemon_error=" + word(replace_controls(s.last_error));
  return {};
}

CommandError Session::sweep(const Args& args, std::string&) {
  const std::string& dir = args[0];
  if (dir.empty()) return make_error(ec::kDataOutOfRange, "SWEEP: empty directory");
  std::vector<double> freqs, duties;
  if (CommandError e = parse_list(args[1], "SWEEP freqs", freqs); !e.ok()) return e;
  if (CommandError e = parse_list(args[2], "SWEEP duties", duties); !e.ok()) return e;
  std::int64_t trials = 0, cycles = 12;
  if (CommandError e = parse_integer(args[3], "SWEEP trials", 1, 1000000, trials); !e.ok())
    return e;
  if (args.size() == 5)
    if (CommandError e = parse_integer(args[4], "SWEEP cycles", 1, 1000000, cycles); !e.ok())
      return e;
  CommandError e = instrument_error(
      instrument_.sweep(dir, freqs, duties, static_cast<int>(trials), static_cast<int>(cycles)));
  started_motion(e);
  return e;
}

}  // namespace idm::daemon
