// The actuator effects' integer parameters (their map holds doubles); the range checks are
// model/range.h's, like every other.
#pragma once

#include <cmath>
#include <string>

#include "model/range.h"

namespace idm::model::effects_detail {

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
