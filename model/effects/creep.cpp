#include "model/effects/creep.h"

#include <cmath>

#include "model/effects/param_check.h"

namespace idm::model {

void Creep::Params::validate(const std::string& where) const {
  check_range(where, "per_decade", per_decade, Range{0.0, 0.1, false});
}

Creep::Creep(const Params& params) : params_(params) {
  params_.validate();
  weight_ = params_.per_decade / kPerDecade;
  for (int k = 0; k < kRelaxations; ++k)
    tau_s_[k] = kTauMin_s * std::pow(10.0, static_cast<double>(k) / kPerDecade);
  reset(0.0);
}

void Creep::reset(double xi_m) {
  z_m_.fill(xi_m);
  rest_m_ = xi_m;
  u_m_ = xi_m;
  out_m_ = xi_m;
}

void Creep::discretize(double dt_s) {
  for (int k = 0; k < kRelaxations; ++k) {
    const double x = dt_s / tau_s_[k];
    const double one_minus_decay = -std::expm1(-x);
    decay_[k] = 1.0 - one_minus_decay;
    // 1 - (1 - e^-x) / x, by its series where the difference would cancel.
    ramp_[k] = x < 1e-3 ? x * (0.5 - x * (1.0 / 6.0 - x / 24.0)) : 1.0 - one_minus_decay / x;
  }
  cached_dt_s_ = dt_s;
}

double Creep::step(double xi_in_m, double dt_s) {
  if (!(dt_s > 0.0)) return out_m_;
  if (dt_s != cached_dt_s_) discretize(dt_s);
  const double du = xi_in_m - u_m_;
  double drift = 0.0;
  for (int k = 0; k < kRelaxations; ++k) {
    // z relaxes towards u: z1 - u0 = decay (z0 - u0) + ramp du, written around u0 for precision.
    z_m_[k] = u_m_ + decay_[k] * (z_m_[k] - u_m_) + ramp_[k] * du;
    drift += z_m_[k] - rest_m_;
  }
  u_m_ = xi_in_m;
  out_m_ = xi_in_m + weight_ * drift;
  return out_m_;
}

}  // namespace idm::model
