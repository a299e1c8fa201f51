#include "model/stage.h"

#include <cmath>
#include <set>
#include <sstream>
#include <stdexcept>

#include "model/range.h"
#include "model/yaml_util.h"

namespace idm::model {

namespace {

// One table of the stage keys: name, member, range, unit, meaning. Used for reading, writing,
// validating and config/README.md's rows.
struct StageKey {
  const char* name;
  double StageParams::*member;
  Range range;
  bool required_in_dataset;
  const char* unit;
  const char* doc;
};

constexpr StageKey kStageKeys[] = {
    {"slider_mass_kg",
     &StageParams::slider_mass_kg,
     {1e-6, 1e3},
     true,
     "kg",
     "M, the slider (Table 1)"},
    {"counter_mass_kg",
     &StageParams::counter_mass_kg,
     {1e-6, 1e3},
     true,
     "kg",
     "m, the counter mass on the actuator's free end (Table 1)"},
    {"friction_coefficient",
     &StageParams::friction_coefficient,
     {0.0, kMaxFrictionCoefficient, true},
     true,
     "1",
     "mu, kinetic (Coulomb) friction between slider and guide"},
    {"gravity_m_s2",
     &StageParams::gravity_m_s2,
     {0.0, 100.0, true},
     true,
     "m/s²",
     "g, the normal load per mass"},
    {"stroke_m",
     &StageParams::stroke_m,
     {0.0, 1e-3, true},
     true,
     "m",
     "S, the actuator's nominal stroke"},
    {"step_correction",
     &StageParams::step_correction,
     {0.0, 1.0, true},
     true,
     "1",
     "alpha of eq 22 (config/idmd.yaml and idmd-xyz.yaml give 1.0: their rigid plant is the "
     "ideal model; idmd-modbus.yaml and idmd-usb.yaml 0.35, a stage with compliance)"},
    {"stiffness_n_m",
     &StageParams::stiffness_n_m,
     {0.0, 1e12, true},
     false,
     "N/m",
     "K of eq 30, the actuator (mck plant)"},
    {"damping_n_s_m",
     &StageParams::damping_n_s_m,
     {0.0, 1e6, false},
     false,
     "N s/m",
     "C of eq 30, the actuator (mck plant)"},
};

}  // namespace

void validate(const StageParams& stage, const std::string& where) {
  for (const StageKey& k : kStageKeys) {
    check_range(where, k.name, stage.*k.member, k.range);
  }
}

void validate(const InterferometerParams& ifm, const std::string& where) {
  check_range(where, "resolution_m", ifm.resolution_m, Range{0, 1e-6, true});
  check_range(where, "noise_m", ifm.noise_m, Range{0, 1e-6});
}

StageFile parse_stage_yaml(const YAML::Node& root, const std::string& file,
                           const StageYamlOptions& options) {
  StageFile out;
  if (!root.IsMap()) throw InputError(file + ": expected a YAML map with a 'stage:' section");
  const YAML::Node stage = root["stage"];
  if (!stage) {
    if (options.require_dataset_keys) throw InputError(file + ": stage: missing section");
  } else {
    if (!stage.IsMap()) throw InputError(located(file, stage, "stage", "expected a map"));
    std::set<std::string> known;
    for (const StageKey& k : kStageKeys) {
      known.insert(k.name);
      const YAML::Node value = stage[k.name];
      if (!value) {
        if (options.require_dataset_keys && k.required_in_dataset)
          throw InputError(
              located(file, stage, std::string("stage.") + k.name, "missing required key"));
        continue;
      }
      out.stage.*k.member = read_double(value, file, std::string("stage.") + k.name, k.range.lo,
                                        k.range.hi, k.range.lo_open);
    }
    known.insert("travel_m");
    if (const YAML::Node travel = stage["travel_m"]) {
      const std::string key = "stage.travel_m";
      if (!travel.IsSequence() || travel.size() != 2)
        throw InputError(
            located(file, travel, key, "expected [lower, upper] in metres, e.g. [-5e-3, 5e-3]"));
      out.travel_lower_m = read_double(travel[0], file, key + "[0]", -10.0, 10.0);
      out.travel_upper_m = read_double(travel[1], file, key + "[1]", -10.0, 10.0);
      if (!(out.travel_lower_m < out.travel_upper_m))
        throw InputError(located(file, travel, key,
                                 "[" + format_number(out.travel_lower_m) + ", " +
                                     format_number(out.travel_upper_m) +
                                     "] is not a range: lower must be below upper"));
    }
    if (options.strict) {
      for (const auto& kv : stage) {
        const std::string key = kv.first.as<std::string>();
        if (!known.count(key))
          throw InputError(located(file, kv.first, "stage." + key,
                                   unknown_name(key, {known.begin(), known.end()})));
      }
    }
  }
  const YAML::Node ifm = root["interferometer"];
  if (ifm) {
    if (!ifm.IsMap()) throw InputError(located(file, ifm, "interferometer", "expected a map"));
    if (ifm["resolution_m"])
      out.interferometer.resolution_m =
          read_double(ifm["resolution_m"], file, "interferometer.resolution_m", 0.0, 1e-6, true);
    if (ifm["noise_m"])
      out.interferometer.noise_m =
          read_double(ifm["noise_m"], file, "interferometer.noise_m", 0.0, 1e-6);
  } else if (options.require_dataset_keys) {
    throw InputError(file + ": interferometer: missing section (needs resolution_m)");
  }
  return out;
}

StageFile load_stage_file(const std::string& path, const StageYamlOptions& options) {
  return parse_stage_yaml(load_yaml_file(path), path, options);
}

const Range& stage_key_range(const std::string& key) {
  for (const StageKey& k : kStageKeys)
    if (key == k.name) return k.range;
  throw std::invalid_argument("stage_key_range: '" + key + "' is not a stage key");
}

std::string stage_reference_rows() {
  const StageParams defaults;
  std::string out;
  for (const StageKey& k : kStageKeys)
    out += std::string("| ") + k.name + " | " + k.unit + " | " + format_number(defaults.*k.member) +
           " | " + k.range.text() + " | " + k.doc + " |\n";
  out +=
      "| travel_m | m | **required** by idmd | [lower, upper] in [-10, 10], lower < upper | the "
      "stage's mechanical range; the soft limits default to it, and no move, STEP or LIM may "
      "leave it |\n";
  return out;
}

std::string to_yaml(const StageFile& f) {
  std::ostringstream out;
  out.precision(17);
  out << "stage:\n";
  for (const StageKey& k : kStageKeys) out << "  " << k.name << ": " << f.stage.*k.member << "\n";
  if (f.has_travel())
    out << "  travel_m: [" << f.travel_lower_m << ", " << f.travel_upper_m << "]\n";
  out << "interferometer:\n";
  out << "  resolution_m: " << f.interferometer.resolution_m << "\n";
  out << "  noise_m: " << f.interferometer.noise_m << "\n";
  return out.str();
}

}  // namespace idm::model
