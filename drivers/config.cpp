#include "drivers/config.h"

#include <cmath>
#include <sstream>

#include "model/yaml_util.h"

namespace idm::drivers {

using model::InputError;
using model::located;
using model::read_double;
using model::read_integer;
using model::read_string;

namespace detail {

YAML::Node child(const YAML::Node& root, const char* key) {
  if (root.IsDefined() && root.IsMap()) return root[key];
  return YAML::Node(YAML::NodeType::Undefined);
}

void check_keys(const YAML::Node& map, const std::string& file, const std::string& section,
                std::initializer_list<const char*> allowed) {
  if (!present(map)) return;
  if (!map.IsMap()) throw InputError(located(file, map, section, "expected a map"));
  for (const auto& kv : map) {
    const std::string key = kv.first.as<std::string>();
    bool known = false;
    for (const char* a : allowed) known = known || key == a;
    if (known) continue;
    std::string list;
    for (const char* a : allowed) list += (list.empty() ? "" : ", ") + std::string(a);
    throw InputError(located(file, kv.first, section + "." + key, "unknown key, allowed " + list));
  }
}

bool read_output_capability(const std::string& key, const YAML::Node& v, const std::string& file,
                            const std::string& section, OutputCapabilities& caps) {
  const std::string k = section + "." + key;
  if (key == "max_sample_rate_hz") {
    caps.max_sample_rate_hz = read_double(v, file, k, 0, 1e9, true);
  } else if (key == "max_burst_samples") {
    caps.max_burst_samples = static_cast<std::size_t>(read_integer(v, file, k, 2, 1L << 28));
  } else if (key == "resolution_bits") {
    caps.resolution_bits = static_cast<unsigned>(read_integer(v, file, k, 1, 32));
  } else if (key == "min_voltage_v") {
    caps.min_voltage_v = read_double(v, file, k, -1000, 0);
  } else if (key == "max_voltage_v") {
    caps.max_voltage_v = read_double(v, file, k, 0, 1000, true);
  } else if (key == "volts_per_m") {
    caps.volts_per_m = read_double(v, file, k, 0, 1e12, true);
  } else if (key == "max_freq_hz") {
    caps.max_freq_hz = read_double(v, file, k, 0, 1e6, true);
  } else if (key == "max_cycles") {
    caps.max_cycles = static_cast<std::uint32_t>(read_integer(v, file, k, 1, 100000000));
  } else {
    return false;
  }
  return true;
}

}  // namespace detail

InterferometerConfig parse_interferometer_yaml(const YAML::Node& root, const std::string& file) {
  InterferometerConfig c;
  const YAML::Node ifm = detail::child(root, "interferometer");
  if (!detail::present(ifm)) {
    c.sensor.resolution_m = c.word.count_m();
    return c;
  }
  detail::check_keys(ifm, file, "interferometer",
                     {"word_bits", "optics", "divisor", "lambda_vac_m", "air_index", "air",
                      "max_velocity_m_s", "max_consecutive_jumps", "resolution_m", "noise_m"});
  if (const YAML::Node v = ifm["word_bits"]) {
    const long bits = read_integer(v, file, "interferometer.word_bits", 32, 36);
    if (bits != 32 && bits != 36)
      throw InputError(located(file, v, "interferometer.word_bits",
                               std::to_string(bits) + " is not allowed, allowed 32 or 36"));
    c.word.width = bits == 32 ? WordWidth::Bits32 : WordWidth::Bits36;
  }
  if (const YAML::Node v = ifm["optics"]) {
    try {
      c.word.optics = parse_optics(read_string(v, file, "interferometer.optics"), "optics");
    } catch (const InputError& e) {
      throw InputError(located(file, v, "interferometer.optics",
                               "unknown optics '" + v.Scalar() +
                                   "', allowed single_beam_linear, plane_mirror, custom"));
    }
  }
  if (const YAML::Node v = ifm["divisor"]) {
    if (c.word.optics != Optics::Custom)
      throw InputError(located(file, v, "interferometer.divisor",
                               "only with optics: custom (the optics fix the divisor)"));
    c.word.divisor = read_double(v, file, "interferometer.divisor", 0, 1e6, true);
  } else if (c.word.optics == Optics::Custom) {
    throw InputError(located(file, ifm, "interferometer.divisor", "required with optics: custom"));
  }
  if (const YAML::Node v = ifm["lambda_vac_m"])
    c.word.lambda_vac_m = read_double(v, file, "interferometer.lambda_vac_m", 100e-9, 20e-6);
  if (ifm["air_index"] && ifm["air"])
    throw InputError(located(file, ifm["air"], "interferometer.air",
                             "give either air_index or air conditions, not both"));
  if (const YAML::Node v = ifm["air_index"])
    c.word.air_index = read_double(v, file, "interferometer.air_index", 1.0, 1.01);
  if (const YAML::Node air = ifm["air"]) {
    detail::check_keys(air, file, "interferometer.air",
                       {"temperature_c", "pressure_pa", "relative_humidity_pct", "co2_ppm"});
    AirConditions a;
    if (air["temperature_c"])
      a.temperature_c = read_double(air["temperature_c"], file, "interferometer.air.temperature_c", -40, 60);
    if (air["pressure_pa"])
      a.pressure_pa = read_double(air["pressure_pa"], file, "interferometer.air.pressure_pa", 50e3, 120e3);
    if (air["relative_humidity_pct"])
      a.relative_humidity_pct = read_double(air["relative_humidity_pct"], file,
                                            "interferometer.air.relative_humidity_pct", 0, 100);
    if (air["co2_ppm"])
      a.co2_ppm = read_double(air["co2_ppm"], file, "interferometer.air.co2_ppm", 0, 2000);
    c.word.air_index = air_refractive_index(a, c.word.lambda_vac_m);
  }
  if (const YAML::Node v = ifm["max_velocity_m_s"])
    c.word.max_velocity_m_s = read_double(v, file, "interferometer.max_velocity_m_s", 0, 100, true);
  if (const YAML::Node v = ifm["max_consecutive_jumps"])
    c.word.max_consecutive_jumps = static_cast<std::uint32_t>(
        read_integer(v, file, "interferometer.max_consecutive_jumps", 1, 1000000));
  c.sensor.resolution_m = c.word.count_m();
  if (const YAML::Node v = ifm["resolution_m"]) {
    const double r = read_double(v, file, "interferometer.resolution_m", 0, 1e-6, true);
    if (std::fabs(r / c.word.count_m() - 1.0) > 1e-3) {
      std::ostringstream msg;
      msg.precision(9);
      msg << r << " disagrees with lambda_vac / (n_air divisor) = " << c.word.count_m()
          << " m (set optics, divisor or lambda_vac_m instead)";
      throw InputError(located(file, v, "interferometer.resolution_m", msg.str()));
    }
  }
  if (const YAML::Node v = ifm["noise_m"])
    c.sensor.noise_m = read_double(v, file, "interferometer.noise_m", 0, 1e-6);
  try {
    validate(c.word, "interferometer");
  } catch (const InputError& e) {
    throw InputError(located(file, ifm, "interferometer", e.what()));
  }
  return c;
}

std::string parse_daq_driver(const YAML::Node& root, const std::string& file) {
  const YAML::Node daq = detail::child(root, "daq");
  if (!detail::present(daq)) return "sim";
  detail::check_keys(daq, file, "daq", {"driver", "sim", "modbus", "usb"});
  if (const YAML::Node v = daq["driver"]) return read_string(v, file, "daq.driver");
  return "sim";
}

}  // namespace idm::drivers
