// idmd's configuration file. Devices are declared once and the axes that use them name them:
//
//   devices:
//     card:                      # any name
//       driver: sim              # sim | modbus | usb
//       poll_interval_s: 1e-3    # the device link's keys (table below)
//       sim: {...}               # the driver's own section (drivers/README.md)
//   axes:
//     x:                         # 1..N axes, in this order (AXIS1 is the first)
//       device: card             # (the only device, when there is one)
//       channel: 0               # output channel and interferometer axis on the device
//       stage: {...}             # with travel_m: [lower, upper], required
//       interferometer: {...}
//       sim: {...}               # this axis's simulated stage (sim devices)
//       control: {...}
//   server: / realtime: / logging: / recording:
//
// The single-axis form of earlier versions (stage:, interferometer:, daq:, control:, sim: at the
// top) still works: it is one device `daq` and one axis `x`.
//
// Every section that is a struct of this file is read through its parameter table
// (model/param_table.h): the check, the message and config/README.md's rows come from it. The
// sections other layers own are read by their parsers (model::parse_stage_yaml,
// drivers::parse_interferometer_yaml, model::parse_sim_yaml, the backend's own). Unknown keys,
// wrong types and out-of-range values throw model::InputError "FILE:LINE: key: what (range)".
// Parsing does no I/O.
#pragma once

#include <yaml-cpp/yaml.h>

#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "control/calibration.h"
#include "control/planner.h"
#include "control/positioner.h"
#include "control/region_map.h"
#include "drivers/config.h"
#include "drivers/interfaces.h"
#include "drivers/link.h"
#include "model/param_table.h"
#include "model/simulation.h"
#include "model/stage.h"

namespace idm::daemon {

// An axis's `control:`: the region map's grid and friction uncertainty, the planner, the
// positioner (the motor record's RDBD/RTRY, soft limits) and the calibration.
struct ControlConfig {
  // Region map grid: frequencies every freq_step_hz over [min_freq_hz, max_freq_hz] (narrowed to
  // what the device plays), duties every duty_step, stroke_count strokes over
  // [min_stroke_m, max_stroke_m] (max 0: the stage's nominal stroke, capped by the output range).
  double freq_step_hz = 10.0;
  double duty_step = 0.005;
  int stroke_count = 6;
  double min_freq_hz = 10.0;
  double max_freq_hz = 2000.0;
  double min_stroke_m = 0.1e-6;
  double max_stroke_m = 0.0;
  double output_sample_rate_hz = 1e5;  // buffered outputs: the DAC clock (capped by the device)
  double friction_uncertainty = 0.15;
  control::PlannerConfig planner;  // resolution_m comes from the interferometer
  control::PositionerConfig positioner;
  control::CalibrationConfig calibration;
  std::string calibration_file;  // "" = no saved calibration
  // What the axis's other sections fix, put here by the parser before the relations between keys
  // are checked (control_params()): the stage's nominal stroke and travel, and the output as the
  // device's section describes it (its voltage range and volts per metre; a device may narrow its
  // clock further when opened). One count is planner.resolution_m.
  struct AxisFacts {
    double stage_stroke_m = model::StageParams{}.stroke_m;
    double travel_lower_m = -std::numeric_limits<double>::infinity();
    double travel_upper_m = std::numeric_limits<double>::infinity();
    drivers::OutputCapabilities output;
  } axis;
};
// The keys of control: and their relations: min_freq_hz <= the highest frequency, min_stroke_m <=
// the largest stroke, the soft limits within the travel and lower < upper, tolerance_m (0 or) at
// least one count, hold_window_m (0 or) at least the move window, eot_step_m (0 or) above one count
// over eot_cycles cycles, min_step_counts < final_step_counts.
const model::ParamTable<ControlConfig>& control_params();

// `server:`: where the command protocol listens.
struct ListenConfig {
  std::string tcp_address = "127.0.0.1";            // "" = no TCP listener
  int tcp_port = 5025;                              // 0 = any free port (printed at start)
  std::string unix_socket = "/run/idmd/idmd.sock";  // "" = no Unix socket
  int max_clients = 16;
  int overflow_slots = 4;
  double ready_timeout_s = 10.0;  // every axis must read a valid position within this at start
  // A tcp_address other than loopback is refused unless this is true (then a warning).
  bool allow_remote = false;
  // A file holding the token TCP clients send with *AUTH before commands that move or change a
  // setting ("": none needed). Read at start; it must not be readable by others.
  std::string auth_token_file;
};
const model::ParamTable<ListenConfig>& server_params();

// `realtime:`: the loop's period and the real-time setup it attempts.
struct RealtimeConfig {
  double period_s = 1e-4;  // 10 kHz
  // While every axis is at rest (nothing commanded, played, settling or recorded) the loop ticks
  // this often instead: readings at rest come every daq.poll_interval_s, so nothing waits on a
  // faster tick but a command, which it picks up this much later at most. 0: always period_s.
  double rest_period_s = 1e-3;
  bool sched_fifo = true;         // SCHED_FIFO at `priority` when permitted (CAP_SYS_NICE)
  int priority = 80;              // 1..99
  int cpu = -1;                   // pin the loop to this CPU; -1 = no affinity
  bool lock_memory = true;        // mlockall when permitted (RLIMIT_MEMLOCK / CAP_IPC_LOCK)
  double histogram_bin_s = 5e-6;  // wake-up latency histogram bin width
  double watchdog_stall_s = 0.5;  // no tick for this long: the loop is considered stalled
};
const model::ParamTable<RealtimeConfig>& realtime_params();

// `logging:`
struct LoggingConfig {
  std::string level = "info";   // trace, debug, info, warn, error, critical, off
  std::string format = "auto";  // auto (journal under systemd), console, journal
};
const model::ParamTable<LoggingConfig>& logging_params();

// `recording:`
struct RecordingConfig {
  std::string data_dir = "/var/lib/idmd/data";  // SWEEP directories are relative to this
  double sweep_rest_s = 5e-4;                   // command at rest before each trial's first cycle
  int sweep_settle_cycles = 2;                  // periods of rest recorded after the last cycle
  double sweep_span_m = 1e-3;  // a trial that would start farther than this from the sweep's
                               // start returns there first (closed-loop move)
  int sweep_max_trials = 100000;
};
const model::ParamTable<RecordingConfig>& recording_params();

// `devices.NAME:` (or the single-axis form's `daq:`).
struct DeviceConfig {
  std::string name;
  std::string driver = "sim";
  drivers::LinkConfig link;
  double crosstalk_fraction = 0.0;  // sim: a step of one axis displaces the others by this share
  YAML::Node node;                  // the driver's own section (devices.NAME.<driver>)
};
const model::ParamTable<DeviceConfig>& device_params();

// `axes.NAME:`.
struct AxisConfig {
  std::string name;
  std::size_t device = 0;  // into DaemonConfig::devices
  int channel = 0;         // on the device
  model::StageFile stage;  // stage: and the interferometer's model view; travel
  model::SimConfig sim;    // sim: (the simulated stage of this axis)
  ControlConfig control;
  bool require_reference = false;
  // REFerence without an argument: which end stop (or the mark); and the position the reference
  // sets there (NaN: the end of the travel it lies at, stage.travel_m).
  enum class Reference : std::uint8_t { Negative, Positive, Mark };
  Reference reference = Reference::Negative;
  double reference_position_m = std::numeric_limits<double>::quiet_NaN();
  // REFerence MARK drives this way first (Negative or Positive; it turns at an end stop).
  Reference reference_mark_search = Reference::Negative;
  // Where the reference is kept across restarts ("": nowhere; daemon/reference_file.h).
  std::string reference_file;
  // The axis's sections as one document (stage, interferometer, sim, daq.<driver>) for the
  // backend's factory (drivers::make_backend).
  YAML::Node document;
};

// The implicit move assignment may throw only through YAML::Node, which throws on an invalid node;
// a parsed document holds none.
// NOLINTNEXTLINE(bugprone-exception-escape)
struct DaemonConfig {
  std::string file;
  std::vector<DeviceConfig> devices;
  std::vector<AxisConfig> axes;
  ListenConfig server;
  RealtimeConfig realtime;
  LoggingConfig logging;
  RecordingConfig recording;
  YAML::Node root;  // the whole document (reloads read control: again from the file)

  // The index of the axis called `name`, or -1.
  int axis_index(const std::string& name) const;
};

// What a valid configuration still does that a lab should know of, one sentence each (TCP open
// to other machines, TCP without a token): --check-config prints them, idmd logs them at start.
std::vector<std::string> config_warnings(const DaemonConfig& config);

// Parses every section (constructs each device object to check its section, without I/O).
DaemonConfig parse_daemon_config(const YAML::Node& root, const std::string& file);
// load_yaml_file + parse_daemon_config.
DaemonConfig load_daemon_config(const std::string& path);
// Every axis's control: section again, from a fresh read of the file (SIGHUP and *RST). The
// axes, their order and their stages must be the ones of `running` (else InputError).
std::vector<ControlConfig> reload_control_configs(const YAML::Node& root, const std::string& file,
                                                  const DaemonConfig& running);

// config/README.md's generated tables (idmd --config-reference), one per section.
std::string config_reference();

// The largest stroke of the map: max_stroke_m (0: the stage's nominal stroke), capped by what the
// output's voltage range reaches.
double largest_stroke_m(const ControlConfig& control, double stage_stroke_m,
                        const drivers::OutputCapabilities& caps);
// The highest frequency of the map: max_freq_hz narrowed by the output (a buffered output plays at
// least four samples a period of its clock, output_sample_rate_hz capped by the device's; a
// function generator its max_freq_hz).
double highest_freq_hz(const ControlConfig& control, const drivers::OutputCapabilities& caps);

// The device limits the region map uses: the configured ranges narrowed by the output's
// capabilities (read after configure: some devices report them only then).
control::DeviceLimits device_limits(const ControlConfig& control, const model::StageParams& stage,
                                    const drivers::OutputCapabilities& caps);
control::RegionMapConfig region_map_config(const ControlConfig& control,
                                           const model::StageParams& stage,
                                           const control::DeviceLimits& limits);

}  // namespace idm::daemon
