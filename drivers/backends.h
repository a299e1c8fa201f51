// The one name -> factory table of the backends (`daq.driver: sim | modbus | usb`).
#pragma once

#include <yaml-cpp/yaml.h>

#include <string>
#include <vector>

#include "drivers/interfaces.h"

namespace idm::drivers {

// Builds a device from the whole configuration document `root` (read from `file`, for messages).
// Parses only: no I/O happens before Device::configure(). Throws model::InputError for a bad
// config (file, line, key, range) and for an unknown name ("unknown driver 'x', known: sim,
// modbus, usb").
using BackendFactory = Device (*)(const YAML::Node& root, const std::string& file);

struct BackendEntry {
  const char* name;
  BackendFactory factory;
  const char* what;
};

const std::vector<BackendEntry>& backend_table();
// "sim, modbus, usb".
std::string known_backends();

Device make_backend(const std::string& name, const YAML::Node& root, const std::string& file);
// make_backend(parse_daq_driver(root, file), root, file).
Device make_backend_from_config(const YAML::Node& root, const std::string& file);

}  // namespace idm::drivers
