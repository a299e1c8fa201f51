// Builds an actuator-chain effect by its name in the gap report's effect table
// (docs/gap-report.md): "amplifier", "hysteresis", "creep", "quantization".
#pragma once

#include <map>
#include <memory>
#include <string>
#include <vector>

#include "model/effects/actuator_effect.h"

namespace idm::model {

// The effect with its parameters: missing keys keep their documented defaults; an unknown key or a
// value out of range throws InputError naming the effect and the key (and, for an unknown key,
// listing the allowed ones). Returns nullptr for a name that is not an actuator-chain effect, so
// that the caller can look it up elsewhere.
std::unique_ptr<ActuatorEffect> make_actuator_effect(const std::string& name,
                                                     const std::map<std::string, double>& params);

// The names make_actuator_effect builds, and the parameter keys of one of them (empty if unknown).
std::vector<std::string> actuator_effect_names();
std::vector<std::string> actuator_effect_keys(const std::string& name);

}  // namespace idm::model
