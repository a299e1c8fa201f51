// `amplifier`: the piezo amplifier's finite bandwidth and slew rate between the commanded and the
// actual actuator length.
//
// A Butterworth low-pass of order 1 or 2 with its -3 dB point at cutoff_hz (unity DC gain),
// followed by an optional slew-rate limit on the output (0 = none). The filter is discretized
// exactly for an input that moves linearly within each step (ramp-invariant, by the matrix
// exponential of the augmented system), so the output at the step ends does not depend on the
// step size beyond rounding. The coefficients are computed on the first step and again only when
// dt changes. The slew limit is the continuous-time rate limiter, solved exactly for a filter
// output taken as linear within the step.
#pragma once

#include <Eigen/Dense>
#include <string>

#include "model/effects/actuator_effect.h"

namespace idm::model {

class Amplifier final : public ActuatorEffect {
 public:
  struct Params {
    int order = 1;               // 1 or 2 (Butterworth)
    double cutoff_hz = 3000.0;   // -3 dB bandwidth; the paper's PZ-350M: 3 kHz
    double slew_rate_m_s = 0.0;  // output rate limit, 0 = none
    // Throws InputError "WHERE.KEY: VALUE is out of range, allowed RANGE".
    void validate(const std::string& where = "amplifier") const;
  };

  explicit Amplifier(const Params& params);

  void reset(double xi_m) override;
  double step(double xi_in_m, double dt_s) override;

  const Params& params() const { return params_; }

 private:
  void discretize(double dt_s);

  Params params_;
  // Continuous state space x' = A x + B u, y = x(0); order 1 uses only x(0).
  Eigen::Matrix2d a_ = Eigen::Matrix2d::Zero();
  Eigen::Vector2d b_ = Eigen::Vector2d::Zero();
  // Ramp-invariant step: x1 = phi x0 + gamma0 u0 + gamma1 (u1 - u0), cached for cached_dt_s_.
  double cached_dt_s_ = -1.0;
  Eigen::Matrix2d phi_ = Eigen::Matrix2d::Identity();
  Eigen::Vector2d gamma0_ = Eigen::Vector2d::Zero();
  Eigen::Vector2d gamma1_ = Eigen::Vector2d::Zero();

  Eigen::Vector2d x_ = Eigen::Vector2d::Zero();
  double u_m_ = 0.0;         // input at the end of the last step
  double filtered_m_ = 0.0;  // filter output at the end of the last step (rate limiter target)
  double out_m_ = 0.0;       // rate-limited output at the end of the last step
};

}  // namespace idm::model
