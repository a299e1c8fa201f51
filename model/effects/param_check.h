// Range checks shared by the actuator effects' Params::validate() and their factory.
// Messages read "EFFECT.KEY: VALUE is out of range, allowed RANGE", like the stage's.
#pragma once

#include <cmath>
#include <sstream>
#include <string>

#include "model/stage.h"

namespace idm::model::effects_detail {

[[noreturn]] inline void throw_out_of_range(const std::string& where, const std::string& key,
                                            double value, const std::string& allowed) {
  std::ostringstream msg;
  msg.precision(9);
  msg << where << "." << key << ": " << value << " is out of range, allowed " << allowed;
  throw InputError(msg.str());
}

// value in (lo, hi] when lo_open, else [lo, hi]; always finite.
inline void check_range(const std::string& where, const std::string& key, double value, double lo,
                        double hi, bool lo_open) {
  const bool ok = std::isfinite(value) && value <= hi && (lo_open ? value > lo : value >= lo);
  if (ok) return;
  std::ostringstream allowed;
  allowed << (lo_open ? "(" : "[") << lo << ", " << hi << "]";
  throw_out_of_range(where, key, value, allowed.str());
}

// An integer parameter given as a double (the effect map holds doubles): must be whole and in
// [lo, hi].
inline int to_integer(const std::string& where, const std::string& key, double value, int lo,
                      int hi) {
  if (!std::isfinite(value) || value != std::floor(value) || value < lo || value > hi) {
    std::ostringstream allowed;
    allowed << "an integer in [" << lo << ", " << hi << "]";
    throw_out_of_range(where, key, value, allowed.str());
  }
  return static_cast<int>(value);
}

}  // namespace idm::model::effects_detail
