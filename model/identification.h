// Identification of the actuator's stiffness K and damping C (paper section 4.2, eqs 32-34).
//
// With the slider held, the counter mass obeys m x'' = -C (x' - xi') - K (x - xi). Written in
// finite differences at the sample period Ts this is linear in W = [C Ts / m, K Ts^2 / m]:
//   H_i W = Y_i,  H_i = [d(x - xi)_i, (x - xi)_i],  Y_i = -d2x_i            (eqs 32-33)
// and W is estimated by weighted recursive least squares with a forgetting factor (eq 34):
//   G = P H' / (lambda + H P H'),  W += G (Y - H W),  P = (P - G H P) / lambda.
// The paper's differences are backward (x_i - x_{i-1}, x_i - 2x_{i-1} + x_{i-2}); they are biased
// by O(omega Ts). `central` uses centred differences (bias O((omega Ts)^2)) in the same form.
// Stencils that hold a corner of the command are skipped (eq 32 assumes a smooth command there).
// P is kept symmetric after each update: without that the plain update of eq 34 drifts and, over
// tens of thousands of samples with forgetting, diverges.
#pragma once

#include <Eigen/Dense>
#include <vector>

namespace idm::model {

class WeightedRls {
 public:
  WeightedRls(int parameters, double forgetting, double p0 = 1.0);
  // One observation y = h . w with weight (inverse variance) `weight`.
  void update(const Eigen::VectorXd& h, double y, double weight = 1.0);
  const Eigen::VectorXd& estimate() const { return w_; }
  const Eigen::MatrixXd& covariance() const { return p_; }

 private:
  double forgetting_;
  Eigen::VectorXd w_;
  Eigen::MatrixXd p_;
};

struct StiffnessEstimate {
  double stiffness_n_m = 0;
  double damping_n_s_m = 0;
  int samples_used = 0;
};

enum class Differences { Backward, Central };

// From samples at period ts_s of the command xi and the measured counter-mass position x (relative
// to the held slider), counter mass m: runs eqs 32-34 and converts W to K and C.
StiffnessEstimate identify_stiffness(const std::vector<double>& xi_m,
                                     const std::vector<double>& x_m, double ts_s,
                                     double counter_mass_kg, double forgetting = 0.995,
                                     Differences differences = Differences::Central);

}  // namespace idm::model
