// The drivers' part of the configuration: the `interferometer:` section (the position-word codec
// and the model's sensor keys), the `daq:` section that names the driver, and the checked-read
// helpers the backends share. Every error names the file, the line, the key and the range.
#pragma once

#include <yaml-cpp/yaml.h>

#include <initializer_list>
#include <string>

#include "drivers/air_index.h"
#include "drivers/interfaces.h"
#include "drivers/position_word.h"
#include "model/param_table.h"
#include "model/stage.h"

namespace idm::drivers {

struct InterferometerConfig {
  PositionWordConfig word;             // sample_interval_s is set by the backend (stream rate)
  model::InterferometerParams sensor;  // resolution_m = word.count_m(); noise_m
};

// The `interferometer:` section of `root` (all keys optional):
//   word_bits: 32 | 36, optics: single_beam_linear | plane_mirror | custom, divisor (custom),
//   lambda_vac_m, air_index or air: {temperature_c, pressure_pa, relative_humidity_pct, co2_ppm},
//   max_velocity_m_s, max_consecutive_jumps, resolution_m (must agree with
//   lambda_vac / (n_air divisor) to 1e-3), noise_m. Unknown keys are errors.
InterferometerConfig parse_interferometer_yaml(const YAML::Node& root, const std::string& file);

// config/README.md's rows for the `interferometer:` keys and its `air:` map, from the tables the
// reader checks with.
std::string interferometer_reference_rows();
std::string air_reference_rows();

// The output capability keys every driver's section takes (max_sample_rate_hz, ..., max_cycles):
// the backends lift them into their own tables (model::lifted).
const model::ParamTable<OutputCapabilities>& output_capability_params();

// The `daq:` section: `driver` (default "sim") and one section per driver (sim, modbus, usb).
// Unknown keys are errors. Returns the driver name.
std::string parse_daq_driver(const YAML::Node& root, const std::string& file);

namespace detail {

// A key that is there with a value (not missing, not null).
inline bool present(const YAML::Node& node) {
  return node.IsDefined() && !node.IsNull();
}
// root[key] when root is a map, else an undefined node.
YAML::Node child(const YAML::Node& root, const char* key);

// Throws InputError at the first key of `map` not in `allowed` ("FILE:LINE: SECTION.KEY: unknown
// key, allowed ..."), or when `map` is present but not a map.
void check_keys(const YAML::Node& map, const std::string& file, const std::string& section,
                std::initializer_list<const char*> allowed);

}  // namespace detail

}  // namespace idm::drivers
