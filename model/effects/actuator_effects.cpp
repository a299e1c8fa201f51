#include "model/effects/actuator_effects.h"

#include <algorithm>

#include "model/effects/amplifier.h"
#include "model/effects/creep.h"
#include "model/effects/hysteresis.h"
#include "model/effects/param_check.h"
#include "model/effects/quantization.h"
#include "model/stage.h"
#include "model/yaml_util.h"

namespace idm::model {

namespace {

using effects_detail::to_integer;

// One table: effect name and its keys, in the order the README lists them.
struct EffectKeys {
  const char* name;
  std::vector<std::string> keys;
};

const std::vector<EffectKeys>& effect_table() {
  static const std::vector<EffectKeys> table = {
      {"amplifier", {"order", "cutoff_hz", "slew_rate_m_s"}},
      {"hysteresis", {"ratio", "stroke_m"}},
      {"creep", {"per_decade"}},
      {"quantization", {"bits", "update_rate_hz", "full_scale_m"}},
  };
  return table;
}

void check_keys(const std::string& name, const std::vector<std::string>& allowed,
                const std::map<std::string, double>& params) {
  for (const auto& [key, value] : params) {
    if (std::find(allowed.begin(), allowed.end(), key) != allowed.end()) continue;
    throw InputError(name + "." + key + ": " + model::unknown_name(key, allowed, "parameter"));
  }
}

// Sets `target` from params[key] when present.
void take(const std::map<std::string, double>& params, const std::string& key, double& target) {
  if (const auto it = params.find(key); it != params.end()) target = it->second;
}
void take_integer(const std::string& name, const std::map<std::string, double>& params,
                  const std::string& key, int lo, int hi, int& target) {
  if (const auto it = params.find(key); it != params.end())
    target = to_integer(name, key, it->second, lo, hi);
}

}  // namespace

std::vector<std::string> actuator_effect_names() {
  std::vector<std::string> names;
  for (const EffectKeys& e : effect_table()) names.emplace_back(e.name);
  return names;
}

std::vector<std::string> actuator_effect_keys(const std::string& name) {
  for (const EffectKeys& e : effect_table())
    if (name == e.name) return e.keys;
  return {};
}

std::unique_ptr<ActuatorEffect> make_actuator_effect(const std::string& name,
                                                     const std::map<std::string, double>& params) {
  const std::vector<std::string> keys = actuator_effect_keys(name);
  if (keys.empty()) return nullptr;
  check_keys(name, keys, params);

  if (name == "amplifier") {
    Amplifier::Params p;
    take_integer(name, params, "order", 1, 2, p.order);
    take(params, "cutoff_hz", p.cutoff_hz);
    take(params, "slew_rate_m_s", p.slew_rate_m_s);
    p.validate(name);
    return std::make_unique<Amplifier>(p);
  }
  if (name == "hysteresis") {
    Hysteresis::Params p;
    take(params, "ratio", p.ratio);
    take(params, "stroke_m", p.stroke_m);
    p.validate(name);
    return std::make_unique<Hysteresis>(p);
  }
  if (name == "creep") {
    Creep::Params p;
    take(params, "per_decade", p.per_decade);
    p.validate(name);
    return std::make_unique<Creep>(p);
  }
  Quantization::Params p;  // "quantization", the last name in the table
  take_integer(name, params, "bits", 1, 24, p.bits);
  take(params, "update_rate_hz", p.update_rate_hz);
  take(params, "full_scale_m", p.full_scale_m);
  p.validate(name);
  return std::make_unique<Quantization>(p);
}

}  // namespace idm::model
