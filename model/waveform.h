// The triangular waveform of the actuator (paper eq 4, Fig. 3).
//
// One cycle of period T = 1/f: extension from 0 to S during duty*T at S/(duty*T), then retraction
// back to 0 during (1-duty)*T. A burst of N cycles starts at t = 0 and the command is 0 before it
// and after it. duty > 0.5 gives a slow extension and a fast retraction: the other direction.
#pragma once

#include <cstddef>
#include <cstdint>
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

// A waveform on an output's sample clock: f = rate / P, duty = k / P.
struct ClockedWave {
  double freq_hz = 0;
  double duty = 0;
  std::uint32_t period_samples = 0;     // P
  std::uint32_t extension_samples = 0;  // k, 1 <= k <= P - 1
};
// The playable waveform nearest to (freq_hz, duty): P = round(rate / f) (at least 2), k =
// round(duty P) clamped to [1, P-1]. The corners then lie on samples, so the ideal model of the
// played waveform is exact; a cell is evaluated at the snapped values, not the requested ones.
ClockedWave snap_to_sample_clock(double sample_rate_hz, double freq_hz, double duty);

// One burst as a controller hands it to an output: `cycles` whole cycles of one triangle, with
// the command at rest before and after. On a sample-clocked output (sample_rate_hz > 0) the period
// and the extension are whole samples (snap_to_sample_clock) and the burst is rest_samples of 0,
// the cycles, settle_samples of 0 and a final 0; a parameter output (sample_rate_hz = 0) plays the
// triangle itself and the sample fields are unused. Trivially copyable: it crosses lock-free
// queues between the real-time loop and a device's I/O thread.
struct Segment {
  double freq_hz = 0;
  double duty = 0;
  double stroke_m = 0;
  std::uint64_t cycles = 0;
  double sample_rate_hz = 0;
  std::uint32_t period_samples = 0;     // P
  std::uint32_t extension_samples = 0;  // k
  std::uint32_t rest_samples = 0;
  std::uint32_t settle_samples = 0;

  bool clocked() const { return sample_rate_hz > 0; }
  // Samples of the whole burst: rest + cycles P + settle + 1 (the final zero).
  std::size_t sample_count() const;
  // Time from the burst's first sample to the start of its first extension.
  double start_offset_s() const;
  // The same triangle as a TriangleWave (t = 0 at the first extension's start).
  TriangleWave wave() const;
};

// A segment of `cycles` cycles of (freq_hz, duty, stroke_m); on a clock (sample_rate_hz > 0) the
// frequency and duty are snapped to it. rest_s and settle_s are rounded to whole samples.
Segment make_segment(double freq_hz, double duty, double stroke_m, std::uint64_t cycles,
                     double sample_rate_hz, double rest_s = 0, double settle_s = 0);

// The one triangle generator: writes segment.sample_count() samples into out (the caller's
// buffer, at least that long). Rising edge rise j for j in [0, k), falling fall (P - j) for
// j in [k, P): every corner on a sample, the command exactly 0 at every cycle's start.
void fill_samples(const Segment& segment, double* out);

}  // namespace idm::model
