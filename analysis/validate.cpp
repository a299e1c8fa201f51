#include "analysis/validate.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <random>
#include <sstream>

#include "analysis/unknown_effects.h"
#include "model/yaml_util.h"

namespace idm::analysis {

const std::vector<std::string>& validate_effects() {
  static const std::vector<std::string> e = {"amplifier", "actuator_compliance", "hysteresis",
                                             "stribeck",  "friction_spread",     "tilt"};
  return e;
}

std::vector<std::string> validate_cases(bool quick) {
  if (quick) return {"none", "amplifier", "friction_spread+tilt", "unknown:thermal_stroke"};
  std::vector<std::string> out{"none"};
  const std::vector<std::string>& e = validate_effects();
  for (const std::string& a : e) out.push_back(a);
  for (std::size_t i = 0; i < e.size(); ++i)
    for (std::size_t j = i + 1; j < e.size(); ++j)
      if (!(e[i] == "amplifier" && e[j] == "actuator_compliance")) out.push_back(e[i] + "+" + e[j]);
  for (const std::string& u : unknown_effect_names()) out.push_back("unknown:" + u);
  out.push_back("not_identifiable:tilt");
  out.push_back("not_identifiable:hysteresis");
  return out;
}

namespace {

std::vector<std::string> split(const std::string& s, char sep) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  std::string item;
  while (std::getline(ss, item, sep)) out.push_back(item);
  return out;
}

bool is_validate_effect(const std::string& e) {
  const std::vector<std::string>& v = validate_effects();
  return std::find(v.begin(), v.end(), e) != v.end();
}

[[noreturn]] void bad_case(const std::string& name) {
  std::string allowed;
  for (const std::string& e : validate_effects()) allowed += (allowed.empty() ? "" : ", ") + e;
  throw model::InputError(
      "validate case '" + name + "': allowed none, one of " + allowed +
      ", two of them joined by '+', unknown:stroke_saturation, unknown:thermal_stroke, "
      "not_identifiable:tilt, not_identifiable:hysteresis");
}

double round3(double v) {  // three significant digits, as a person would write them
  if (v == 0) return v;
  const double p = std::pow(10.0, std::floor(std::log10(std::fabs(v))) - 2);
  return std::round(v / p) * p;
}

}  // namespace

std::string case_class(const std::string& name) {
  if (name == "none") return "none";
  if (name.rfind("unknown:", 0) == 0) {
    const std::vector<std::string>& u = unknown_effect_names();
    if (std::find(u.begin(), u.end(), name.substr(8)) == u.end()) bad_case(name);
    return "unknown";
  }
  if (name.rfind("not_identifiable:", 0) == 0) {
    const std::string e = name.substr(17);
    if (e != "tilt" && e != "hysteresis") bad_case(name);
    return "not_identifiable";
  }
  const std::vector<std::string> parts = split(name, '+');
  for (const std::string& p : parts)
    if (!is_validate_effect(p)) bad_case(name);
  if (parts.size() == 1) return "single";
  if (parts.size() == 2 && parts[0] != parts[1]) return "pair";
  bad_case(name);
}

std::string Scenario::describe() const {
  std::ostringstream s;
  const model::StageParams& p = stage.stage;
  s.precision(3);
  s << "M " << p.slider_mass_kg << " kg, m " << p.counter_mass_kg << " kg, mu "
    << p.friction_coefficient << ", S " << p.stroke_m * 1e6 << " um; " << plan.freqs_hz.size()
    << " x " << plan.duties.size() << " cells x " << std::max<std::size_t>(1, plan.strokes_m.size())
    << " stroke(s), " << plan.trials << " trials, " << plan.sample_rate_hz / 1e3 << " kHz, "
    << plan.freqs_hz.front() << "-" << plan.freqs_hz.back() << " Hz";
  return s.str();
}

namespace {

// The hidden library effect's parameters, from ranges scaled to the stage and the sweep.
model::EffectSpec draw_effect(const std::string& effect, const Scenario& sc, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  auto lin = [&](double lo, double hi) { return lo + u(rng) * (hi - lo); };
  auto logu = [&](double lo, double hi) { return std::exp(lin(std::log(lo), std::log(hi))); };
  const model::StageParams& st = sc.stage.stage;
  const double f_max = sc.plan.freqs_hz.back();
  const double fast_hz = f_max / sc.plan.duties.front();  // the shortest phase's rate
  model::EffectSpec s{effect, {}};
  if (effect == "amplifier") {
    s.params["order"] = u(rng) < 0.5 ? 1 : 2;
    s.params["cutoff_hz"] = round3(fast_hz * logu(0.08, 0.4));
  } else if (effect == "actuator_compliance") {
    const double m_red = st.reduced_mass_kg();
    const double k = m_red * std::pow(2 * M_PI * fast_hz * logu(0.08, 0.4), 2);
    s.params["stiffness_n_m"] = round3(k);
    s.params["damping_n_s_m"] = round3(2 * logu(0.08, 0.4) * std::sqrt(k * m_red));
  } else if (effect == "hysteresis") {
    s.params["ratio"] = round3(lin(0.05, 0.2));
  } else if (effect == "stribeck") {
    // against the slider's typical velocity jump at a corner
    const double speed = st.mass_ratio() * st.stroke_m * fast_hz / 2;
    s.params["static_over_kinetic"] = round3(lin(1.3, 2.0));
    s.params["stribeck_velocity_m_s"] = round3(speed * logu(0.03, 0.3));
  } else if (effect == "friction_spread") {
    s.params["relative_sd"] = round3(lin(0.05, 0.2));
  } else if (effect == "tilt") {
    const double sine = st.friction_coefficient * lin(0.05, 0.3) * (u(rng) < 0.5 ? -1 : 1);
    s.params["angle_deg"] = round3(std::asin(sine) * 180 / M_PI);
  }
  return model::complete_effect(s, "validate");
}

// A stage in the ranges, with nominal K and C of a resonance at 1.5-5 kHz.
model::StageFile draw_stage(std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  auto lin = [&](double lo, double hi) { return lo + u(rng) * (hi - lo); };
  auto logu = [&](double lo, double hi) { return std::exp(lin(std::log(lo), std::log(hi))); };
  model::StageFile f;
  model::StageParams& s = f.stage;
  s.slider_mass_kg = round3(logu(0.05, 0.5));
  s.counter_mass_kg = round3(s.slider_mass_kg * lin(0.2, 0.5));
  s.friction_coefficient = round3(lin(0.15, 0.7));
  s.stroke_m = round3(logu(5e-6, 50e-6));
  s.gravity_m_s2 = 9.8;
  s.step_correction = 0.35;
  const double m_red = s.reduced_mass_kg();
  s.stiffness_n_m = round3(m_red * std::pow(2 * M_PI * logu(1500, 5000), 2));
  s.damping_n_s_m = round3(2 * lin(0.1, 0.3) * std::sqrt(s.stiffness_n_m * m_red));
  const double counts[] = {1.2363e-9, 2.4727e-9, 4.9453e-9, 9.8906e-9};  // lambda / 512 ... / 64
  f.interferometer.resolution_m = counts[static_cast<std::size_t>(u(rng) * 4) % 4];
  return f;
}

}  // namespace

Scenario make_scenario(const std::string& name, std::uint64_t seed, bool quick) {
  Scenario sc;
  sc.name = name;
  sc.cls = case_class(name);
  sc.seed = seed;
  std::mt19937_64 rng(seed * 1000003ULL + std::hash<std::string>{}(name));
  std::uniform_real_distribution<double> u(0.0, 1.0);
  auto pick = [&](int lo, int hi) {
    return lo + static_cast<int>(u(rng) * (hi - lo + 1)) % (hi - lo + 1);
  };
  sc.stage = draw_stage(rng);
  const std::vector<std::string> hidden = sc.cls == "single" || sc.cls == "pair" ? split(name, '+')
                                          : sc.cls == "not_identifiable"
                                              ? std::vector<std::string>{name.substr(17)}
                                              : std::vector<std::string>{};
  auto hides = [&](const char* e) {
    return std::find(hidden.begin(), hidden.end(), e) != hidden.end();
  };
  // the lab's sampling
  SweepPlan& p = sc.plan;
  p.sample_rate_hz = 1e3 * std::round(10 + 40 * u(rng));
  p.trials = hides("friction_spread") ? pick(4, 5) : pick(3, 5);
  p.cycles = 10;
  p.seed = seed;
  const bool two_dirs = hides("tilt") ? sc.cls != "not_identifiable" : u(rng) < 0.5;
  const bool two_strokes = hides("hysteresis") ? sc.cls != "not_identifiable" : u(rng) < 0.4;
  // frequencies up to where the impulse ratio reaches 0.25-0.6 (every region of the map)
  const model::StageParams& st = sc.stage.stage;
  const double beta_max = 0.25 + 0.35 * u(rng);
  double f_max = std::sqrt(beta_max * st.total_mass_kg() * st.friction_coefficient *
                           st.gravity_m_s2 / (st.counter_mass_kg * st.stroke_m));
  f_max = std::clamp(std::round(f_max), 40.0, std::min(2000.0, p.sample_rate_hz / 25));
  const int n_f = quick ? 4 : pick(4, 8);
  int n_d = quick ? 5 : pick(5, 8);
  while (n_f * n_d * (two_dirs ? 2 : 1) * (two_strokes ? 2 : 1) > 96 && n_d > 5) --n_d;
  const double f_min = f_max / (4 + 4 * u(rng));
  for (int i = 0; i < n_f; ++i)
    p.freqs_hz.push_back(std::round(f_min + (f_max - f_min) * i / (n_f - 1)));
  for (int i = 0; i < n_d; ++i)
    p.duties.push_back(std::round(1000 * (0.05 + 0.4 * i / (n_d - 1))) / 1000);
  if (two_dirs)
    for (int i = 0; i < n_d; ++i)
      p.duties.push_back(std::round(1000 * (1 - p.duties[static_cast<std::size_t>(i)])) / 1000);
  p.strokes_m = {st.stroke_m};
  if (two_strokes) p.strokes_m.push_back(st.stroke_m / 2);
  // noise and the hidden effects
  sc.sim.plant = model::PlantKind::Rigid;
  sc.sim.seed = seed;
  sc.sim.noise_m = 0.5e-9 + 2.5e-9 * u(rng);
  sc.stage.interferometer.noise_m = sc.sim.noise_m;
  for (const std::string& e : hidden) {
    const model::EffectSpec spec = draw_effect(e, sc, rng);
    sc.sim.effects.push_back(spec);
    for (const auto& [k, v] : spec.params) {
      if ((e == "friction_spread" && (k == "correlation_m" || k == "mean_shift")) ||
          (k == "slew_rate_m_s"))
        continue;
      sc.params[e + "." + k] = v;
    }
  }
  if (sc.cls == "unknown") {
    sc.unknown = name.substr(8);
    sc.unknown_strength = u(rng);
    std::map<std::string, double> params;
    make_unknown_effect(sc.unknown, sc.unknown_strength, st.stroke_m, f_max, params);
    for (const auto& [k, v] : params) sc.params[sc.unknown + "." + k] = v;
  }
  if (sc.cls == "single" || sc.cls == "pair") sc.expected = hidden;
  std::sort(sc.expected.begin(), sc.expected.end());
  sc.expect_unexplained = sc.cls == "unknown";
  return sc;
}

}  // namespace idm::analysis
