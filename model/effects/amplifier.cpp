#include "model/effects/amplifier.h"

#include <cmath>
#include <numbers>
#include <unsupported/Eigen/MatrixFunctions>

#include "model/effects/param_check.h"

namespace idm::model {

namespace {

// The continuous rate limiter y' = rate * sign(a - y) (y = a while it can follow), for a target
// a(t) moving linearly from a0 to a1 over h, starting at y0. Exact for that target.
double rate_limit(double y0, double a0, double a1, double rate, double h) {
  if (a0 < y0) return -rate_limit(-y0, -a0, -a1, rate, h);
  // From here the target is at or above y0: y rises at `rate` until it meets the target.
  const double s = (a1 - a0) / h;  // target rate
  const double gap = a0 - y0;
  if (s >= rate || gap >= (rate - s) * h) return y0 + rate * h;  // does not catch up in this step
  const double t_meet = gap / (rate - s);
  if (s >= -rate) return a1;  // caught up and follows the target
  // The target falls faster than the limit: y turns at the meeting point and falls at `rate`.
  return a0 + s * t_meet - rate * (h - t_meet);
}

}  // namespace

void Amplifier::Params::validate(const std::string& where) const {
  if (order != 1 && order != 2) throw_out_of_range(where, "order", order, "an integer in [1, 2]");
  check_range(where, "cutoff_hz", cutoff_hz, Range{0.0, 1e6, true});
  check_range(where, "slew_rate_m_s", slew_rate_m_s, Range{0.0, 1e3, false});
}

Amplifier::Amplifier(const Params& params) : params_(params) {
  params_.validate();
  const double wc = 2.0 * std::numbers::pi * params_.cutoff_hz;
  if (params_.order == 1) {
    // y' = wc (u - y)
    a_(0, 0) = -wc;
    b_(0) = wc;
  } else {
    // y'' = wc^2 (u - y) - sqrt(2) wc y'; state (y, y')
    a_ << 0.0, 1.0, -wc * wc, -std::numbers::sqrt2 * wc;
    b_ << 0.0, wc * wc;
  }
  reset(0.0);
}

void Amplifier::reset(double xi_m) {
  x_ << xi_m, 0.0;
  u_m_ = xi_m;
  filtered_m_ = xi_m;
  out_m_ = xi_m;
}

void Amplifier::discretize(double dt_s) {
  // Augmented state z = (x, u, du) with u' = du / dt and du' = 0 over one step:
  // exp(F dt) holds phi, gamma0 (column of u) and gamma1 (column of du = u1 - u0).
  Eigen::Matrix4d f = Eigen::Matrix4d::Zero();
  f.topLeftCorner<2, 2>() = a_ * dt_s;
  f.block<2, 1>(0, 2) = b_ * dt_s;
  f(2, 3) = 1.0;
  const Eigen::Matrix4d e = f.exp();
  phi_ = e.topLeftCorner<2, 2>();
  gamma0_ = e.block<2, 1>(0, 2);
  gamma1_ = e.block<2, 1>(0, 3);
  cached_dt_s_ = dt_s;
}

double Amplifier::step(double xi_in_m, double dt_s) {
  if (!(dt_s > 0.0)) return out_m_;
  if (dt_s != cached_dt_s_) discretize(dt_s);
  x_ = phi_ * x_ + gamma0_ * u_m_ + gamma1_ * (xi_in_m - u_m_);
  u_m_ = xi_in_m;
  const double filtered = x_(0);
  if (params_.slew_rate_m_s > 0.0) {
    out_m_ = rate_limit(out_m_, filtered_m_, filtered, params_.slew_rate_m_s, dt_s);
  } else {
    out_m_ = filtered;
  }
  filtered_m_ = filtered;
  return out_m_;
}

}  // namespace idm::model
