#include "model/effects/hysteresis.h"

#include <algorithm>
#include <cmath>
#include <limits>

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
  input_m_ = xi_m;
}

double Hysteresis::next_kink_s(double rate_m_s) const {
  // Operator i stays put until the input leaves [F_i - r_i, F_i + r_i] on the side it moves to.
  double first = std::numeric_limits<double>::infinity();
  if (rate_m_s == 0.0) return first;
  for (int i = 0; i < kOperators; ++i) {
    const double gap = rate_m_s > 0 ? play_m_[i] + half_width_m_[i] - input_m_
                                    : input_m_ - (play_m_[i] - half_width_m_[i]);
    if (gap > 1e-16)
      first = std::min(first, gap / std::fabs(rate_m_s));  // 0.1 fm: already following
  }
  return first;
}

double Hysteresis::step(double xi_in_m, double /*dt_s*/) {
  // Within a step the input is monotone, so each play operator's end value is exact.
  for (int i = 0; i < kOperators; ++i) {
    const double r = half_width_m_[i];
    play_m_[i] = std::max(xi_in_m - r, std::min(xi_in_m + r, play_m_[i]));
  }
  input_m_ = xi_in_m;
  return output(xi_in_m);
}

}  // namespace idm::model
