#include "model/identification.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace idm::model {

WeightedRls::WeightedRls(int n, double forgetting, double p0)
    : forgetting_(forgetting),
      w_(Eigen::VectorXd::Zero(n)),
      p_(Eigen::MatrixXd::Identity(n, n) * p0) {}

void WeightedRls::update(const Eigen::VectorXd& h, double y, double weight) {
  const Eigen::VectorXd ph = p_ * h;
  const double denom = forgetting_ / weight + h.dot(ph);
  const Eigen::VectorXd gain = ph / denom;
  w_ += gain * (y - h.dot(w_));
  p_ = (p_ - gain * ph.transpose()) / forgetting_;
  // keep P symmetric: the plain update drifts from symmetry over many steps and then diverges
  p_ = 0.5 * (p_ + p_.transpose()).eval();
}

StiffnessEstimate identify_stiffness(const std::vector<double>& xi, const std::vector<double>& x,
                                     double ts, double m, double forgetting, Differences diff) {
  if (xi.size() != x.size() || x.size() < 8)
    throw std::invalid_argument("identify_stiffness: need equal, non-trivial series");
  // Scale the regressors to O(1) so that P0 = I is a sensible prior whatever the units.
  double scale = 0;
  for (std::size_t i = 0; i < x.size(); ++i) scale = std::max(scale, std::fabs(x[i] - xi[i]));
  if (scale == 0) scale = 1;
  double xi_span = 0;
  for (double v : xi) xi_span = std::max(xi_span, std::fabs(v));
  const double corner_tolerance = 1e-9 * xi_span;
  WeightedRls rls(2, forgetting, 1.0);
  Eigen::VectorXd h(2);
  StiffnessEstimate out;
  for (std::size_t i = 2; i + 1 < x.size(); ++i) {
    double d_e = 0, e = 0, d2x = 0;
    if (diff == Differences::Backward) {
      d_e = (x[i] - x[i - 1]) - (xi[i] - xi[i - 1]);
      e = x[i] - xi[i];
      d2x = x[i] - 2 * x[i - 1] + x[i - 2];
    } else {
      d_e = 0.5 * ((x[i + 1] - x[i - 1]) - (xi[i + 1] - xi[i - 1]));
      e = x[i] - xi[i];
      d2x = x[i + 1] - 2 * x[i] + x[i - 1];
    }
    // Eq 32 assumes a smooth command inside the difference stencil: skip stencils holding a
    // corner of the command (known exactly, it is the waveform we sent), where xi' jumps.
    const double d2xi = (diff == Differences::Backward ? xi[i] - 2 * xi[i - 1] + xi[i - 2]
                                                       : xi[i + 1] - 2 * xi[i] + xi[i - 1]);
    if (std::fabs(d2xi) > corner_tolerance) continue;
    h << d_e / scale, e / scale;
    rls.update(h, -d2x / scale);
    ++out.samples_used;
  }
  const Eigen::VectorXd& w = rls.estimate();  // [C Ts / m, K Ts^2 / m]
  out.damping_n_s_m = w(0) * m / ts;
  out.stiffness_n_m = w(1) * m / (ts * ts);
  return out;
}

}  // namespace idm::model
