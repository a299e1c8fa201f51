#include "tools/cli.h"

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <sstream>
#include <string_view>

#include "model/text_list.h"
#include "model/yaml_util.h"

namespace idm::tools {

using model::InputError;

Flags::Flags(int argc, char** argv, int first, const std::vector<std::string>& known,
             const std::vector<std::string>& repeatable) {
  for (int i = first; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg.rfind("--", 0) != 0) throw InputError("unexpected argument '" + arg + "'");
    std::string name = arg.substr(2), value;
    const auto eq = name.find('=');
    if (eq != std::string::npos) {
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
  try {
    std::size_t used = 0;
    v = std::stod(text, &used);
    if (used != text.size()) throw std::invalid_argument(text);
  } catch (const std::exception&) {
    throw InputError(what + ": '" + text + "' is not a number");
  }
  if (!std::isfinite(v)) throw InputError(what + ": '" + text + "' is not finite");
  return v;
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
