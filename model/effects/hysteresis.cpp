#include "model/effects/hysteresis.h"

#include <algorithm>

#include "model/effects/param_check.h"

namespace idm::model {

void Hysteresis::Params::validate(const std::string& where) const {
  check_range(where, "ratio", ratio, Range{0.0, 0.5, false});
  check_range(where, "stroke_m", stroke_m, Range{0.0, 1e-3, true});
}

Hysteresis::Hysteresis(const Params& params) : params_(params) {
  params_.validate();
  // Width of the loop at u: sum_i w_i min(x_i, 1 - x_i) S at u = S/2, with sum min(x_i, 1 - x_i)
  // = n/4 for the midpoint thresholds; the turning-point span w0 S + sum_i w_i (1 - x_i) S = S
  // with sum (1 - x_i) = n/2.
  const double n = kOperators;
  const double w = 4.0 * params_.ratio / n;
  input_weight_ = 1.0 - 2.0 * params_.ratio;
  for (int i = 0; i < kOperators; ++i) {
    const double x = (i + 0.5) / n;
    half_width_m_[i] = 0.5 * x * params_.stroke_m;
    weight_[i] = w;
  }
  reset(0.0);
}

double Hysteresis::output(double u_m) const {
  double y = input_weight_ * u_m + offset_m_;
  for (int i = 0; i < kOperators; ++i) y += weight_[i] * (play_m_[i] - half_width_m_[i]);
  return y;
}

void Hysteresis::reset(double xi_m) {
  // On the descending branch at xi: every play operator sits at its upper edge.
  for (int i = 0; i < kOperators; ++i) play_m_[i] = xi_m + half_width_m_[i];
  offset_m_ = 0.0;
  offset_m_ = xi_m - output(xi_m);
}

double Hysteresis::step(double xi_in_m, double /*dt_s*/) {
  // Within a step the input is monotone, so each play operator's end value is exact.
  for (int i = 0; i < kOperators; ++i) {
    const double r = half_width_m_[i];
    play_m_[i] = std::max(xi_in_m - r, std::min(xi_in_m + r, play_m_[i]));
  }
  return output(xi_in_m);
}

}  // namespace idm::model
