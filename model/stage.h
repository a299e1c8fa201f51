// Stage parameters (the paper's Table 1 by default) and their YAML form.
#pragma once

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <limits>
#include <optional>
#include <stdexcept>
#include <string>

namespace idm::model {

// An input error that names where it happened: "FILE:LINE: key: what (allowed range)".
class InputError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// The largest friction coefficient a stage may have (stage.friction_coefficient's range is
// (0, kMaxFrictionCoefficient]): a fit of mu stays at or below it.
constexpr double kMaxFrictionCoefficient = 2.0;

// The mechanical stage (SI units).
struct StageParams {
  double slider_mass_kg = 0.16557;    // M
  double counter_mass_kg = 0.05761;   // m
  double friction_coefficient = 0.4;  // mu (kinetic, Coulomb)
  double gravity_m_s2 = 9.8;          // g
  double stroke_m = 20.35e-6;         // S, nominal actuator stroke
  double step_correction = 0.35;      // alpha of eq 22
  double stiffness_n_m = 5.7e6;       // K of eq 30 (actuator)
  double damping_n_s_m = 230.0;       // C of eq 30 (actuator)

  double total_mass_kg() const { return slider_mass_kg + counter_mass_kg; }
  // m/(M+m): the slider's share of an actuator velocity jump (eqs 1-3).
  double mass_ratio() const { return counter_mass_kg / total_mass_kg(); }
  double reduced_mass_kg() const { return slider_mass_kg * counter_mass_kg / total_mass_kg(); }
  // mu g: the sliding deceleration under Coulomb friction.
  double friction_decel_m_s2() const { return friction_coefficient * gravity_m_s2; }
};

// The laser interferometer as the model sees it.
struct InterferometerParams {
  double resolution_m = 9.8906e-9;  // one count of the position word
  double noise_m = 0.0;             // rms noise added before quantization
};

struct StageFile {
  StageParams stage;
  InterferometerParams interferometer;
  // stage.travel_m: [lower, upper], the stage's mechanical range in interferometer coordinates
  // (m). NaN when the file does not give it (datasets need not; idmd requires it).
  double travel_lower_m = std::numeric_limits<double>::quiet_NaN();
  double travel_upper_m = std::numeric_limits<double>::quiet_NaN();
  bool has_travel() const { return !std::isnan(travel_lower_m) && !std::isnan(travel_upper_m); }
};

// Throws InputError naming the parameter and the allowed range when a value is out of range.
void validate(const StageParams& stage, const std::string& where = "stage");
void validate(const InterferometerParams& ifm, const std::string& where = "interferometer");

// Reads the `stage:` and `interferometer:` sections (keys of docs/sweep-dataset.md).
// Missing optional keys keep their defaults; `required` lists stage keys that must be present.
// When `strict`, unknown keys in those sections are errors; otherwise they are ignored.
struct StageYamlOptions {
  bool strict = false;
  bool require_dataset_keys = false;  // the six keys docs/sweep-dataset.md requires
};
StageFile parse_stage_yaml(const YAML::Node& root, const std::string& file_name,
                           const StageYamlOptions& options = {});
StageFile load_stage_file(const std::string& path, const StageYamlOptions& options = {});

struct Range;
// The range of one stage key of stage.yaml ("stroke_m", "slider_mass_kg", ...), from the one table
// the reader checks with: what a stage can be, for code that checks values against it (a dataset's
// strokes). std::invalid_argument for a name that is not a stage key.
const Range& stage_key_range(const std::string& key);

// config/README.md's rows of the stage keys ("| key | unit | default | range | meaning |"), from
// the same table the reader checks with.
std::string stage_reference_rows();

// Writes the two sections, full precision, so that parse_stage_yaml reads the same values back.
std::string to_yaml(const StageFile& stage_file);

}  // namespace idm::model
