#include "model/effects/quantization.h"

#include <algorithm>
#include <cmath>

#include "model/effects/param_check.h"

namespace idm::model {

namespace {
constexpr double kEdgeTolerance = 1e-9;  // clock periods
}  // namespace

void Quantization::Params::validate(const std::string& where) const {
  if (bits < 1 || bits > 24) throw_out_of_range(where, "bits", bits, "an integer in [1, 24]");
  check_range(where, "update_rate_hz", update_rate_hz, Range{0.0, 1e9, true});
  check_range(where, "full_scale_m", full_scale_m, Range{0.0, 1e-2, true});
}

Quantization::Quantization(const Params& params) : params_(params) {
  params_.validate();
  spacing_m_ = std::ldexp(params_.full_scale_m, -params_.bits);
  lowest_code_ = -std::ldexp(1.0, params_.bits - 1);
  highest_code_ = std::ldexp(1.0, params_.bits - 1) - 1.0;
  reset(0.0);
}

double Quantization::quantize(double xi_m) const {
  const double code = std::clamp(std::nearbyint(xi_m / spacing_m_), lowest_code_, highest_code_);
  return code * spacing_m_;
}

void Quantization::reset(double xi_m) {
  phase_ = 0.0;
  u_m_ = xi_m;
  held_m_ = quantize(xi_m);
}

double Quantization::step(double xi_in_m, double dt_s) {
  if (!(dt_s > 0.0)) return held_m_;
  const double p0 = phase_;
  const double p1 = p0 + dt_s * params_.update_rate_hz;
  // The phase stays in [-tol, 1 - tol): this step holds the updates 1 .. floor(p1 + tol).
  const double last_update = std::floor(p1 + kEdgeTolerance);
  if (last_update >= 1.0) {
    // The last update in this step, at fraction lambda of the step.
    const double lambda = std::min(1.0, (last_update - p0) / (p1 - p0));
    held_m_ = quantize(u_m_ + lambda * (xi_in_m - u_m_));
    phase_ = p1 - last_update;
  } else {
    phase_ = p1;
  }
  u_m_ = xi_in_m;
  return held_m_;
}

}  // namespace idm::model
