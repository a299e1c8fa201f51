#include "drivers/backends.h"

#include "drivers/config.h"
#include "drivers/modbus/modbus_backend.h"
#include "drivers/sim/sim_backend.h"
#include "drivers/usb/usb_backend.h"
#include "model/stage.h"
#include "model/yaml_util.h"

namespace idm::drivers {

const std::vector<BackendEntry>& backend_table() {
  static const std::vector<BackendEntry> table = {
      {"sim", &sim::make_sim_device, "the simulated stage (model/ plant, synthetic or wall clock)"},
      {"modbus", &modbus::make_modbus_device,
       "a Modbus TCP waveform generator with a position counter (libmodbus)"},
      {"usb", &usb::make_usb_device,
       "the USB bridge: buffered DAC samples, position records (libusb)"},
  };
  return table;
}

std::string known_backends() {
  std::string out;
  for (const BackendEntry& e : backend_table())
    out += (out.empty() ? "" : ", ") + std::string(e.name);
  return out;
}

Device make_backend(const std::string& name, const YAML::Node& root, const std::string& file) {
  for (const BackendEntry& e : backend_table())
    if (name == e.name) return e.factory(root, file);
  throw model::InputError(file + ": daq.driver: unknown driver '" + name +
                          "', known: " + known_backends());
}

Device make_backend_from_config(const YAML::Node& root, const std::string& file) {
  const std::string name = parse_daq_driver(root, file);
  for (const BackendEntry& e : backend_table())
    if (name == e.name) return e.factory(root, file);
  const YAML::Node at = detail::child(detail::child(root, "daq"), "driver");
  throw model::InputError(model::located(
      file, at, "daq.driver", "unknown driver '" + name + "', known: " + known_backends()));
}

}  // namespace idm::drivers
