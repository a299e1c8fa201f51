#include "model/waveform.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "model/stage.h"

namespace idm::model {

namespace {
// Position inside the burst as (cycle index, time into the cycle), robust at cycle ends.
struct Phase {
  long cycle;
  double tau_s;
};
Phase phase_of(const TriangleWave& w, double t_s) {
  const double T = w.period_s();
  double k = std::floor(t_s * w.freq_hz);
  double tau = t_s - k * T;
  if (tau < 0) {  // floating-point guard
    k -= 1;
    tau += T;
  } else if (tau >= T) {
    k += 1;
    tau -= T;
  }
  return {static_cast<long>(k), tau};
}
}  // namespace

double TriangleWave::xi_m(double t_s) const {
  if (!(t_s > 0.0) || t_s >= duration_s()) return 0.0;
  const Phase p = phase_of(*this, t_s);
  if (p.cycle >= cycles) return 0.0;
  const double ext = extension_s();
  if (p.tau_s <= ext) return stroke_m * (p.tau_s / ext);
  return stroke_m * ((period_s() - p.tau_s) / retraction_s());
}

double TriangleWave::rate_m_s(double t_s) const {
  if (t_s < 0.0 || t_s >= duration_s()) return 0.0;
  const Phase p = phase_of(*this, t_s);
  if (p.cycle >= cycles) return 0.0;
  return p.tau_s < extension_s() ? extension_rate_m_s() : retraction_rate_m_s();
}

std::vector<double> TriangleWave::corner_times_s() const {
  std::vector<double> out;
  out.reserve(2 * static_cast<std::size_t>(cycles) + 1);
  const double T = period_s();
  for (int k = 0; k < cycles; ++k) {
    out.push_back(k * T);
    out.push_back(k * T + duty * T);
  }
  out.push_back(cycles * T);
  return out;
}

void validate(const TriangleWave& w) {
  auto fail = [](const std::string& key, double v, const std::string& range) {
    std::ostringstream msg;
    msg.precision(9);
    msg << key << ": " << v << " is out of range, allowed " << range;
    throw InputError(msg.str());
  };
  if (!(w.freq_hz > 0.0) || !std::isfinite(w.freq_hz) || w.freq_hz > 1e6)
    fail("freq_hz", w.freq_hz, "(0, 1e6]");
  if (!(w.duty > 0.0 && w.duty < 1.0)) fail("duty", w.duty, "(0, 1)");
  if (!(w.stroke_m > 0.0) || !std::isfinite(w.stroke_m) || w.stroke_m > 1e-3)
    fail("stroke_m", w.stroke_m, "(0, 1e-3]");
  if (w.cycles < 0 || w.cycles > 100000000) fail("cycles", w.cycles, "[0, 1e8]");
}

void sample(const TriangleWave& w, double sample_rate_hz, double t_start_s, std::size_t count,
            std::vector<double>& out) {
  out.resize(count);
  const double dt = 1.0 / sample_rate_hz;
  for (std::size_t k = 0; k < count; ++k) out[k] = w.xi_m(t_start_s + static_cast<double>(k) * dt);
}

ClockedWave snap_to_sample_clock(double rate_hz, double freq_hz, double duty) {
  ClockedWave w;
  const double p = std::max(2.0, std::round(rate_hz / freq_hz));
  const double k = std::clamp(std::round(duty * p), 1.0, p - 1);
  w.period_samples = static_cast<std::uint32_t>(p);
  w.extension_samples = static_cast<std::uint32_t>(k);
  w.freq_hz = rate_hz / p;
  w.duty = k / p;
  return w;
}

std::size_t Segment::sample_count() const {
  return static_cast<std::size_t>(rest_samples) +
         static_cast<std::size_t>(cycles) * period_samples + settle_samples + 1;
}

double Segment::start_offset_s() const {
  return clocked() ? static_cast<double>(rest_samples) / sample_rate_hz : 0.0;
}

TriangleWave Segment::wave() const {
  TriangleWave w;
  w.freq_hz = freq_hz;
  w.duty = duty;
  w.stroke_m = stroke_m;
  w.cycles = static_cast<int>(std::min<std::uint64_t>(cycles, 100000000));
  return w;
}

Segment make_segment(double freq_hz, double duty, double stroke_m, std::uint64_t cycles,
                     double sample_rate_hz, double rest_s, double settle_s) {
  Segment s;
  s.stroke_m = stroke_m;
  s.cycles = cycles;
  s.sample_rate_hz = sample_rate_hz;
  if (sample_rate_hz > 0) {
    const ClockedWave w = snap_to_sample_clock(sample_rate_hz, freq_hz, duty);
    s.freq_hz = w.freq_hz;
    s.duty = w.duty;
    s.period_samples = w.period_samples;
    s.extension_samples = w.extension_samples;
    s.rest_samples = static_cast<std::uint32_t>(std::lround(rest_s * sample_rate_hz));
    s.settle_samples = static_cast<std::uint32_t>(std::lround(settle_s * sample_rate_hz));
  } else {
    s.freq_hz = freq_hz;
    s.duty = duty;
  }
  return s;
}

void fill_samples(const Segment& seg, double* out) {
  std::size_t i = 0;
  for (std::uint32_t j = 0; j < seg.rest_samples; ++j) out[i++] = 0.0;
  const std::uint32_t P = seg.period_samples, k = seg.extension_samples;
  const double rise = seg.stroke_m / k, fall = seg.stroke_m / (P - k);
  for (std::uint64_t c = 0; c < seg.cycles; ++c) {
    for (std::uint32_t j = 0; j < k; ++j) out[i++] = rise * j;
    for (std::uint32_t j = k; j < P; ++j) out[i++] = fall * (P - j);
  }
  for (std::uint32_t j = 0; j <= seg.settle_samples; ++j) out[i++] = 0.0;
}

}  // namespace idm::model
