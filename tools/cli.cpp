#include "tools/cli.h"

#include <array>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <sstream>
#include <string_view>
#include <utility>

#include "model/text_list.h"
#include "model/yaml_util.h"

namespace idm::tools {

using model::InputError;

Flags::Flags(int argc, char** argv, int first, const std::vector<std::string>& known,
             const std::vector<std::string>& repeatable, const std::vector<std::string>& switches) {
  for (int i = first; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg.rfind("--", 0) != 0) throw InputError("unexpected argument '" + arg + "'");
    std::string name = arg.substr(2), value;
    const auto eq = name.find('=');
    const bool is_switch = std::find(switches.begin(), switches.end(), name) != switches.end();
    if (is_switch) {
      value = "1";
    } else if (eq != std::string::npos) {
      value = name.substr(eq + 1);
      name = name.substr(0, eq);
    } else {
      if (i + 1 >= argc) throw InputError("--" + name + ": missing value");
      value = argv[++i];
    }
    bool ok = false;
    for (const auto& k : known) ok = ok || k == name;
    if (!ok) {
      std::string allowed;
      for (const auto& k : known) allowed += (allowed.empty() ? "--" : ", --") + k;
      throw InputError("--" + name + ": unknown flag, allowed " + allowed);
    }
    bool repeat = false;
    for (const auto& k : repeatable) repeat = repeat || k == name;
    if (values_.count(name) && !repeat) throw InputError("--" + name + ": given twice");
    values_[name].push_back(value);
  }
}

std::string Flags::text(const std::string& name) const {
  auto it = values_.find(name);
  if (it == values_.end()) throw InputError("--" + name + ": missing (required)");
  return it->second.front();
}

std::vector<std::string> Flags::all(const std::string& name) const {
  auto it = values_.find(name);
  return it == values_.end() ? std::vector<std::string>{} : it->second;
}

double Flags::number(const std::string& name, double lo, double hi) const {
  const double v = parse_number(text(name), "--" + name);
  if (v < lo || v > hi)
    throw InputError("--" + name + ": " + model::format_number(v) + " is out of range, allowed [" +
                     model::format_number(lo) + ", " + model::format_number(hi) + "]");
  return v;
}

double Flags::number_or(const std::string& name, double fallback, double lo, double hi) const {
  return has(name) ? number(name, lo, hi) : fallback;
}

long Flags::integer(const std::string& name, long lo, long hi) const {
  const double v = number(name, static_cast<double>(lo), static_cast<double>(hi));
  if (v != std::floor(v))
    throw InputError("--" + name + ": " + model::format_number(v) + " is not an integer");
  return static_cast<long>(v);
}

long Flags::integer_or(const std::string& name, long fallback, long lo, long hi) const {
  return has(name) ? integer(name, lo, hi) : fallback;
}

std::vector<double> Flags::list(const std::string& name) const {
  return parse_list(text(name), "--" + name);
}

double parse_number(const std::string& text, const std::string& what) {
  double v = 0;
  switch (model::parse_decimal(text, v)) {
    case model::NumberText::Ok:
      return v;
    case model::NumberText::NotANumber:
      throw InputError(what + ": '" + text + "' is not a number");
    case model::NumberText::NotFinite:
      break;
  }
  throw InputError(what + ": '" + text + "' is not finite");
}

std::vector<double> parse_list(const std::string& text, const std::string& what) {
  std::vector<double> out;
  if (text.find(':') != std::string::npos) {
    std::string_view parts[3];
    if (!model::split_range(text, parts))
      throw InputError(what + ": '" + text + "' is not start:stop:step");
    const double start = parse_number(std::string(parts[0]), what),
                 stop = parse_number(std::string(parts[1]), what),
                 step = parse_number(std::string(parts[2]), what);
    switch (model::expand_range(start, stop, step, 1000000, out)) {
      case model::RangeError::None:
        return out;
      case model::RangeError::BadRange:
        throw InputError(what + ": '" + text + "' needs step > 0 and stop >= start");
      case model::RangeError::TooMany:
        break;
    }
    throw InputError(what + ": '" + text + "' has more than 1e6 values");
  }
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ',')) {
    if (item.empty()) throw InputError(what + ": empty item in '" + text + "'");
    out.push_back(parse_number(item, what));
  }
  if (out.empty()) throw InputError(what + ": empty list");
  return out;
}

namespace {

constexpr std::array<LengthUnit, 4> kLengthUnits{{{"nm", 1e9}, {"um", 1e6}, {"mm", 1e3}, {"m", 1}}};

bool is_letter(char c) {
  return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z');
}

}  // namespace

const LengthUnit* find_length_unit(std::string_view name) {
  for (const LengthUnit& u : kLengthUnits)
    if (u.name == name) return &u;
  return nullptr;
}

std::string length_unit_names() {
  std::string names;
  for (const LengthUnit& u : kLengthUnits)
    names += (names.empty() ? "" : ", ") + std::string(u.name);
  return names;
}

namespace {

// "1.5mm" -> {"1.5", "mm"}: the number and the letters that end it.
std::pair<std::string, std::string> split_number_unit(const std::string& text) {
  std::size_t end = text.size();
  while (end > 0 && is_letter(text[end - 1])) --end;
  return {text.substr(0, end), text.substr(end)};
}

// `number` in metres (or metres per second) given in `unit`; `kind` ("length", "speed") and
// `accepted` for the message when it is not a number.
double in_metres(const std::string& number, const LengthUnit& unit, const std::string& what,
                 const std::string& text, const char* kind, const std::string& accepted) {
  double value = 0;
  try {
    value = parse_number(number, what);
  } catch (const InputError&) {
    throw InputError(what + ": '" + text + "' is not a " + kind + ": " + accepted);
  }
  return value / unit.per_metre;
}

}  // namespace

double parse_length(const std::string& text, const std::string& what, const LengthUnit* bare) {
  const std::string accepted =
      "a number and a unit, one of " + length_unit_names() + " (e.g. 250nm, 1.5mm)";
  const auto [number, suffix] = split_number_unit(text);
  if (text.find("\xC2\xB5") != std::string::npos || text.find("\xCE\xBC") != std::string::npos)
    throw InputError(what + ": '" + text + "': write um for micrometres; " + accepted);
  if (number.empty() || number.find_first_not_of("0123456789.eE+-") != std::string::npos)
    throw InputError(what + ": '" + text + "' is not a length: " + accepted);
  const LengthUnit* unit = suffix.empty() ? bare : find_length_unit(suffix);
  if (suffix.empty() && !unit)
    throw InputError(what + ": '" + text + "' has no unit: write " + text + "um, " + text +
                     "m, ... (a bare number is metres only without --unit or with --unit m)");
  if (!unit)
    throw InputError(what + ": '" + text + "': unknown unit '" + suffix + "', accepted " +
                     length_unit_names() + " (case matters; a bare number is metres)");
  return in_metres(number, *unit, what, text, "length", accepted);
}

std::string speed_unit_names() {
  std::string names;
  for (const LengthUnit& u : kLengthUnits)
    names += (names.empty() ? "" : ", ") + std::string(u.name) + "/s";
  return names;
}

double parse_speed(const std::string& text, const std::string& what, const LengthUnit* bare) {
  const std::string accepted =
      "a number and a unit, one of " + speed_unit_names() + " (e.g. 400um/s, 0.5mm/s)";
  if (text.find("\xC2\xB5") != std::string::npos || text.find("\xCE\xBC") != std::string::npos)
    throw InputError(what + ": '" + text + "': write um/s for micrometres per second; " + accepted);
  const bool per_second = text.size() > 2 && text.compare(text.size() - 2, 2, "/s") == 0;
  const std::string length = per_second ? text.substr(0, text.size() - 2) : text;
  const auto [number, suffix] = split_number_unit(length);
  if (number.empty() || number.find_first_not_of("0123456789.eE+-") != std::string::npos)
    throw InputError(what + ": '" + text + "' is not a speed: " + accepted);
  if (!per_second && !suffix.empty())
    throw InputError(what + ": '" + text + "' is a length, not a speed: write " + text + "/s (" +
                     accepted + ")");
  if (per_second && suffix.empty())
    throw InputError(what + ": '" + text + "' has no unit before /s: " + accepted);
  const LengthUnit* unit = suffix.empty() ? bare : find_length_unit(suffix);
  if (suffix.empty() && !unit)
    throw InputError(what + ": '" + text + "' has no unit: write " + text + "um/s, " + text +
                     "m/s, ... (a bare number is m/s only without --unit or with --unit m)");
  if (!unit)
    throw InputError(what + ": '" + text + "': unknown unit '" + suffix + "/s', accepted " +
                     speed_unit_names() + " (case matters; a bare number is m/s)");
  return in_metres(number, *unit, what, text, "speed", accepted);
}

std::string format_length(double metres, const LengthUnit& unit) {
  return model::format_number(metres * unit.per_metre, 12);
}

std::string exact_number(double value) {
  std::array<char, 32> buf{};
  const auto [end, ec] = std::to_chars(buf.data(), buf.data() + buf.size(), value);
  return ec == std::errc() ? std::string(buf.data(), end) : model::format_number(value, 17);
}

int run_subcommands(const char* tool, const char* usage, std::initializer_list<Subcommand> commands,
                    int argc, char** argv) {
  if (argc < 2) {
    std::fputs(usage, stderr);
    return 2;
  }
  const std::string cmd = argv[1];
  try {
    for (const Subcommand& c : commands) {
      if (cmd != c.name) continue;
      for (int k = 2; k < argc; ++k)
        if (std::string(argv[k]) == "--help" || std::string(argv[k]) == "-h") {
          std::fputs(usage, stdout);
          return 0;
        }
      return c.run(argc, argv);
    }
    if (cmd == "--help" || cmd == "-h" || cmd == "help") {
      std::fputs(usage, stdout);
      return 0;
    }
    std::string allowed;
    for (const Subcommand& c : commands)
      allowed += (allowed.empty() ? "" : ", ") + std::string(c.name);
    std::fprintf(stderr, "%s: unknown command '%s', allowed %s\n", tool, cmd.c_str(),
                 allowed.c_str());
    return 2;
  } catch (const model::InputError& e) {
    std::fprintf(stderr, "%s %s: %s\n", tool, cmd.c_str(), e.what());
    return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s %s: error: %s\n", tool, cmd.c_str(), e.what());
    return 1;
  }
}

}  // namespace idm::tools
