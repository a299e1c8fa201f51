#include "model/simulation.h"

#include <cmath>
#include <sstream>

#include "model/effects/actuator_effects.h"
#include "model/yaml_util.h"

namespace idm::model {

const char* plant_name(PlantKind kind) {
  switch (kind) {
    case PlantKind::Impulse:
      return "impulse";
    case PlantKind::Rigid:
      return "rigid";
    case PlantKind::MassDamperSpring:
      return "mck";
  }
  return "?";
}

PlantKind parse_plant_name(const std::string& name) {
  if (name == "impulse") return PlantKind::Impulse;
  if (name == "rigid") return PlantKind::Rigid;
  if (name == "mck") return PlantKind::MassDamperSpring;
  throw InputError("plant: unknown plant '" + name + "', allowed impulse, rigid, mck");
}

const std::vector<EffectInfo>& effect_library() {
  static const std::vector<EffectInfo> library = {
      {"amplifier",
       "finite bandwidth or slew rate between commanded and actual actuator length",
       {{"order", 2, 1, 2, "Butterworth order, 1 or 2"},
        {"cutoff_hz", 3000, 10, 1e6, "-3 dB frequency"},
        {"slew_rate_m_s", 0, 0, 100, "slew-rate limit of the actuator length, 0 = none"}}},
      {"actuator_compliance",
       "actuator stiffness and damping: the mass-damper-spring model of eq 30",
       {{"stiffness_n_m", 5.7e6, 1e4, 1e12, "K"}, {"damping_n_s_m", 230, 0, 1e5, "C"}}},
      {"hysteresis",
       "rate-independent hysteresis between command and actuator length",
       {{"ratio", 0.15, 0, 0.5, "loop width over stroke"}}},
      {"creep",
       "slow drift of the actuator length after a change",
       {{"per_decade", 0.01, 0, 0.1, "relative change per decade of time"}}},
      {"stribeck",
       "velocity-dependent friction: static above kinetic, Stribeck curve",
       {{"static_over_kinetic", 1.15, 1, 3, "mu_s / mu_k"},
        {"stribeck_velocity_m_s", 1e-3, 1e-6, 1, "Stribeck velocity"}}},
      {"friction_spread",
       "friction that varies along the guide, trial to trial",
       {{"relative_sd", 0.1, 0, 0.5, "relative standard deviation of mu along the guide"},
        {"correlation_m", 2e-3, 1e-6, 1, "correlation length along the guide"},
        {"mean_shift", 0, -0.5, 0.5,
         "mean relative change of mu over the stretch of guide in use"}}},
      {"tilt",
       "a gravity component along the axis (guide not level)",
       {{"angle_deg", 1, -30, 30, "positive: the positive direction is uphill"}}},
      {"quantization",
       "the DAC's finite resolution and update clock of the waveform",
       {{"bits", 12, 1, 24, "DAC resolution"},
        {"update_rate_hz", 100e3, 100, 1e8, "DAC update clock"}}},
  };
  return library;
}

namespace {
const EffectInfo* find_info(const std::string& name) {
  for (const EffectInfo& e : effect_library())
    if (name == e.name) return &e;
  return nullptr;
}
std::string known_effects() {
  std::string out;
  for (const EffectInfo& e : effect_library())
    out += (out.empty() ? "" : ", ") + std::string(e.name);
  return out;
}
}  // namespace

EffectSpec complete_effect(const EffectSpec& spec, const std::string& where) {
  const EffectInfo* info = find_info(spec.name);
  if (!info)
    throw InputError(where + ": unknown effect '" + spec.name + "', allowed " + known_effects());
  EffectSpec out{spec.name, {}};
  for (const auto& [key, value] : spec.params) {
    const EffectParamInfo* p = nullptr;
    for (const EffectParamInfo& q : info->params)
      if (key == q.name) p = &q;
    if (!p) {
      std::string allowed;
      for (const EffectParamInfo& q : info->params)
        allowed += (allowed.empty() ? "" : ", ") + std::string(q.name);
      throw InputError(where + ": " + spec.name + "." + key + ": unknown parameter, allowed " +
                       allowed);
    }
    if (!std::isfinite(value) || value < p->lo || value > p->hi)
      throw InputError(where + ": " + spec.name + "." + key + ": " + model::format_number(value) +
                       " is out of range, allowed [" + model::format_number(p->lo) + ", " +
                       model::format_number(p->hi) + "]");
    if ((key == "order" || key == "bits") && value != std::floor(value))
      throw InputError(where + ": " + spec.name + "." + key + ": " + model::format_number(value) +
                       " must be an integer");
    out.params[key] = value;
  }
  for (const EffectParamInfo& q : info->params)
    if (!out.params.count(q.name)) out.params[q.name] = q.default_value;
  return out;
}

EffectSpec parse_effect_arg(const std::string& text) {
  const std::string where = "--effect " + text;
  EffectSpec spec;
  const auto colon = text.find(':');
  spec.name = text.substr(0, colon);
  if (colon != std::string::npos) {
    std::stringstream rest(text.substr(colon + 1));
    std::string item;
    while (std::getline(rest, item, ',')) {
      if (item.empty()) continue;
      const auto eq = item.find('=');
      if (eq == std::string::npos) throw InputError(where + ": '" + item + "' is not key=value");
      const std::string key = item.substr(0, eq), value = item.substr(eq + 1);
      double v = 0;
      if (parse_decimal(value, v) != NumberText::Ok)
        throw InputError(where + ": " + spec.name + "." + key + ": '" + value +
                         "' is not a finite number");
      spec.params[key] = v;
    }
  }
  return complete_effect(spec, where);
}

bool SimConfig::has(const std::string& effect) const {
  return find(effect) != nullptr;
}

const EffectSpec* SimConfig::find(const std::string& effect) const {
  for (const EffectSpec& e : effects)
    if (e.name == effect) return &e;
  return nullptr;
}

const ParamTable<SimConfig>& sim_params() {
  using C = SimConfig;
  static const ParamTable<C> table({
      choice<C, PlantKind>(
          "plant",
          {{plant_name(PlantKind::Rigid), PlantKind::Rigid},
           {plant_name(PlantKind::Impulse), PlantKind::Impulse},
           {plant_name(PlantKind::MassDamperSpring), PlantKind::MassDamperSpring}},
          "rigid: the two-mass plant; impulse: the ideal model, no effects; mck: the actuator's K "
          "and C",
          [](auto& c) -> auto& { return c.plant; }),
      custom<C>("effects", "map", "NAME: {PARAM: value}, docs/gap-report.md", "none",
                "unmodelled effects the simulated stage adds",
                [](C& c, const YAML::Node& v, const std::string& file, const std::string& key) {
                  if (!v.IsMap())
                    throw InputError(located(file, v, key, "expected a map NAME: {PARAM: value}"));
                  for (const auto& e : v) {
                    EffectSpec spec;
                    spec.name = e.first.as<std::string>();
                    const std::string k = key + "." + spec.name;
                    if (e.second && !e.second.IsNull()) {
                      if (!e.second.IsMap())
                        throw InputError(located(file, e.second, k, "expected a map PARAM: value"));
                      for (const auto& p : e.second) {
                        const std::string pk = p.first.as<std::string>();
                        spec.params[pk] = read_double(p.second, file, k + "." + pk, -1e300, 1e300);
                      }
                    }
                    const std::string at =
                        file + ":" + std::to_string(e.first.Mark().line + 1) + ": " + key;
                    c.effects.push_back(complete_effect(spec, at));
                  }
                }),
      integer<C>(
          "seed", "", 0, 1L << 62, "the random streams' seed (noise, effects)",
          [](auto& c) -> auto& { return c.seed; }),
      real<C>(
          "noise_m", "m", {0, 1e-6}, "interferometer noise, rms, before quantization",
          [](auto& c) -> auto& { return c.noise_m; }),
      real<C>(
          "internal_rate_hz", "Hz", {1e3, 1e8},
          "the plant's rate when actuator effects smooth the command",
          [](auto& c) -> auto& { return c.internal_rate_hz; }),
      real<C>(
          "start_position_m", "m", {-10, 10},
          "where the slider rests when the device is first opened",
          [](auto& c) -> auto& { return c.start_position_m; }),
      custom<C>("end_stops_m", "m", "[low, high] in [-10, 10], low < high",
                "the ends of stage.travel_m", "hard stops the slider cannot pass",
                [](C& c, const YAML::Node& v, const std::string& file, const std::string& key) {
                  if (!v.IsSequence() || v.size() != 2)
                    throw InputError(located(file, v, key, "expected [low, high] in metres"));
                  c.end_stop_low_m = read_double(v[0], file, key + "[0]", -10, 10);
                  c.end_stop_high_m = read_double(v[1], file, key + "[1]", -10, 10);
                  if (!(c.end_stop_low_m < c.end_stop_high_m))
                    throw InputError(located(file, v, key, "low must be below high"));
                }),
      with_default(real<C>(
                       "reference_mark_m", "m", {-10, 10},
                       "an index mark (a slider position) REFerence MARK finds: the word after "
                       "each crossing carries the reference mark bit",
                       [](auto& c) -> auto& { return c.reference_mark_m; }),
                   "none"),
  });
  return table;
}

SimConfig parse_sim_yaml(const YAML::Node& node, const std::string& file) {
  SimConfig c;
  if (!node) return c;
  sim_params().read(node, file, "sim", c);
  if (c.plant == PlantKind::Impulse && !c.effects.empty())
    throw InputError(
        file +
        ": sim.plant: the impulse plant is the ideal model and takes no effects; use rigid or mck");
  return c;
}

StageParams effective_stage(const StageParams& stage, const SimConfig& config) {
  StageParams s = stage;
  if (const EffectSpec* e = config.find("actuator_compliance")) {
    s.stiffness_n_m = e->params.at("stiffness_n_m");
    s.damping_n_s_m = e->params.at("damping_n_s_m");
  }
  return s;
}

FrictionLaw friction_law(const StageParams& stage, const SimConfig& config) {
  FrictionLaw f = FrictionLaw::coulomb(stage);
  if (const EffectSpec* e = config.find("stribeck")) {
    f.static_over_kinetic = e->params.at("static_over_kinetic");
    f.stribeck_velocity_m_s = e->params.at("stribeck_velocity_m_s");
  }
  if (const EffectSpec* e = config.find("tilt"))
    f.tilt_rad = e->params.at("angle_deg") * M_PI / 180.0;
  if (const EffectSpec* e = config.find("friction_spread"))
    f.profile = GuideProfile(e->params.at("relative_sd"), e->params.at("correlation_m"),
                             config.seed * 7919 + 17, e->params.at("mean_shift"));
  return f;
}

SimulatedStage::SimulatedStage(const StageParams& stage, const InterferometerParams& ifm,
                               const SimConfig& config)
    : stage_(effective_stage(stage, config)), ifm_(ifm), config_(config) {
  validate(stage_);
  validate(ifm_);
  const bool compliant =
      config.plant == PlantKind::MassDamperSpring || config.has("actuator_compliance");
  plant_ = make_plant(compliant ? ActuatorKind::MassDamperSpring : ActuatorKind::Rigid, stage_,
                      friction_law(stage_, config));
  plant_->set_end_stops(config.end_stop_low_m, config.end_stop_high_m);
  // The actuator chain in signal order: DAC, amplifier, hysteresis, creep.
  for (const char* name : {"quantization", "amplifier", "hysteresis", "creep"}) {
    const EffectSpec* e = config.find(name);
    if (!e) continue;
    std::map<std::string, double> params = e->params;
    if (e->name == "hysteresis") params["stroke_m"] = stage_.stroke_m;
    if (e->name == "quantization") params["full_scale_m"] = 2.0 * stage_.stroke_m;
    chain_.push_back(make_actuator_effect(e->name, params));
  }
  reset(0.0, config.seed);
}

double SimulatedStage::next_kink_s(double rate_m_s) const {
  // one piecewise-linear effect sees the command itself; a chain of them is not handled here
  if (chain_.size() != 1) return -1.0;
  return chain_.front()->next_kink_s(rate_m_s);
}

void SimulatedStage::reset(double x_m, std::uint64_t noise_seed) {
  plant_->reset(x_m, 0.0);
  for (auto& e : chain_) e->reset(0.0);
  xi_cmd_m_ = 0.0;
  noise_rng_.seed(noise_seed);
  normal_.reset();
}

void SimulatedStage::displace(double dx_m) {
  plant_->displace(dx_m);
  const double x = plant_->position_m();
  if (x < plant_->stop_low_m()) plant_->displace(plant_->stop_low_m() - x);  // not through a stop
  if (x > plant_->stop_high_m()) plant_->displace(plant_->stop_high_m() - x);
}

void SimulatedStage::advance(double dt_s, double xi_cmd_end_m) {
  double xi = xi_cmd_end_m;
  for (auto& e : chain_) xi = e->step(xi, dt_s);
  plant_->step(dt_s, xi);
  xi_cmd_m_ = xi_cmd_end_m;
}

void SimulatedStage::step(double dt_s, double xi_cmd_end_m) {
  if (chain_.empty()) {
    advance(dt_s, xi_cmd_end_m);
    return;
  }
  // Smoothing effects: run at the internal rate, the command linear within the step.
  const int n = std::max(1, static_cast<int>(std::ceil(dt_s * config_.internal_rate_hz - 1e-9)));
  const double h = dt_s / n;
  const double xi0 = xi_cmd_m_;
  for (int k = 1; k <= n; ++k) advance(h, xi0 + (xi_cmd_end_m - xi0) * k / n);
}

double SimulatedStage::measured_m() {
  double x = plant_->position_m();
  if (config_.noise_m > 0) x += config_.noise_m * normal_(noise_rng_);
  return std::round(x / ifm_.resolution_m) * ifm_.resolution_m;
}

void SimulatedStage::run_burst(const TriangleWave& w, double rate_hz, double pre_s, double post_s,
                               TrialSamples& out) {
  const long n_pre = std::lround(pre_s * rate_hz);
  const long n_total = n_pre + std::lround((w.duration_s() + post_s) * rate_hz) + 1;
  out.t_s.reserve(out.t_s.size() + n_total);
  out.xi_cmd_m.reserve(out.xi_cmd_m.size() + n_total);
  out.x_m.reserve(out.x_m.size() + n_total);
  const std::vector<double> corners = w.corner_times_s();
  const bool exact_corners = chain_.empty();
  std::size_t next = 0;
  double t = -static_cast<double>(n_pre) / rate_hz;
  for (long k = 0; k < n_total; ++k) {
    const double t_k = static_cast<double>(k - n_pre) / rate_hz;
    if (k > 0) {
      // step to every corner before this sample, then to the sample
      while (next < corners.size() && corners[next] < t_k - 1e-13 / rate_hz) {
        if (corners[next] > t && exact_corners) {
          step(corners[next] - t, w.xi_m(corners[next]));
          t = corners[next];
        }
        ++next;
      }
      if (next < corners.size() && std::fabs(corners[next] - t_k) <= 1e-13 / rate_hz) ++next;
    }
    const double xi_k = w.xi_m(t_k);
    if (k > 0) {
      if (t_k > t) step(t_k - t, xi_k);
      t = t_k;
    }
    out.t_s.push_back(t_k);
    out.xi_cmd_m.push_back(xi_k);
    out.x_m.push_back(measured_m());
  }
}

}  // namespace idm::model
