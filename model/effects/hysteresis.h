// `hysteresis`: rate-independent hysteresis between the commanded and the actual actuator length.
//
// A Prandtl-Ishlinskii model: y = w0 u + sum_i w_i (F_i[u] - r_i) + offset, with 16 play
// operators F_i of half-width r_i = x_i S / 2, x_i = (i - 1/2) / 16 (S = stroke_m), equal weights
// w_i = 4 ratio / 16 and w0 = 1 - 2 ratio. For a full 0 -> S -> 0 cycle this gives parabolic
// branches y = (1 - 2h) u + 2h u^2 / S (h = ratio) on the way up and their point mirror on the way
// down: the loop's largest vertical width (at u = S/2) is exactly ratio * S and its turning points
// are (0, 0) and (S, S). reset(xi) puts the operators on the descending branch through (xi, xi),
// as after a retraction to xi, so a burst of full strokes from rest at 0 runs on the closed loop
// from its first cycle. Each play operator is exact for an input moving linearly (monotonically)
// within a step, so the output does not depend on rate or step size.
#pragma once

#include <array>
#include <string>

#include "model/effects/actuator_effect.h"

namespace idm::model {

class Hysteresis final : public ActuatorEffect {
 public:
  static constexpr int kOperators = 16;

  struct Params {
    double ratio = 0.15;         // loop width over stroke; the paper's PZL-015: 15 %
    double stroke_m = 20.35e-6;  // S, the span the loop is normalized to
    void validate(const std::string& where = "hysteresis") const;
  };

  explicit Hysteresis(const Params& params);

  void reset(double xi_m) override;
  double step(double xi_in_m, double dt_s) override;
  // The output is piecewise linear in the input: a kink where an operator starts to follow.
  double next_kink_s(double rate_m_s) const override;

  const Params& params() const { return params_; }

 private:
  double output(double u_m) const;

  Params params_;
  double input_weight_ = 1.0;                      // w0
  std::array<double, kOperators> half_width_m_{};  // r_i
  std::array<double, kOperators> weight_{};        // w_i
  std::array<double, kOperators> play_m_{};        // F_i
  double offset_m_ = 0.0;
  double input_m_ = 0.0;  // the last input
};

}  // namespace idm::model
