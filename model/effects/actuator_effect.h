// An effect between the commanded and the actual actuator length (amplifier, hysteresis, creep,
// DAC). The plant runs the chain at its fixed internal rate: each call advances the effect by one
// internal step dt_s with the input moving linearly from its previous value to xi_in_m, and returns
// the output at the end of the step. No allocation, I/O or logging in step().
#pragma once

namespace idm::model {

class ActuatorEffect {
 public:
  virtual ~ActuatorEffect() = default;
  // At rest: input and output at xi_m for a long time.
  virtual void reset(double xi_m) = 0;
  virtual double step(double xi_in_m, double dt_s) = 0;
  // For an input moving on from its last value at rate_m_s: the time until the output's slope
  // next changes, when the output is piecewise linear in a linear input (hysteresis: an operator
  // starts or stops following); a negative value when it is not (a filter is smooth, not
  // piecewise linear). Stepping from kink to kink, a plant sees the output exactly.
  virtual double next_kink_s(double /*rate_m_s*/) const { return -1.0; }
};

}  // namespace idm::model
