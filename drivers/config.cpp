#include "drivers/config.h"

#include <cmath>
#include <sstream>

#include "model/param_table.h"
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
    const std::vector<std::string> names(allowed.begin(), allowed.end());
    throw InputError(located(file, kv.first, section + "." + key, model::unknown_name(key, names)));
  }
}

}  // namespace detail

using model::ParamTable;

const ParamTable<OutputCapabilities>& output_capability_params() {
  using C = OutputCapabilities;
  static const ParamTable<C> table({
      model::real<C>(
          "max_sample_rate_hz", "Hz", {0, 1e9, true}, "buffered output: the highest DAC clock",
          [](auto& c) -> auto& { return c.max_sample_rate_hz; }),
      model::integer<C>(
          "max_burst_samples", "count", 2, 1L << 28, "buffered output: the largest burst",
          [](auto& c) -> auto& { return c.max_burst_samples; }),
      model::integer<C>(
          "resolution_bits", "bits", 1, 32, "the DAC's resolution",
          [](auto& c) -> auto& { return c.resolution_bits; }),
      model::real<C>(
          "min_voltage_v", "V", {-1000, 0}, "the output range's low end",
          [](auto& c) -> auto& { return c.min_voltage_v; }),
      model::real<C>(
          "max_voltage_v", "V", {0, 1000, true}, "the output range's high end",
          [](auto& c) -> auto& { return c.max_voltage_v; }),
      model::real<C>(
          "volts_per_m", "V/m", {0, 1e12, true}, "output volts per metre of actuator elongation",
          [](auto& c) -> auto& { return c.volts_per_m; }),
      model::real<C>(
          "max_freq_hz", "Hz", {0, 1e6, true}, "burst parameters: the highest frequency",
          [](auto& c) -> auto& { return c.max_freq_hz; }),
      model::integer<C>(
          "max_cycles", "count", 1, 100000000, "burst parameters: most cycles in one burst",
          [](auto& c) -> auto& { return c.max_cycles; }),
  });
  return table;
}

namespace {

// The `interferometer:` section as written, before the keys that depend on each other are
// combined (divisor and optics, air and air_index, resolution_m and the wavelength).
struct InterferometerYaml {
  InterferometerConfig config;
  bool has_air = false;
  AirConditions air;
  double resolution_m = 0.0;  // 0: not given
};

const ParamTable<AirConditions>& air_params() {
  using A = AirConditions;
  static const ParamTable<A> table({
      model::real<A>(
          "temperature_c", "°C", {-40, 60}, "air temperature along the beam",
          [](auto& a) -> auto& { return a.temperature_c; }),
      model::real<A>(
          "pressure_pa", "Pa", {50e3, 120e3}, "air pressure",
          [](auto& a) -> auto& { return a.pressure_pa; }),
      model::real<A>(
          "relative_humidity_pct", "%", {0, 100}, "relative humidity",
          [](auto& a) -> auto& { return a.relative_humidity_pct; }),
      model::real<A>(
          "co2_ppm", "ppm", {0, 2000}, "CO2 content", [](auto& a) -> auto& { return a.co2_ppm; }),
  });
  return table;
}

const ParamTable<InterferometerYaml>& interferometer_params() {
  using Y = InterferometerYaml;
  static const ParamTable<Y> table({
      model::custom<Y>(
          "word_bits", "bits", "32, 36", "32",
          "the position word's width (HP10885A: 32; 36 with the extension)",
          [](Y& y, const YAML::Node& v, const std::string& file, const std::string& key) {
            const long bits = read_integer(v, file, key, 32, 36);
            if (bits != 32 && bits != 36)
              throw InputError(
                  located(file, v, key, std::to_string(bits) + " is not allowed, allowed 32, 36"));
            y.config.word.width = bits == 32 ? WordWidth::Bits32 : WordWidth::Bits36;
          }),
      model::choice<Y, Optics>(
          "optics",
          {{optics_name(Optics::SingleBeamLinear), Optics::SingleBeamLinear},
           {optics_name(Optics::PlaneMirror), Optics::PlaneMirror},
           {optics_name(Optics::Custom), Optics::Custom}},
          "the optics, which fix the counts per wavelength (64, 128; custom: divisor)",
          [](auto& y) -> auto& { return y.config.word.optics; }),
      model::with_default(model::real<Y>(
                              "divisor", "1", {0, 1e6, true},
                              "counts per wavelength; only with optics: custom, and required there",
                              [](auto& y) -> auto& { return y.config.word.divisor; }),
                          "(the optics)"),
      model::real<Y>(
          "lambda_vac_m", "m", {100e-9, 20e-6}, "the laser's vacuum wavelength",
          [](auto& y) -> auto& { return y.config.word.lambda_vac_m; }),
      model::real<Y>(
          "air_index", "1", {1.0, 1.01}, "the air's refractive index (or air:, not both)",
          [](auto& y) -> auto& { return y.config.word.air_index; }),
      model::custom<Y>(
          "air", "map", "keys: temperature_c, pressure_pa, relative_humidity_pct, co2_ppm",
          "(below)",
          "air conditions: the index from the modified Edlen equation (interferometer.air below)",
          [](Y& y, const YAML::Node& v, const std::string& file, const std::string& key) {
            air_params().read(v, file, key, y.air);
            y.has_air = true;
          }),
      model::real<Y>(
          "max_velocity_m_s", "m/s", {0, 100, true},
          "the decoder's plausibility bound; the positioner refuses one slower than the map's "
          "jumps (the shipped files give 1)",
          [](auto& y) -> auto& { return y.config.word.max_velocity_m_s; }),
      model::integer<Y>(
          "max_consecutive_jumps", "count", 1, 1000000,
          "implausible words in a row before continuity is declared lost",
          [](auto& y) -> auto& { return y.config.word.max_consecutive_jumps; }),
      model::with_default(model::real<Y>(
                              "resolution_m", "m", {0, 1e-6, true},
                              "one count; must agree with lambda_vac / (n_air divisor) to 1e-3",
                              [](auto& y) -> auto& { return y.resolution_m; }),
                          "lambda_vac / (n_air divisor)"),
      model::real<Y>(
          "noise_m", "m", {0, 1e-6}, "simulated stage: rms position noise before quantization",
          [](auto& y) -> auto& { return y.config.sensor.noise_m; }),
  });
  return table;
}

}  // namespace

InterferometerConfig parse_interferometer_yaml(const YAML::Node& root, const std::string& file) {
  InterferometerYaml y;
  const YAML::Node ifm = detail::child(root, "interferometer");
  interferometer_params().read(detail::present(ifm) ? ifm : YAML::Node(), file, "interferometer",
                               y);
  InterferometerConfig& c = y.config;
  if (detail::present(ifm)) {
    if (const YAML::Node v = ifm["divisor"]; v && c.word.optics != Optics::Custom)
      throw InputError(located(file, v, "interferometer.divisor",
                               "only with optics: custom (the optics fix the divisor)"));
    if (!ifm["divisor"] && c.word.optics == Optics::Custom)
      throw InputError(
          located(file, ifm, "interferometer.divisor", "required with optics: custom"));
    if (ifm["air_index"] && ifm["air"])
      throw InputError(located(file, ifm["air"], "interferometer.air",
                               "give either air_index or air conditions, not both"));
  }
  if (y.has_air) {
    try {
      c.word.air_index = air_refractive_index(y.air, c.word.lambda_vac_m);
    } catch (const InputError& e) {  // the equation's own range (of the wavelength)
      throw InputError(located(file, ifm["air"], "interferometer", e.what()));
    }
  }
  c.sensor.resolution_m = c.word.count_m();
  if (y.resolution_m > 0 && std::fabs(y.resolution_m / c.word.count_m() - 1.0) > 1e-3) {
    std::ostringstream msg;
    msg.precision(9);
    msg << y.resolution_m << " disagrees with lambda_vac / (n_air divisor) = " << c.word.count_m()
        << " m (set optics, divisor or lambda_vac_m instead)";
    throw InputError(located(file, ifm["resolution_m"], "interferometer.resolution_m", msg.str()));
  }
  try {
    validate(c.word, "interferometer");
  } catch (const InputError& e) {
    throw InputError(located(file, ifm, "interferometer", e.what()));
  }
  return c;
}

std::string interferometer_reference_rows() {
  return interferometer_params().markdown();
}
std::string air_reference_rows() {
  return air_params().markdown("air.");
}

std::string parse_daq_driver(const YAML::Node& root, const std::string& file) {
  const YAML::Node daq = detail::child(root, "daq");
  if (!detail::present(daq)) return "sim";
  detail::check_keys(daq, file, "daq", {"driver", "sim", "modbus", "usb"});
  if (const YAML::Node v = daq["driver"]) return read_string(v, file, "daq.driver");
  return "sim";
}

}  // namespace idm::drivers
