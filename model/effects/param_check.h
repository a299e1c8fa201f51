// Range checks shared by the actuator effects' Params::validate() and their factory.
// Messages read "EFFECT.KEY: VALUE is out of range, allowed RANGE", like the stage's.
#pragma once

#include <charconv>
#include <cmath>
#include <string>

#include "model/stage.h"

namespace idm::model::effects_detail {

// A number as a person writes it: the shortest form that reads back the same, exponents without
// '+' and leading zeros (1e6, 2.5e-7, 0.01, 3000).
inline std::string format_number(double value) {
  char buffer[64];
  const auto result = std::to_chars(buffer, buffer + sizeof buffer, value);
  std::string text(buffer, result.ptr);
  const std::size_t e = text.find('e');
  if (e == std::string::npos) return text;
  std::size_t digits = e + 1;
  std::string sign;
  if (text[digits] == '+' || text[digits] == '-') {
    if (text[digits] == '-') sign = "-";
    ++digits;
  }
  while (digits + 1 < text.size() && text[digits] == '0') ++digits;
  return text.substr(0, e + 1) + sign + text.substr(digits);
}

[[noreturn]] inline void throw_out_of_range(const std::string& where, const std::string& key,
                                            double value, const std::string& allowed) {
  throw InputError(where + "." + key + ": " + format_number(value) + " is out of range, allowed " +
                   allowed);
}

// value in (lo, hi] when lo_open, else [lo, hi]; always finite.
inline void check_range(const std::string& where, const std::string& key, double value, double lo,
                        double hi, bool lo_open) {
  const bool ok = std::isfinite(value) && value <= hi && (lo_open ? value > lo : value >= lo);
  if (ok) return;
  throw_out_of_range(where, key, value,
                     (lo_open ? "(" : "[") + format_number(lo) + ", " + format_number(hi) + "]");
}

// An integer parameter given as a double (the effect map holds doubles): must be whole and in
// [lo, hi].
inline int to_integer(const std::string& where, const std::string& key, double value, int lo,
                      int hi) {
  if (!std::isfinite(value) || value != std::floor(value) || value < lo || value > hi) {
    throw_out_of_range(where, key, value,
                       "an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
  }
  return static_cast<int>(value);
}

}  // namespace idm::model::effects_detail
