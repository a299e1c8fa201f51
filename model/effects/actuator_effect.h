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
};

}  // namespace idm::model
