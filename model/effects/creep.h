// `creep`: slow logarithmic drift of the actuator length after a change of the command.
//
// After an input step of size A from rest, the output jumps by A and then drifts on so that
// y(10 t) - y(t) = per_decade * A for t between about 1e-4 s and 1e3 s (within 3 %; the log law
// fades out towards the ends of the relaxation bank, 1e-5 s and 1e4 s). The model is linear in
// the deviation from the rest point xi0 given to reset():
//
//   y = u + sum_k g_k (z_k - xi0),   z_k' = (u - z_k) / tau_k,
//
// with tau_k spaced 3 per decade from 1e-5 s to 1e4 s and g_k = per_decade / 3 (a flat density
// of relaxations per decade gives a constant slope per decade). Each relaxation is discretized
// exactly for an input moving linearly within a step; coefficients are cached per dt. With the
// input held at xi0 the output is xi0 and nothing drifts.
#pragma once

#include <array>
#include <string>

#include "model/effects/actuator_effect.h"

namespace idm::model {

class Creep final : public ActuatorEffect {
 public:
  static constexpr int kPerDecade = 3;
  static constexpr double kTauMin_s = 1e-5;
  static constexpr int kDecades = 9;  // up to 1e4 s
  static constexpr int kRelaxations = kPerDecade * kDecades + 1;

  struct Params {
    double per_decade = 0.01;  // relative drift per decade of time; piezo stacks: about 1 %
    void validate(const std::string& where = "creep") const;
  };

  explicit Creep(const Params& params);

  void reset(double xi_m) override;
  double step(double xi_in_m, double dt_s) override;

  const Params& params() const { return params_; }

 private:
  void discretize(double dt_s);

  Params params_;
  double weight_ = 0.0;  // g_k, the same for all k
  std::array<double, kRelaxations> tau_s_{};
  // z1 = decay z0 + (1 - decay) u0 + ramp (u1 - u0), cached for cached_dt_s_.
  double cached_dt_s_ = -1.0;
  std::array<double, kRelaxations> decay_{};
  std::array<double, kRelaxations> ramp_{};

  std::array<double, kRelaxations> z_m_{};
  double rest_m_ = 0.0;  // xi0
  double u_m_ = 0.0;     // input at the end of the last step
  double out_m_ = 0.0;
};

}  // namespace idm::model
