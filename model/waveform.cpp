#include "model/waveform.h"

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

}  // namespace idm::model
