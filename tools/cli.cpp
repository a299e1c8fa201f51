#include "tools/cli.h"
#include "model/yaml_util.h"

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <sstream>

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
    throw InputError("--" + name + ": " + model::format_number(v) + " is out of range, allowed [" + model::format_number(lo) + ", " + model::format_number(hi) + "]");
  return v;
}

double Flags::number_or(const std::string& name, double fallback, double lo, double hi) const {
  return has(name) ? number(name, lo, hi) : fallback;
}

long Flags::integer(const std::string& name, long lo, long hi) const {
  const double v = number(name, static_cast<double>(lo), static_cast<double>(hi));
  if (v != std::floor(v)) throw InputError("--" + name + ": " + model::format_number(v) + " is not an integer");
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
    std::stringstream ss(text);
    std::string a, b, c;
    if (!std::getline(ss, a, ':') || !std::getline(ss, b, ':') || !std::getline(ss, c) ||
        c.find(':') != std::string::npos)
      throw InputError(what + ": '" + text + "' is not start:stop:step");
    const double start = parse_number(a, what), stop = parse_number(b, what),
                 step = parse_number(c, what);
    if (!(step > 0) || stop < start)
      throw InputError(what + ": '" + text + "' needs step > 0 and stop >= start");
    const double n = std::floor((stop - start) / step + 1e-9);
    if (n > 1e6) throw InputError(what + ": '" + text + "' has more than 1e6 values");
    for (long k = 0; k <= static_cast<long>(n); ++k) {
      // 12 significant digits, so 0.05:0.95:0.1 gives 0.35, not 0.35000000000000003
      char buf[32];
      std::snprintf(buf, sizeof buf, "%.12g", start + static_cast<double>(k) * step);
      out.push_back(std::strtod(buf, nullptr));
    }
    return out;
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

}  // namespace idm::tools
