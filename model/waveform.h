// The triangular waveform of the actuator (paper eq 4, Fig. 3).
//
// One cycle of period T = 1/f: extension from 0 to S during duty*T at S/(duty*T), then retraction
// back to 0 during (1-duty)*T. A burst of N cycles starts at t = 0 and the command is 0 before it
// and after it. duty > 0.5 gives a slow extension and a fast retraction: the other direction.
#pragma once

#include <cstddef>
#include <string>
#include <vector>

namespace idm::model {

struct TriangleWave {
  double freq_hz = 100.0;
  double duty = 0.1;
  double stroke_m = 20.35e-6;
  int cycles = 1;

  double period_s() const { return 1.0 / freq_hz; }
  double extension_s() const { return duty / freq_hz; }
  double retraction_s() const { return (1.0 - duty) / freq_hz; }
  double duration_s() const { return cycles / freq_hz; }
  double extension_rate_m_s() const { return stroke_m / extension_s(); }
  double retraction_rate_m_s() const { return -stroke_m / retraction_s(); }

  // Commanded elongation at t (0 outside the burst).
  double xi_m(double t_s) const;
  // Commanded elongation rate on the open interval after t (0 outside the burst).
  double rate_m_s(double t_s) const;
  // Every velocity corner: 0, duty*T, T, T + duty*T, ..., N*T (2N+1 times).
  std::vector<double> corner_times_s() const;
};

// Throws InputError naming the argument and the allowed range (0 < duty < 1, f > 0, ...).
void validate(const TriangleWave& wave);

// The waveform sampled at a device clock: samples t_k = t_start_s + k / sample_rate_hz,
// k = 0..count-1, written to out (resized). For output devices and simulated sweeps.
void sample(const TriangleWave& wave, double sample_rate_hz, double t_start_s, std::size_t count,
            std::vector<double>& out);

}  // namespace idm::model
