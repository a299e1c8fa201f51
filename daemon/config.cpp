#include "daemon/config.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <set>
#include <utility>

#include "daemon/server.h"
#include "drivers/backends.h"
#include "drivers/modbus/modbus_backend.h"
#include "drivers/sim/sim_backend.h"
#include "drivers/usb/usb_backend.h"
#include "model/yaml_util.h"

namespace idm::daemon {

using model::boolean;
using model::choice;
using model::custom;
using model::InputError;
using model::integer;
using model::located;
using model::real;
using model::text;
using model::with_default;

namespace {

using Node = YAML::Node;

bool present(const Node& n) {
  return n.IsDefined() && !n.IsNull();
}

// map[key], or an undefined node (never yaml-cpp's invalid one, which cannot be assigned).
Node child(const Node& map, const char* key) {
  if (map.IsDefined() && map.IsMap()) {
    const Node n = map[key];
    if (n.IsDefined()) return n;
  }
  return Node(YAML::NodeType::Undefined);
}

// An axis's sections before they are parsed by their layers.
struct AxisSections {
  std::string device;
  int channel = -1;
  bool require_reference = false;
  AxisConfig::Reference reference = AxisConfig::Reference::Negative;
  double reference_position_m = std::numeric_limits<double>::quiet_NaN();
  AxisConfig::Reference reference_mark_search = AxisConfig::Reference::Negative;
  std::string reference_file;
  Node stage, interferometer, sim, control;
};

template <typename S>
model::Param<S> section(const char* name, const char* doc, Node S::*field) {
  return custom<S>(name, "map", "see its section", "", doc,
                   [field](S& s, const Node& v, const std::string& f, const std::string& k) {
                     if (!v.IsMap()) throw InputError(located(f, v, k, "expected a map"));
                     s.*field = v;
                   });
}

const model::ParamTable<AxisSections>& axis_params() {
  static const model::ParamTable<AxisSections> table({
      text<AxisSections>(
          "device", "the device (devices.NAME) it is on; the only one when there is one",
          [](auto& a) -> auto& { return a.device; }, "a name under devices:"),
      with_default(
          integer<AxisSections>(
              "channel", "count", 0, 63, "its output channel and interferometer axis on the device",
              [](auto& a) -> auto& { return a.channel; }),
          "its place among the device's axes"),
      boolean<AxisSections>(
          "require_reference", "MOVE:ABS is refused (-221) until the axis is referenced",
          [](auto& a) -> auto& { return a.require_reference; }),
      choice<AxisSections, AxisConfig::Reference>(
          "reference",
          {{"negative", AxisConfig::Reference::Negative},
           {"positive", AxisConfig::Reference::Positive},
           {"mark", AxisConfig::Reference::Mark}},
          "what REFerence without an argument finds: an end stop or the reference mark",
          [](auto& a) -> auto& { return a.reference; }),
      with_default(real<AxisSections>(
                       "reference_position_m", "m", {-10, 10},
                       "the position REFerence sets where it finds the reference",
                       [](auto& a) -> auto& { return a.reference_position_m; }),
                   "the end of stage.travel_m it lies at (the mark: 0)"),
      choice<AxisSections, AxisConfig::Reference>(
          "reference_mark_search",
          {{"negative", AxisConfig::Reference::Negative},
           {"positive", AxisConfig::Reference::Positive}},
          "which way REFerence MARK drives first (it turns at an end stop before the mark)",
          [](auto& a) -> auto& { return a.reference_mark_search; }),
      text<AxisSections>(
          "reference_file",
          "the interferometer keeps its count while idmd is down: the reference is saved here and "
          "restored at start when the device's count epoch is unchanged (\"\": never restored)",
          [](auto& a) -> auto& { return a.reference_file; }, "a path"),
      section<AxisSections>("stage", "the stage (below), travel_m required", &AxisSections::stage),
      section<AxisSections>("interferometer", "the position words (below)",
                            &AxisSections::interferometer),
      section<AxisSections>("sim", "this axis's simulated stage (below)", &AxisSections::sim),
      section<AxisSections>("control", "the axis's control settings (below)",
                            &AxisSections::control),
  });
  return table;
}

// The single-axis form has the axis's keys at the top (but device and channel) and `daq`.
bool single_axis_key(const std::string& name) {
  if (name == "daq") return true;
  if (name == "device" || name == "channel") return false;
  for (const model::Param<AxisSections>& p : axis_params().params())
    if (p.name == name) return true;
  return false;
}

// An axis's control: read through its table, the soft limits defaulted to the stage's travel, then
// every relation between keys checked (control_params(): against the other keys, the stage, one
// count and the output `caps` the device's section describes).
ControlConfig parse_control(const Node& node, const std::string& f, const std::string& key,
                            const model::StageFile& stage,
                            const drivers::OutputCapabilities& caps) {
  ControlConfig c;
  c.planner.resolution_m = stage.interferometer.resolution_m;
  control_params().read(node, f, key, c);
  auto& p = c.positioner;
  // Without a travel (an error parse_axis reports after this section's) the range's ends.
  if (!present(child(node, "soft_lower_m")))
    p.soft_lower_m = stage.has_travel() ? stage.travel_lower_m : -10;
  if (!present(child(node, "soft_upper_m")))
    p.soft_upper_m = stage.has_travel() ? stage.travel_upper_m : 10;
  c.axis.stage_stroke_m = stage.stage.stroke_m;
  if (stage.has_travel()) {
    p.travel_lower_m = stage.travel_lower_m;  // where an end of travel may be met
    p.travel_upper_m = stage.travel_upper_m;
    c.axis.travel_lower_m = stage.travel_lower_m;
    c.axis.travel_upper_m = stage.travel_upper_m;
  }
  c.axis.output = caps;
  control_params().check_relations(c, node, f, key);
  try {
    control::validate(c.planner, key);
    control::validate(c.positioner, key);
    control::validate(c.calibration, key + ".calibration");
  } catch (const InputError& e) {
    throw InputError(located(f, node, key, e.what()));
  }
  return c;
}

// devices.NAME (or daq:) -> DeviceConfig; the driver's section is checked with the axes.
DeviceConfig parse_device(const Node& node, const std::string& f, const std::string& key,
                          const std::string& name) {
  DeviceConfig d;
  d.name = name;
  device_params().read(node, f, key, d);
  device_params().check_relations(d, node, f, key);
  bool known = false;
  for (const drivers::BackendEntry& e : drivers::backend_table())
    known = known || d.driver == e.name;
  if (!known)
    throw InputError(
        located(f, child(node, "driver"), key + ".driver",
                "unknown driver '" + d.driver + "', known: " + drivers::known_backends()));
  for (const drivers::BackendEntry& e : drivers::backend_table()) {
    const Node sub = child(node, e.name);
    if (present(sub) && d.driver != e.name)
      throw InputError(located(
          f, sub, key + "." + e.name,
          std::string("a section for driver ") + e.name + ", but the driver is " + d.driver));
  }
  d.node = child(node, d.driver.c_str());
  if (d.crosstalk_fraction != 0 && d.driver != "sim")
    throw InputError(located(f, child(node, "crosstalk_fraction"), key + ".crosstalk_fraction",
                             "only a simulated device has crosstalk"));
  try {
    drivers::validate(d.link, key);
  } catch (const InputError& e) {
    throw InputError(located(f, node, key, e.what()));
  }
  return d;
}

// The document a backend's factory reads for one axis: its stage, interferometer and sim
// sections, and daq: {driver, <driver>: the device's section}.
Node axis_document(const AxisSections& a, const DeviceConfig& d) {
  Node doc(YAML::NodeType::Map);
  if (present(a.stage)) doc["stage"] = a.stage;
  if (present(a.interferometer)) doc["interferometer"] = a.interferometer;
  if (present(a.sim)) doc["sim"] = a.sim;
  Node daq(YAML::NodeType::Map);
  daq["driver"] = d.driver;
  if (present(d.node)) daq[d.driver] = d.node;
  doc["daq"] = daq;
  return doc;
}

// `prefix`: "" in the single-axis form ("stage.travel_m"), "axes.NAME." with axes.
AxisConfig parse_axis(const AxisSections& a, const std::string& name, std::size_t device,
                      const DaemonConfig& c, const Node& name_node, const std::string& prefix) {
  const std::string& f = c.file;
  AxisConfig axis;
  axis.name = name;
  axis.device = device;
  axis.require_reference = a.require_reference;
  axis.reference = a.reference;
  axis.reference_position_m = a.reference_position_m;
  axis.reference_mark_search = a.reference_mark_search;
  axis.reference_file = a.reference_file;
  axis.document = axis_document(a, c.devices[device]);
  axis.stage =
      model::parse_stage_yaml(axis.document, f, {.strict = true, .require_dataset_keys = false});
  try {
    model::validate(axis.stage.stage, prefix + "stage");
  } catch (const InputError& e) {
    throw InputError(located(f, a.stage, prefix + "stage", e.what()));
  }
  const drivers::InterferometerConfig ifm = drivers::parse_interferometer_yaml(axis.document, f);
  axis.stage.interferometer = ifm.sensor;
  if (present(a.sim)) axis.sim = model::parse_sim_yaml(a.sim, f);
  // The simulated stage's hard stops are the ends of its travel unless the file says otherwise.
  if (std::isnan(axis.sim.end_stop_low_m)) {
    axis.sim.end_stop_low_m = axis.stage.travel_lower_m;
    axis.sim.end_stop_high_m = axis.stage.travel_upper_m;
  }
  // The backend's own parser checks the device's section for this axis (no I/O); its output's
  // capabilities bound the map's strokes and frequencies.
  const drivers::Device backend = drivers::make_backend(c.devices[device].driver, axis.document, f);
  axis.control =
      parse_control(a.control, f, prefix + "control", axis.stage, backend.output->capabilities());
  // Last, so that a typo elsewhere is reported first.
  if (!axis.stage.has_travel())
    throw InputError(
        located(f, present(a.stage) ? a.stage : name_node, prefix + "stage.travel_m",
                "missing: the stage's mechanical range in metres, e.g. "
                "`travel_m: [-5e-3, 5e-3]` under stage:; the soft limits default to it "
                "and no move or STEP may leave it"));
  return axis;
}

void parse_globals(const Node& root, DaemonConfig& c) {
  const std::string& f = c.file;
  server_params().read(child(root, "server"), f, "server", c.server);
  if (c.server.unix_socket.size() > 100)
    throw InputError(located(f, child(root, "server"), "server.unix_socket",
                             "longer than 100 characters (sockaddr_un)"));
  if (!c.server.tcp_address.empty() && !c.server.allow_remote &&
      !is_loopback_address(c.server.tcp_address)) {
    const Node server = child(root, "server");
    throw InputError(located(
        f, present(child(server, "tcp_address")) ? child(server, "tcp_address") : server,
        "server.tcp_address",
        "'" + c.server.tcp_address +
            "' is not a loopback address (127.0.0.1, ::1, localhost): any machine that reaches "
            "it could move the stage. Set server.allow_remote: true (and server.auth_token_file) "
            "to mean it"));
  }
  realtime_params().read(child(root, "realtime"), f, "realtime", c.realtime);
  realtime_params().check_relations(c.realtime, child(root, "realtime"), f, "realtime");
  logging_params().read(child(root, "logging"), f, "logging", c.logging);
  recording_params().read(child(root, "recording"), f, "recording", c.recording);
  if (c.recording.data_dir.empty())
    throw InputError(
        located(f, child(root, "recording"), "recording.data_dir", "must not be empty"));
}

// Every file an axis writes is its own: two axes that shared a calibration_file (or a
// reference_file, or one axis's calibration another's reference) would overwrite each other's,
// and all but one would lose it. Paths are compared made absolute and normal (no I/O).
void require_own_files(const DaemonConfig& c) {
  struct Owner {
    std::string key;
    std::filesystem::path path;
  };
  std::vector<Owner> seen;
  const auto claim = [&](const std::string& key, const std::string& file) {
    if (file.empty()) return;
    const std::filesystem::path p = std::filesystem::absolute(file).lexically_normal();
    for (const Owner& o : seen)
      if (o.path == p)
        throw InputError(c.file + ": " + key + ": " + file + " is also " + o.key +
                         ": each axis needs files of its own (the daemon writes them; a shared "
                         "one would be overwritten and all but one axis would lose theirs)");
    seen.push_back({key, p});
  };
  claim("the configuration file", c.file);
  for (const AxisConfig& a : c.axes) {
    const std::string prefix = c.axes.size() > 1 ? "axes." + a.name + "." : "";
    claim(prefix + "control.calibration_file", a.control.calibration_file);
    claim(prefix + "reference_file", a.reference_file);
  }
}

// The single-axis form: one device `daq`, one axis `x`.
void parse_single_axis(const Node& root, DaemonConfig& c) {
  c.devices.push_back(parse_device(child(root, "daq"), c.file, "daq", "daq"));
  AxisSections a;
  a.stage = child(root, "stage");
  a.interferometer = child(root, "interferometer");
  a.sim = child(root, "sim");
  a.control = child(root, "control");
  a.channel = 0;
  // The axis's own keys, at the top in this form.
  for (const model::Param<AxisSections>& p : axis_params().params())
    if (p.unit != "map" && single_axis_key(p.name))
      if (const Node v = child(root, p.name.c_str()); present(v)) p.read(a, v, c.file, p.name);
  c.axes.push_back(parse_axis(a, "x", 0, c, root, ""));
  c.axes.back().channel = 0;
}

void parse_axes(const Node& root, DaemonConfig& c) {
  const std::string& f = c.file;
  const Node devices = child(root, "devices");
  if (!present(devices) || !devices.IsMap() || devices.size() == 0)
    throw InputError(located(f, present(devices) ? devices : root, "devices",
                             "axes: needs devices: with at least one device, e.g.\n"
                             "  devices:\n    card:\n      driver: sim\n"));
  for (const auto& kv : devices) {
    const std::string name = kv.first.as<std::string>();
    c.devices.push_back(parse_device(kv.second, f, "devices." + name, name));
  }
  const Node axes = child(root, "axes");
  if (!axes.IsMap() || axes.size() == 0)
    throw InputError(located(f, axes, "axes", "expected a map of axes, e.g. axes: {x: {...}}"));
  std::vector<int> next_channel(c.devices.size(), 0);
  std::set<std::pair<std::size_t, int>> used;
  for (const auto& kv : axes) {
    const std::string name = kv.first.as<std::string>();
    const std::string key = "axes." + name;
    if (name.empty() || name.find_first_of(" \t,;:") != std::string::npos)
      throw InputError(
          located(f, kv.first, key, "an axis name is a word without blanks, ',', ';' or ':'"));
    AxisSections a;
    axis_params().read(kv.second, f, key, a);
    std::size_t device = 0;
    if (a.device.empty()) {
      if (c.devices.size() > 1)
        throw InputError(
            located(f, kv.second, key + ".device", "missing: there are several devices"));
    } else {
      auto it = std::find_if(c.devices.begin(), c.devices.end(),
                             [&](const DeviceConfig& d) { return d.name == a.device; });
      if (it == c.devices.end())
        throw InputError(located(f, child(kv.second, "device"), key + ".device",
                                 "no device '" + a.device + "' under devices:"));
      device = static_cast<std::size_t>(it - c.devices.begin());
    }
    const int channel = a.channel >= 0 ? a.channel : next_channel[device];
    next_channel[device] = std::max(next_channel[device], channel + 1);
    if (!used.insert({device, channel}).second)
      throw InputError(located(f, kv.first, key + ".channel",
                               "channel " + std::to_string(channel) + " of device " +
                                   c.devices[device].name + " is taken by another axis"));
    c.axes.push_back(parse_axis(a, name, device, c, kv.first, key + "."));
    c.axes.back().channel = channel;
  }
}

}  // namespace

// ---- parsing ----

int DaemonConfig::axis_index(const std::string& name) const {
  for (std::size_t i = 0; i < axes.size(); ++i)
    if (axes[i].name == name) return static_cast<int>(i);
  return -1;
}

DaemonConfig parse_daemon_config(const YAML::Node& root, const std::string& f) {
  if (!root.IsDefined() || root.IsNull()) throw InputError(f + ": empty configuration");
  if (!root.IsMap()) throw InputError(located(f, root, "(top)", "expected a YAML map of sections"));
  model::require_unique_keys(root, f);
  const bool multi = present(child(root, "axes")) || present(child(root, "devices"));
  static const char* const kCommon[] = {"server", "realtime", "logging", "recording"};
  for (const auto& kv : root) {
    const std::string name = kv.first.as<std::string>();
    const bool common =
        std::find(std::begin(kCommon), std::end(kCommon), name) != std::end(kCommon);
    const bool single = single_axis_key(name);
    const bool axes = name == "axes" || name == "devices";
    if (common || (multi ? axes : single)) continue;
    if (multi && single)
      throw InputError(located(f, kv.first, name,
                               "with axes:, each axis has its own " + name + ": (axes.NAME." +
                                   name + "); devices are declared under devices:"));
    std::vector<std::string> allowed = {"devices",  "axes",    "server",
                                        "realtime", "logging", "recording"};
    if (!multi) {
      allowed.erase(allowed.begin(), allowed.begin() + 2);
      for (const model::Param<AxisSections>& p : axis_params().params())
        if (single_axis_key(p.name)) allowed.push_back(p.name);
      allowed.emplace_back("daq");
    }
    throw InputError(located(
        f, kv.first, name,
        model::unknown_name(name, allowed, "section") + (multi ? "" : " (or devices: and axes:)")));
  }
  DaemonConfig c;
  c.file = f;
  c.root = root;
  parse_globals(root, c);
  if (multi)
    parse_axes(root, c);
  else
    parse_single_axis(root, c);
  require_own_files(c);
  return c;
}

std::vector<std::string> config_warnings(const DaemonConfig& c) {
  std::vector<std::string> out;
  const ListenConfig& s = c.server;
  if (s.tcp_address.empty()) return out;
  const std::string where = "server.tcp_address " + s.tcp_address;
  if (!is_loopback_address(s.tcp_address)) {
    if (s.auth_token_file.empty())
      out.push_back(where +
                    " (server.allow_remote): any machine that reaches it can move the stage; "
                    "server.auth_token_file is not set");
    else
      out.push_back(where +
                    " (server.allow_remote): other machines can connect; motion and settings "
                    "need the token of " +
                    s.auth_token_file + ", queries and STOP do not");
  }
  return out;
}

DaemonConfig load_daemon_config(const std::string& path) {
  return parse_daemon_config(model::load_yaml_file(path), path);
}

std::vector<ControlConfig> reload_control_configs(const YAML::Node& root, const std::string& f,
                                                  const DaemonConfig& running) {
  const DaemonConfig fresh = parse_daemon_config(root, f);
  if (fresh.axes.size() != running.axes.size())
    throw InputError(f + ": the axes changed (" + std::to_string(fresh.axes.size()) +
                     " instead of " + std::to_string(running.axes.size()) +
                     "): restart idmd to apply that");
  std::vector<ControlConfig> out;
  for (std::size_t i = 0; i < fresh.axes.size(); ++i) {
    if (fresh.axes[i].name != running.axes[i].name)
      throw InputError(f + ": axis " + std::to_string(i + 1) + " is now '" + fresh.axes[i].name +
                       "', was '" + running.axes[i].name + "': restart idmd to apply that");
    out.push_back(fresh.axes[i].control);
  }
  return out;
}

std::string config_reference() {
  const auto section = [](const std::string& title, const std::string& rows) {
    return "### " + title + "\n\n" + model::markdown_header() + rows + "\n";
  };
  return section("devices.NAME (single-axis form: daq)", device_params().markdown()) +
         section("axes.NAME", axis_params().markdown()) +
         section("control (axes.NAME.control)", control_params().markdown()) +
         section("control.calibration", control::calibration_params().markdown("calibration.")) +
         section("server", server_params().markdown()) +
         section("realtime", realtime_params().markdown()) +
         section("logging", logging_params().markdown()) +
         section("recording", recording_params().markdown()) +
         section("stage (axes.NAME.stage; model/stage.h, the paper's Table 1)",
                 model::stage_reference_rows()) +
         section("interferometer (axes.NAME.interferometer; drivers/config.h)",
                 drivers::interferometer_reference_rows()) +
         section("interferometer.air", drivers::air_reference_rows()) +
         section(
             "sim (axes.NAME.sim; model/simulation.h): the simulated stage, whatever the driver",
             model::sim_params().markdown()) +
         section("devices.NAME.sim (drivers/sim/)", drivers::sim::sim_device_params().markdown()) +
         section("devices.NAME.sim.faults", drivers::sim::sim_fault_params().markdown("faults.")) +
         section("devices.NAME.modbus (drivers/modbus/)",
                 drivers::modbus::modbus_params().markdown()) +
         section("devices.NAME.usb (drivers/usb/)", drivers::usb::usb_device_params().markdown());
}

// ---- the map's limits ----

double largest_stroke_m(const ControlConfig& c, double stage_stroke_m,
                        const drivers::OutputCapabilities& caps) {
  return std::min(c.max_stroke_m > 0 ? c.max_stroke_m : stage_stroke_m, caps.max_elongation_m());
}

double highest_freq_hz(const ControlConfig& c, const drivers::OutputCapabilities& caps) {
  // A buffered output needs at least a few samples per period.
  if (caps.mode == drivers::OutputMode::BufferedSamples)
    return std::min(c.max_freq_hz, std::min(c.output_sample_rate_hz, caps.max_sample_rate_hz) / 4);
  return std::min(c.max_freq_hz, caps.max_freq_hz);
}

control::DeviceLimits device_limits(const ControlConfig& c, const model::StageParams& stage,
                                    const drivers::OutputCapabilities& caps) {
  control::DeviceLimits lim;
  const bool buffered = caps.mode == drivers::OutputMode::BufferedSamples;
  lim.output_sample_rate_hz =
      buffered ? std::min(c.output_sample_rate_hz, caps.max_sample_rate_hz) : 0.0;
  lim.min_freq_hz = c.min_freq_hz;
  // The config's relations keep min_freq_hz and min_stroke_m within these for the output the
  // device's section describes; a device that narrows its clock when opened may still shrink them.
  lim.max_freq_hz = std::max(highest_freq_hz(c, caps), lim.min_freq_hz);
  const double smax = largest_stroke_m(c, stage.stroke_m, caps);
  lim.max_stroke_m = smax;
  lim.min_stroke_m = std::min(c.min_stroke_m, smax);
  lim.max_burst_cycles = buffered ? 1000000 : caps.max_cycles;
  lim.max_burst_samples = buffered ? caps.max_burst_samples : 0;
  return lim;
}

control::RegionMapConfig region_map_config(const ControlConfig& c, const model::StageParams& stage,
                                           const control::DeviceLimits& limits) {
  control::RegionMapConfig m;
  m.stage = stage;
  m.limits = limits;
  m.friction_uncertainty = c.friction_uncertainty;
  m.grid.freqs_hz = control::RegionGrid::frequency_steps(
      std::max(limits.min_freq_hz, c.freq_step_hz), limits.max_freq_hz, c.freq_step_hz);
  if (m.grid.freqs_hz.empty()) m.grid.freqs_hz.push_back(limits.max_freq_hz);
  m.grid.duty_step = c.duty_step;
  m.grid.strokes_m =
      control::RegionGrid::stroke_steps(limits.min_stroke_m, limits.max_stroke_m, c.stroke_count);
  return m;
}

}  // namespace idm::daemon
