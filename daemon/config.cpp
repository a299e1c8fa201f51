#include "daemon/config.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <utility>
#include <vector>

#include "drivers/backends.h"
#include "drivers/config.h"
#include "model/yaml_util.h"

namespace idm::daemon {

using model::InputError;
using model::located;
using model::read_bool;
using model::read_double;
using model::read_integer;
using model::read_string;

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// One section: its keys and how each is read. Unknown keys are errors naming the allowed ones.
struct Key {
  const char* name;
  std::function<void(const YAML::Node&, const std::string& key)> read;
};

void read_section(const YAML::Node& root, const char* section, const std::string& file,
                  const std::vector<Key>& keys) {
  const YAML::Node node = drivers::detail::child(root, section);
  if (!drivers::detail::present(node)) return;
  if (!node.IsMap()) throw InputError(located(file, node, section, "expected a map"));
  for (const auto& kv : node) {
    const std::string name = kv.first.as<std::string>();
    const std::string key = std::string(section) + "." + name;
    const auto it = std::find_if(keys.begin(), keys.end(),
                                 [&](const Key& k) { return name == k.name; });
    if (it == keys.end()) {
      std::string allowed;
      for (const Key& k : keys) allowed += (allowed.empty() ? "" : ", ") + std::string(k.name);
      throw InputError(located(file, kv.first, key, "unknown key, allowed " + allowed));
    }
    if (!drivers::detail::present(kv.second))
      throw InputError(located(file, kv.first, key, "no value"));
    it->read(kv.second, key);
  }
}

int read_int(const YAML::Node& v, const std::string& file, const std::string& key, long lo,
             long hi) {
  return static_cast<int>(read_integer(v, file, key, lo, hi));
}

std::string read_choice(const YAML::Node& v, const std::string& file, const std::string& key,
                        std::initializer_list<const char*> allowed) {
  const std::string s = read_string(v, file, key);
  std::string list;
  for (const char* a : allowed) {
    if (s == a) return s;
    list += (list.empty() ? "" : ", ") + std::string(a);
  }
  throw InputError(located(file, v, key, "'" + s + "' is not allowed, allowed " + list));
}

// A validate() of another layer failed on values we read: point at the section.
template <typename Fn>
void at_section(const YAML::Node& root, const char* section, const std::string& file, Fn&& fn) {
  try {
    fn();
  } catch (const InputError& e) {
    throw InputError(located(file, drivers::detail::child(root, section), section, e.what()));
  }
}

}  // namespace

ControlConfig parse_control_config(const YAML::Node& root, const std::string& f,
                                   const model::StageFile& stage) {
  ControlConfig c;
  c.planner.resolution_m = stage.interferometer.resolution_m;
  auto& p = c.positioner;
  read_section(root, "control", f, {
      {"freq_step_hz", [&](auto& v, auto& k) { c.freq_step_hz = read_double(v, f, k, 0, 1e5, true); }},
      {"duty_step", [&](auto& v, auto& k) { c.duty_step = read_double(v, f, k, 0, 0.25, true); }},
      {"stroke_count", [&](auto& v, auto& k) { c.stroke_count = read_int(v, f, k, 1, 64); }},
      {"min_freq_hz", [&](auto& v, auto& k) { c.min_freq_hz = read_double(v, f, k, 0, 1e6, true); }},
      {"max_freq_hz", [&](auto& v, auto& k) { c.max_freq_hz = read_double(v, f, k, 0, 1e6, true); }},
      {"min_stroke_m", [&](auto& v, auto& k) { c.min_stroke_m = read_double(v, f, k, 0, 1e-3, true); }},
      {"max_stroke_m", [&](auto& v, auto& k) { c.max_stroke_m = read_double(v, f, k, 0, 1e-3); }},
      {"output_sample_rate_hz",
       [&](auto& v, auto& k) { c.output_sample_rate_hz = read_double(v, f, k, 0, 1e8, true); }},
      {"friction_uncertainty",
       [&](auto& v, auto& k) { c.friction_uncertainty = read_double(v, f, k, 0, 0.45); }},
      {"final_class_slack",
       [&](auto& v, auto& k) { c.planner.final_class_slack = read_double(v, f, k, 1, 100); }},
      {"final_approach_steps",
       [&](auto& v, auto& k) { c.planner.final_approach_steps = read_int(v, f, k, 1, 10000); }},
      {"max_bursts", [&](auto& v, auto& k) { c.planner.max_bursts = read_int(v, f, k, 1, 1000000); }},
      {"tolerance_m", [&](auto& v, auto& k) { p.tolerance_m = read_double(v, f, k, 0, 1e-3); }},
      {"max_retries", [&](auto& v, auto& k) { p.max_retries = read_int(v, f, k, 0, 1000); }},
      {"stall_bursts", [&](auto& v, auto& k) { p.stall_bursts = read_int(v, f, k, 1, 1000); }},
      {"stall_fraction", [&](auto& v, auto& k) { p.stall_fraction = read_double(v, f, k, 0, 1); }},
      {"settle_s", [&](auto& v, auto& k) { p.settle_s = read_double(v, f, k, 0, 10); }},
      {"max_chunk_s", [&](auto& v, auto& k) { p.max_chunk_s = read_double(v, f, k, 0, 60, true); }},
      {"latch_words", [&](auto& v, auto& k) { p.latch_words = read_int(v, f, k, 1, 1024); }},
      {"soft_lower_m", [&](auto& v, auto& k) { p.soft_lower_m = read_double(v, f, k, -10, 10); }},
      {"soft_upper_m", [&](auto& v, auto& k) { p.soft_upper_m = read_double(v, f, k, -10, 10); }},
      {"idle_poll_s", [&](auto& v, auto& k) { p.idle_poll_s = read_double(v, f, k, 0, 60, true); }},
      {"calibration_file", [&](auto& v, auto& k) { c.calibration_file = read_string(v, f, k); }},
      {"calibration",
       [&](auto& v, auto& k) {
         drivers::detail::check_keys(v, f, k, {"enabled", "forgetting"});
         if (v["enabled"]) c.calibration.enabled = read_bool(v["enabled"], f, k + ".enabled");
         if (v["forgetting"])
           c.calibration.forgetting = read_double(v["forgetting"], f, k + ".forgetting", 0, 1, true);
       }},
  });
  const YAML::Node node = drivers::detail::child(root, "control");
  if (c.min_freq_hz > c.max_freq_hz)
    throw InputError(located(f, node, "control.min_freq_hz",
                             "must not exceed max_freq_hz (" + model::format_number(c.max_freq_hz) + ")"));
  if (c.max_stroke_m > 0 && c.min_stroke_m > c.max_stroke_m)
    throw InputError(located(f, node, "control.min_stroke_m", "must not exceed max_stroke_m"));
  // Soft limits: default to the stage's travel, and never outside it.
  if (!node || !node["soft_lower_m"]) p.soft_lower_m = stage.has_travel() ? stage.travel_lower_m : -kInf;
  if (!node || !node["soft_upper_m"]) p.soft_upper_m = stage.has_travel() ? stage.travel_upper_m : kInf;
  if (!(p.soft_lower_m < p.soft_upper_m))
    throw InputError(located(f, node, "control.soft_lower_m",
                             model::format_number(p.soft_lower_m) + " must be below soft_upper_m (" +
                                 model::format_number(p.soft_upper_m) + ")"));
  if (stage.has_travel()) {
    const std::string travel = "the stage's travel [" + model::format_number(stage.travel_lower_m) +
                               ", " + model::format_number(stage.travel_upper_m) + "] m (stage.travel_m)";
    if (p.soft_lower_m < stage.travel_lower_m)
      throw InputError(located(f, node["soft_lower_m"], "control.soft_lower_m",
                               model::format_number(p.soft_lower_m) + " lies outside " + travel));
    if (p.soft_upper_m > stage.travel_upper_m)
      throw InputError(located(f, node["soft_upper_m"], "control.soft_upper_m",
                               model::format_number(p.soft_upper_m) + " lies outside " + travel));
  }
  at_section(root, "control", f, [&] {
    control::validate(c.planner, "control");
    control::validate(c.positioner, "control");
    control::validate(c.calibration, "control.calibration");
  });
  return c;
}

DaemonConfig parse_daemon_config(const YAML::Node& root, const std::string& f) {
  if (!root.IsDefined() || root.IsNull()) throw InputError(f + ": empty configuration");
  if (!root.IsMap()) throw InputError(located(f, root, "(top)", "expected a YAML map of sections"));
  model::require_unique_keys(root, f);
  for (const auto& kv : root) {
    const std::string name = kv.first.as<std::string>();
    static const char* const kSections[] = {"stage",   "interferometer", "daq",       "control",
                                            "server",  "realtime",       "logging",   "recording",
                                            "sim"};
    if (std::find(std::begin(kSections), std::end(kSections), name) == std::end(kSections))
      throw InputError(located(f, kv.first, name,
                               "unknown section, allowed stage, interferometer, daq, control, "
                               "server, realtime, logging, recording, sim"));
  }
  DaemonConfig c;
  c.file = f;
  c.root = root;
  c.stage = model::parse_stage_yaml(root, f, {.strict = true, .require_dataset_keys = false});
  at_section(root, "stage", f, [&] { model::validate(c.stage.stage, "stage"); });
  // The interferometer section's full form (word format, air index); the model's view of it is
  // the count and the noise.
  const drivers::InterferometerConfig ifm = drivers::parse_interferometer_yaml(root, f);
  c.stage.interferometer = ifm.sensor;
  if (const YAML::Node sim = drivers::detail::child(root, "sim"); drivers::detail::present(sim))
    c.sim = model::parse_sim_yaml(sim, f);
  c.driver = drivers::parse_daq_driver(root, f);
  // The backend's own parser checks daq.<driver> (no I/O before configure()).
  (void)drivers::make_backend_from_config(root, f);
  c.control = parse_control_config(root, f, c.stage);

  auto& s = c.server;
  read_section(root, "server", f, {
      {"tcp_address", [&](auto& v, auto& k) { s.tcp_address = read_string(v, f, k); }},
      {"tcp_port", [&](auto& v, auto& k) { s.tcp_port = read_int(v, f, k, 0, 65535); }},
      {"unix_socket", [&](auto& v, auto& k) { s.unix_socket = read_string(v, f, k); }},
      {"max_clients", [&](auto& v, auto& k) { s.max_clients = read_int(v, f, k, 1, 1024); }},
  });
  if (s.unix_socket.size() > 100)
    throw InputError(located(f, drivers::detail::child(root, "server"), "server.unix_socket",
                             "longer than 100 characters (sockaddr_un)"));

  auto& r = c.realtime;
  read_section(root, "realtime", f, {
      {"period_s", [&](auto& v, auto& k) { r.period_s = read_double(v, f, k, 1e-5, 0.1); }},
      {"sched_fifo", [&](auto& v, auto& k) { r.sched_fifo = read_bool(v, f, k); }},
      {"priority", [&](auto& v, auto& k) { r.priority = read_int(v, f, k, 1, 99); }},
      {"cpu", [&](auto& v, auto& k) { r.cpu = read_int(v, f, k, -1, 1023); }},
      {"lock_memory", [&](auto& v, auto& k) { r.lock_memory = read_bool(v, f, k); }},
      {"histogram_bin_s", [&](auto& v, auto& k) { r.histogram_bin_s = read_double(v, f, k, 1e-7, 1e-2); }},
      {"watchdog_stall_s", [&](auto& v, auto& k) { r.watchdog_stall_s = read_double(v, f, k, 1e-3, 60); }},
  });

  auto& l = c.logging;
  read_section(root, "logging", f, {
      {"level", [&](auto& v, auto& k) {
         l.level = read_choice(v, f, k, {"trace", "debug", "info", "warn", "error", "critical", "off"});
       }},
      {"format", [&](auto& v, auto& k) { l.format = read_choice(v, f, k, {"auto", "console", "journal"}); }},
  });

  auto& rec = c.recording;
  read_section(root, "recording", f, {
      {"data_dir", [&](auto& v, auto& k) { rec.data_dir = read_string(v, f, k); }},
      {"sweep_rest_s", [&](auto& v, auto& k) { rec.sweep_rest_s = read_double(v, f, k, 0, 1); }},
      {"sweep_settle_cycles", [&](auto& v, auto& k) { rec.sweep_settle_cycles = read_int(v, f, k, 0, 1000); }},
      {"sweep_span_m", [&](auto& v, auto& k) { rec.sweep_span_m = read_double(v, f, k, 0, 1, true); }},
      {"sweep_max_trials", [&](auto& v, auto& k) { rec.sweep_max_trials = read_int(v, f, k, 1, 10000000); }},
  });
  if (rec.data_dir.empty())
    throw InputError(located(f, drivers::detail::child(root, "recording"), "recording.data_dir",
                             "must not be empty"));
  // Last, so that a typo elsewhere is reported first.
  if (!c.stage.has_travel())
    throw InputError(located(f, drivers::detail::child(root, "stage"), "stage.travel_m",
                             "missing: the stage's mechanical range in metres, e.g. "
                             "`travel_m: [-5e-3, 5e-3]` under stage:; the soft limits default to it "
                             "and no move or STEP may leave it"));
  return c;
}

DaemonConfig load_daemon_config(const std::string& path) {
  return parse_daemon_config(model::load_yaml_file(path), path);
}

control::DeviceLimits device_limits(const ControlConfig& c, const model::StageParams& stage,
                                    const drivers::OutputCapabilities& caps) {
  control::DeviceLimits lim;
  const bool buffered = caps.mode == drivers::OutputMode::BufferedSamples;
  lim.output_sample_rate_hz = buffered ? std::min(c.output_sample_rate_hz, caps.max_sample_rate_hz) : 0.0;
  lim.min_freq_hz = c.min_freq_hz;
  double fmax = c.max_freq_hz;
  // A buffered output needs at least a few samples per period.
  if (buffered) fmax = std::min(fmax, lim.output_sample_rate_hz / 4.0);
  else fmax = std::min(fmax, caps.max_freq_hz);
  lim.max_freq_hz = std::max(fmax, lim.min_freq_hz);
  double smax = c.max_stroke_m > 0 ? c.max_stroke_m : stage.stroke_m;
  smax = std::min(smax, caps.max_elongation_m());
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
  m.grid.strokes_m = control::RegionGrid::stroke_steps(limits.min_stroke_m, limits.max_stroke_m,
                                                       c.stroke_count);
  return m;
}

}  // namespace idm::daemon
