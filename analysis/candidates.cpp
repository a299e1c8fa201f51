#include "analysis/candidates.h"

#include <algorithm>
#include <cmath>
#include <set>
#include <stdexcept>

namespace idm::analysis {

double FitAxis::value(double u) const {
  u = std::clamp(u, 0.0, 1.0);
  const double v =
      log_scale ? std::exp(std::log(lo) + u * (std::log(hi) - std::log(lo))) : lo + u * (hi - lo);
  return std::clamp(v, lo, hi);
}

double FitAxis::coordinate(double v) const {
  const double u = log_scale ? (std::log(v) - std::log(lo)) / (std::log(hi) - std::log(lo))
                             : (v - lo) / (hi - lo);
  return std::clamp(u, 0.0, 1.0);
}

std::vector<std::string> SetFit::names() const {
  std::vector<std::string> out;
  for (const MemberFit& m : members) out.push_back(m.effect);
  return out;
}

namespace {

// The time scales a sweep can show: its highest frequency, its shortest phase, and the slider's
// typical velocity jump at a corner.
struct SweepScales {
  double f_max_hz = 0;
  double fast_hz = 0;    // 1 / (shortest phase of any cell)
  double speed_m_s = 0;  // median velocity jump of the slider at the fast corner, m/(M+m) dxi
};

SweepScales scales_of(const SweepCells& sweep) {
  SweepScales s;
  const model::StageParams& p = sweep.stage.stage;
  std::vector<double> speeds;
  for (const Cell& c : sweep.cells) {
    const double T = 1.0 / c.key.freq_hz;
    const double shortest = std::min(c.key.duty, 1.0 - c.key.duty) * T;
    s.f_max_hz = std::max(s.f_max_hz, c.key.freq_hz);
    s.fast_hz = std::max(s.fast_hz, 1.0 / shortest);
    speeds.push_back(p.mass_ratio() * c.key.stroke_m *
                     (1.0 / (c.key.duty * T) + 1.0 / ((1.0 - c.key.duty) * T)));
  }
  s.speed_m_s = median(speeds);
  return s;
}

double clamp_to_library(const std::string& effect, const std::string& param, double v) {
  for (const model::EffectInfo& e : model::effect_library())
    if (effect == e.name)
      for (const model::EffectParamInfo& q : e.params)
        if (param == q.name) return std::clamp(v, q.lo, q.hi);
  throw std::logic_error("no parameter " + effect + "." + param);
}

// amplifier: a corner is rounded over ~1 / (2 pi fc); from half the highest frequency (the stage
// barely steps) to 30 times the shortest phase's rate (the rounding is then invisible).
CandidateSpec amplifier_candidate(const SweepScales& sc) {
  CandidateSpec amp;
  amp.effect = "amplifier";
  amp.axes = {
      {"cutoff_hz", std::max(20.0, 0.5 * sc.f_max_hz), std::min(1e6, 30.0 * sc.fast_hz), true}};
  amp.variants = {{{"order", 2}}, {{"order", 1}}};
  amp.params = [](const std::vector<double>& x) { return Params{{"cutoff_hz", x[0]}}; };
  amp.physics = "cutoff between half the highest frequency and 30 x the fastest phase's rate";
  return amp;
}

// actuator_compliance: the actuator's resonance with the reduced mass and its damping ratio (the
// natural coordinates of eq 30: stiffness and damping trade off along a narrow valley); from half
// the highest frequency to 10 times the fastest phase's rate (the actuator is then rigid to it).
CandidateSpec compliance_candidate(const SweepScales& sc, const model::StageParams& st) {
  const double m_red = st.reduced_mass_kg();
  CandidateSpec comp;
  comp.effect = "actuator_compliance";
  comp.axes = {
      {"resonance_hz", std::max(20.0, 0.5 * sc.f_max_hz), std::min(2e5, 10.0 * sc.fast_hz), true},
      {"damping_ratio", 0.02, 2.0, true}};
  comp.variants = {{}};
  comp.params = [m_red](const std::vector<double>& x) {
    const double k = m_red * std::pow(2 * M_PI * x[0], 2);
    return Params{{"stiffness_n_m", clamp_to_library("actuator_compliance", "stiffness_n_m", k)},
                  {"damping_n_s_m", clamp_to_library("actuator_compliance", "damping_n_s_m",
                                                     2 * x[1] * std::sqrt(k * m_red))}};
  };
  if (st.stiffness_n_m > 0 && st.damping_n_s_m > 0) {  // stage.yaml's K and C
    const double fr = std::sqrt(st.stiffness_n_m / m_red) / (2 * M_PI);
    const double zeta = st.damping_n_s_m / (2 * std::sqrt(st.stiffness_n_m * m_red));
    if (fr > comp.axes[0].lo && fr < comp.axes[0].hi && zeta > 0.02 && zeta < 2.0)
      comp.start = {fr, zeta};
  }
  comp.scan_ratio = 1.07;
  comp.scan_other = {0.04, 0.06, 0.09, 0.135, 0.2, 0.3, 0.45, 0.68};
  comp.physics = "resonance with the reduced mass (K = m_red (2 pi f)^2) and damping ratio";
  return comp;
}

CandidateSpec hysteresis_candidate() {
  CandidateSpec hys;
  hys.effect = "hysteresis";
  hys.axes = {{"ratio", 0.005, 0.45, true}};
  hys.variants = {{}};
  hys.params = [](const std::vector<double>& x) { return Params{{"ratio", x[0]}}; };
  hys.physics = "loop width over stroke";
  return hys;
}

CandidateSpec creep_candidate() {
  CandidateSpec creep;
  creep.effect = "creep";
  creep.axes = {{"per_decade", 0.001, 0.1, true}};
  creep.variants = {{}};
  creep.params = [](const std::vector<double>& x) { return Params{{"per_decade", x[0]}}; };
  creep.physics = "relative drift per decade of time";
  return creep;
}

// stribeck: what a slider loses to it is about (mu_s / mu_k - 1) v_s (the bump of friction at
// low speed times its width): the gap runs along a valley of that product. The coordinates are
// the product ("impulse") and where the Stribeck velocity sits among the velocities that give it
// within the ranges (0 to 1): the valley lies along the first.
CandidateSpec stribeck_candidate(const SweepScales& sc) {
  CandidateSpec str;
  str.effect = "stribeck";
  const double v_lo = std::max(1e-6, sc.speed_m_s / 300), v_hi = std::min(1.0, 3 * sc.speed_m_s);
  const double kExcessLo = 0.01, kExcessHi = 1.5;
  str.axes = {{"stribeck_impulse_m_s", kExcessLo * v_lo, kExcessHi * v_hi, true},
              {"velocity_share", 0.0, 1.0, false}};
  str.variants = {{}};
  str.scan_ratio = 1.3;  // the valley across the impulse is narrow: a 7-point grid steps over it
  str.scan_other = {0.15, 0.5, 0.85};
  str.scan_alone_only = true;
  str.params = [v_lo, v_hi, kExcessLo, kExcessHi](const std::vector<double>& x) {
    const double a = x[0];
    const double lo = std::max(v_lo, a / kExcessHi), hi = std::min(v_hi, a / kExcessLo);
    const double v = hi > lo ? std::exp(std::log(lo) + x[1] * (std::log(hi) - std::log(lo)))
                             : std::sqrt(lo * hi);
    return Params{
        {"static_over_kinetic", 1.0 + std::clamp(a / v, kExcessLo, kExcessHi)},
        {"stribeck_velocity_m_s", clamp_to_library("stribeck", "stribeck_velocity_m_s", v)}};
  };
  str.physics =
      "(mu_s / mu_k - 1) times the Stribeck velocity, and that velocity's place in its range";
  return str;
}

// friction_spread: only the spread; an offset of the mean friction is the baseline's mu.
CandidateSpec friction_spread_candidate() {
  CandidateSpec spread;
  spread.effect = "friction_spread";
  spread.axes = {{"relative_sd", 0.005, 0.4, true}};
  spread.variants = {{}};
  spread.params = [](const std::vector<double>& x) { return Params{{"relative_sd", x[0]}}; };
  spread.physics = "relative sd of mu from trial to trial (its mean is the baseline's mu)";
  // every evaluation simulates the spread's quantiles: a paper-size Stribeck + spread sweep ran
  // for minutes with Stribeck scanned across it
  spread.scanned_across = false;
  return spread;
}

// tilt: gravity along the guide against the friction it competes with, sin(angle) / mu.
CandidateSpec tilt_candidate(const model::StageParams& st) {
  CandidateSpec tilt;
  tilt.effect = "tilt";
  tilt.axes = {{"sin_over_mu", -0.6, 0.6, false}};
  tilt.variants = {{}};
  const double mu = st.friction_coefficient;
  tilt.params = [mu](const std::vector<double>& x) {
    return Params{{"angle_deg", std::asin(std::clamp(x[0] * mu, -0.5, 0.5)) * 180 / M_PI}};
  };
  tilt.physics = "sin(angle) over the friction coefficient";
  return tilt;
}

// quantization: a DAC's resolution and clock against the fastest phase.
CandidateSpec quantization_candidate(const SweepScales& sc) {
  CandidateSpec dac;
  dac.effect = "quantization";
  dac.variants = {{}};
  for (double bits : {6.0, 8.0, 10.0, 12.0})
    for (double clock : {0.5, 2.0, 10.0})
      dac.grid.push_back({{"bits", bits},
                          {"update_rate_hz", clamp_to_library("quantization", "update_rate_hz",
                                                              std::round(clock * sc.fast_hz))}});
  dac.physics = "bits and update clock (0.5, 2 and 10 x the fastest phase's rate)";
  return dac;
}

}  // namespace

std::vector<CandidateSpec> candidate_library(const SweepCells& sweep) {
  const SweepScales sc = scales_of(sweep);
  const model::StageParams& st = sweep.stage.stage;
  return {amplifier_candidate(sc), compliance_candidate(sc, st), hysteresis_candidate(),
          creep_candidate(),       stribeck_candidate(sc),       friction_spread_candidate(),
          tilt_candidate(st),      quantization_candidate(sc)};
}

std::string search_range_problem(const SweepCells& sweep, const std::vector<std::string>& effects) {
  const SweepScales sc = scales_of(sweep);
  for (const CandidateSpec& spec : candidate_library(sweep))
    for (const FitAxis& a : spec.axes)
      if ((effects.empty() ||
           std::find(effects.begin(), effects.end(), spec.effect) != effects.end()) &&
          !(std::isfinite(a.lo) && std::isfinite(a.hi) && a.lo < a.hi &&
            (!a.log_scale || a.lo > 0)))
        return spec.effect + "'s " + a.name + ": [" + model::format_number(a.lo) + ", " +
               model::format_number(a.hi) + "] is empty (from the sweep's highest frequency " +
               model::format_number(sc.f_max_hz) + " Hz, its fastest phase's rate " +
               model::format_number(sc.fast_hz) + " Hz and the slider's speed " +
               model::format_number(sc.speed_m_s) + " m/s)";
  return "";
}

const CandidateSpec& spec_of(const std::vector<CandidateSpec>& library, const std::string& effect) {
  for (const CandidateSpec& s : library)
    if (s.effect == effect) return s;
  throw std::invalid_argument("no candidate " + effect);
}

std::string missing_signature(const SweepCells& sweep, const std::string& effect) {
  if (effect == "hysteresis") {
    std::set<double> strokes;
    for (const Cell& c : sweep.cells) strokes.insert(c.key.stroke_m);
    if (strokes.size() < 2) return "a second stroke (hysteresis depends on stroke, not frequency)";
  }
  if (effect == "tilt") {
    bool fwd = false, rev = false;
    for (const Cell& c : sweep.cells) {
      if (c.key.duty < 0.5) fwd = true;
      if (c.key.duty > 0.5) rev = true;
    }
    if (!(fwd && rev))
      return "both directions (duties below and above 0.5): in one direction a tilt is a friction "
             "change";
  }
  if (effect == "friction_spread") {
    bool two = false;
    for (const Cell& c : sweep.cells) two = two || (c.train.size() >= 2 && c.test.size() >= 2);
    if (!two) return "at least 4 trials per cell (the spread needs 2 to fit and 2 held out)";
  }
  return "";
}

}  // namespace idm::analysis
