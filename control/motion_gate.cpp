#include "control/motion_gate.h"

#include <algorithm>
#include <cmath>

namespace idm::control {

Excursion burst_excursion(std::uint64_t cycles, double step_m, double uncertainty, double slip_m) {
  const double n = static_cast<double>(cycles);
  const double nominal = n * step_m;
  const double far = nominal * (1.0 + uncertainty);
  const double slip = std::fabs(slip_m);
  return {std::min({0.0, nominal, far}) - slip, std::max({0.0, nominal, far}) + slip};
}

bool excursion_allowed(double position_m, const Excursion& excursion, double soft_lower_m,
                       double soft_upper_m) {
  if (!std::isfinite(position_m) || std::isnan(excursion.lo_m) || std::isnan(excursion.hi_m))
    return false;
  const double lowest = position_m + excursion.lo_m;
  const double highest = position_m + excursion.hi_m;
  return lowest >= std::min(soft_lower_m, position_m) &&
         highest <= std::max(soft_upper_m, position_m);
}

bool reading_allowed(double reading_m, double start_m, double soft_lower_m, double soft_upper_m,
                     double tolerance_m) {
  if (!std::isfinite(reading_m)) return false;
  return reading_m >= std::min(soft_lower_m, start_m) - tolerance_m &&
         reading_m <= std::max(soft_upper_m, start_m) + tolerance_m;
}

bool target_allowed(double target_m, double soft_lower_m, double soft_upper_m) {
  return target_m >= soft_lower_m && target_m <= soft_upper_m;
}

}  // namespace idm::control
