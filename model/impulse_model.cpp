#include "model/impulse_model.h"

#include <cmath>

namespace idm::model {

namespace {
struct RegionNames {
  Region region;
  const char* name;
  const char* protocol;
};
constexpr RegionNames kRegionNames[] = {{Region::Cutoff, "cutoff", "CUTOFF"},
                                        {Region::OneStep, "one-step", "ONESTEP"},
                                        {Region::MultiStep, "multi-step", "MULTISTEP"}};
}  // namespace

const char* region_name(Region region) {
  for (const RegionNames& r : kRegionNames)
    if (r.region == region) return r.name;
  return "?";
}

const char* region_protocol_name(Region region) {
  for (const RegionNames& r : kRegionNames)
    if (r.region == region) return r.protocol;
  return "?";
}

double impulse_ratio(const StageParams& s, double freq_hz, double stroke_m) {
  const double T = 1.0 / freq_hz;
  return s.mass_ratio() * stroke_m / (s.friction_decel_m_s2() * T * T);
}

RegionBoundaries region_boundaries(double d) {
  return {(1 - d) * d * d, d * d, (1 - d) * (1 - 2 * d), (1 - d) * (1 - d) * d};
}

Region region_closed_form(double beta, double duty) {
  const RegionBoundaries b = region_boundaries(duty);
  if (beta <= b.cutoff) return Region::Cutoff;
  const bool first_cycle_rests =
      beta > b.stop_in_ext ? beta <= b.first_rest_a : beta <= b.first_rest_b;
  return first_cycle_rests ? Region::OneStep : Region::MultiStep;
}

namespace {
// The ideal model in units of mu g (accelerations), T (times) and mu g T^2 (lengths): it depends
// on beta and duty alone. Actuator rates are in S/T, so a rate jump dr gives the slider -beta dr.
StageParams normalized_stage(double beta) {
  StageParams s;
  s.slider_mass_kg = 1.0 - beta;
  s.counter_mass_kg = beta;  // mass ratio m/(M+m) = beta
  s.friction_coefficient = 1.0;
  s.gravity_m_s2 = 1.0;
  return s;
}

bool steady_is_cutoff(double beta, double duty) {
  const double d = duty < 0.5 ? duty : 1.0 - duty;
  return beta <= (1 - d) * d * d;
}
}  // namespace

Region region_by_event_simulation(double beta, double duty, int max_cycles) {
  // beta may exceed 1 at high frequency: scale the normalization so the mass ratio stays < 1.
  const double scale = beta < 0.5 ? 1.0 : 2.0 * beta;
  StageParams s = normalized_stage(beta / scale);
  s.friction_coefficient = 1.0 / scale;
  ImpulseEventSimulator sim(s);
  TriangleWave one{1.0, duty, 1.0, 1};
  const bool cut = steady_is_cutoff(beta, duty);
  // The steady cycle rests just before its fast corner: at k T + duty T (after the slow extension)
  // for duty >= 0.5, at (k+1) T (after the slow retraction) for duty < 0.5. Once the slider rests
  // there, every later cycle is the steady one; `anchor` counts the cycles it took.
  const bool rest_after_extension = duty >= 0.5;
  auto decide = [cut](int anchor) {
    if (cut) return anchor <= 1 ? Region::Cutoff : Region::MultiStep;
    return anchor == 0 ? Region::OneStep : Region::MultiStep;
  };
  for (int k = 0; k < max_cycles; ++k) {
    sim.corner(one.extension_rate_m_s());
    sim.advance(one.extension_s());
    if (rest_after_extension && sim.velocity_m_s() == 0.0) return decide(k);
    sim.corner(one.retraction_rate_m_s());
    sim.advance(one.retraction_s());
    if (!rest_after_extension && sim.velocity_m_s() == 0.0) return decide(k);
  }
  return Region::MultiStep;
}

Region region(double beta, double duty) {
  if (duty < 0.5) return region_closed_form(beta, duty);
  return region_by_event_simulation(beta, duty);
}

double steady_step_ideal_m(const StageParams& s, double freq_hz, double duty, double stroke_m) {
  if (duty == 0.5) return 0.0;
  const double beta = impulse_ratio(s, freq_hz, stroke_m);
  const double d = duty < 0.5 ? duty : 1.0 - duty;
  if (beta <= (1 - d) * d * d) return 0.0;
  const double T = 1.0 / freq_hz;
  // eq 21: -(m S / ((M+m)(1-d)) - mu g d^2 T^2)
  const double step =
      -(s.mass_ratio() * stroke_m / (1 - d) - s.friction_decel_m_s2() * d * d * T * T);
  return duty < 0.5 ? step : -step;
}

double steady_step_corrected_m(const StageParams& s, double freq_hz, double duty, double stroke_m) {
  return s.step_correction * steady_step_ideal_m(s, freq_hz, duty, stroke_m);
}

FirstCycleVelocities first_cycle_velocities(const StageParams& s, double freq_hz, double duty,
                                            double stroke_m) {
  const double T = 1.0 / freq_hz;
  const double beta = impulse_ratio(s, freq_hz, stroke_m);
  const double mu_g_T = s.friction_decel_m_s2() * T;
  const double d = duty;
  FirstCycleVelocities v{0.0, 0.0};
  if (beta > d * d) {
    // eq 25: still sliding backwards at the end of the extension
    v.end_of_extension_m_s = mu_g_T * d - s.mass_ratio() * stroke_m / (d * T);
    // eq 26
    if (beta > (1 - d) * (1 - 2 * d)) v.end_of_cycle_m_s = (beta / (1 - d) - (1 - 2 * d)) * mu_g_T;
  } else {
    // eq 27
    if (beta > (1 - d) * (1 - d) * d)
      v.end_of_cycle_m_s = (beta / ((1 - d) * d) - (1 - d)) * mu_g_T;
  }
  return v;
}

ImpulseCell impulse_cell(const StageParams& s, double freq_hz, double duty, double stroke_m) {
  ImpulseCell c;
  c.beta = impulse_ratio(s, freq_hz, stroke_m);
  c.region = region(c.beta, duty);
  c.step_ideal_m = steady_step_ideal_m(s, freq_hz, duty, stroke_m);
  c.step_m = s.step_correction * c.step_ideal_m;
  return c;
}

ImpulseEventSimulator::ImpulseEventSimulator(const StageParams& s)
    : mass_ratio_(s.mass_ratio()), decel_m_s2_(s.friction_decel_m_s2()) {}

void ImpulseEventSimulator::reset(double x, double v, double rate) {
  position_m_ = x;
  velocity_m_s_ = v;
  rate_m_s_ = rate;
}

void ImpulseEventSimulator::corner(double new_rate_m_s) {
  velocity_m_s_ -= mass_ratio_ * (new_rate_m_s - rate_m_s_);
  rate_m_s_ = new_rate_m_s;
}

void ImpulseEventSimulator::advance(double dt_s) {
  coulomb_slide(position_m_, velocity_m_s_, decel_m_s2_, dt_s);
}

void ImpulseEventSimulator::run(const TriangleWave& w) {
  for (int k = 0; k < w.cycles; ++k) {
    corner(w.extension_rate_m_s());
    advance(w.extension_s());
    corner(w.retraction_rate_m_s());
    advance(w.retraction_s());
  }
  corner(0.0);
}

std::vector<double> cycle_end_positions_m(const StageParams& s, const TriangleWave& w) {
  ImpulseEventSimulator sim(s);
  std::vector<double> out;
  out.reserve(static_cast<std::size_t>(w.cycles));
  for (int k = 0; k < w.cycles; ++k) {
    sim.corner(w.extension_rate_m_s());
    sim.advance(w.extension_s());
    sim.corner(w.retraction_rate_m_s());
    sim.advance(w.retraction_s());
    out.push_back(sim.position_m());
  }
  return out;
}

}  // namespace idm::model
