// `quantization`: the DAC that plays the waveform, with its finite resolution and update clock.
//
// The DAC samples the command at its update instants t_k = t0 + k / update_rate_hz (t0: the
// reset() time; one update happens at t0), rounds it to the nearest of its 2^bits codes, spaced
// full_scale_m / 2^bits over the bipolar span -full_scale_m/2 .. +full_scale_m/2 (code k gives
// k * spacing for k = -2^(bits-1) .. 2^(bits-1) - 1, so the top code is one step below
// +full_scale_m/2), and holds it until the next update. The plant's step need not match the DAC
// clock: the clock phase is tracked across steps, and when an update falls inside a step the
// command at that instant is interpolated linearly within the step; the output at the end of the
// step is the value of the last update in it. An update within 1e-9 clock periods of a step end
// counts as at that end.
#pragma once

#include <string>

#include "model/effects/actuator_effect.h"

namespace idm::model {

class Quantization final : public ActuatorEffect {
 public:
  struct Params {
    int bits = 12;                         // the paper's NI PCI-6711: 12 bit
    double update_rate_hz = 1e6;           // its largest update rate, 1 MS/s
    double full_scale_m = 2.0 * 20.35e-6;  // span of the DAC in actuator length, bipolar
    void validate(const std::string& where = "quantization") const;
  };

  explicit Quantization(const Params& params);

  void reset(double xi_m) override;
  double step(double xi_in_m, double dt_s) override;

  const Params& params() const { return params_; }
  double level_spacing_m() const { return spacing_m_; }
  // The DAC's transfer: nearest code, clamped to the codes that exist.
  double quantize(double xi_m) const;

 private:
  Params params_;
  double spacing_m_ = 0.0;
  double lowest_code_ = 0.0;
  double highest_code_ = 0.0;

  double phase_ = 0.0;  // clock periods since the last update, in [0, 1) up to rounding
  double u_m_ = 0.0;    // input at the end of the last step
  double held_m_ = 0.0;
};

}  // namespace idm::model
