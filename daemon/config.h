// idmd's configuration file: the sections of DESIGN.md (stage, interferometer, daq, control,
// server, realtime, logging, recording, sim), every key documented in config/README.md.
//
// The sections other layers own are read by their parsers (model::parse_stage_yaml,
// drivers::parse_interferometer_yaml, drivers::parse_daq_driver and the backend's own parser
// through drivers::make_backend_from_config, model::parse_sim_yaml); this file reads control,
// server, realtime, logging and recording. Unknown keys, wrong types and out-of-range values throw
// model::InputError "FILE:LINE: section.key: what (allowed range)". Parsing does no I/O.
#pragma once

#include <cstdint>
#include <string>

#include <yaml-cpp/yaml.h>

#include "control/calibration.h"
#include "control/planner.h"
#include "control/positioner.h"
#include "control/region_map.h"
#include "drivers/interfaces.h"
#include "model/simulation.h"
#include "model/stage.h"

namespace idm::daemon {

// `control:`: the region map's grid and friction uncertainty, the planner, the positioner (the
// motor record's RDBD/RTRY, soft limits) and the calibration.
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
  control::PlannerConfig planner;     // resolution_m comes from the interferometer
  control::PositionerConfig positioner;
  control::CalibrationConfig calibration;
  std::string calibration_file;       // "" = no saved calibration
};

// `server:`: where the command protocol listens.
struct ListenConfig {
  std::string tcp_address = "127.0.0.1";  // "" = no TCP listener
  int tcp_port = 5025;                    // 0 = any free port (printed at start)
  std::string unix_socket = "/run/idmd/idmd.sock";  // "" = no Unix socket
  int max_clients = 16;
};

// `realtime:`: the loop's period and the real-time setup it attempts.
struct RealtimeConfig {
  double period_s = 1e-4;       // 10 kHz
  bool sched_fifo = true;       // SCHED_FIFO at `priority` when permitted (CAP_SYS_NICE)
  int priority = 80;            // 1..99
  int cpu = -1;                 // pin the loop to this CPU; -1 = no affinity
  bool lock_memory = true;      // mlockall when permitted (RLIMIT_MEMLOCK / CAP_IPC_LOCK)
  double histogram_bin_s = 5e-6;  // wake-up latency histogram bin width
  double watchdog_stall_s = 0.5;  // no tick for this long: the loop is considered stalled
};

// `logging:`
struct LoggingConfig {
  std::string level = "info";   // trace, debug, info, warn, error, critical, off
  std::string format = "auto";  // auto (journal under systemd), console, journal
};

// `recording:`
struct RecordingConfig {
  std::string data_dir = "/var/lib/idmd/data";  // SWEEP directories are relative to this
  double sweep_rest_s = 5e-4;       // command at rest before each trial's first cycle
  int sweep_settle_cycles = 2;      // periods of rest recorded after the last cycle
  double sweep_span_m = 1e-3;       // a trial that would start farther than this from the sweep's
                                    // start returns there first (closed-loop move)
  int sweep_max_trials = 100000;
};

struct DaemonConfig {
  std::string file;
  model::StageFile stage;        // stage: and interferometer: (model's view)
  std::string driver;            // daq.driver
  model::SimConfig sim;          // sim:
  ControlConfig control;
  ListenConfig server;
  RealtimeConfig realtime;
  LoggingConfig logging;
  RecordingConfig recording;
  YAML::Node root;               // the whole document, for drivers::make_backend_from_config
};

// Parses every section (constructs the device object to check daq:, without I/O).
DaemonConfig parse_daemon_config(const YAML::Node& root, const std::string& file);
// load_yaml_file + parse_daemon_config.
DaemonConfig load_daemon_config(const std::string& path);
// Just the control: section (SIGHUP and *RST reload it from the file).
ControlConfig parse_control_config(const YAML::Node& root, const std::string& file,
                                   const model::StageFile& stage);

// The device limits the region map uses: the configured ranges narrowed by the output's
// capabilities (read after configure: some devices report them only then).
control::DeviceLimits device_limits(const ControlConfig& control, const model::StageParams& stage,
                                    const drivers::OutputCapabilities& caps);
control::RegionMapConfig region_map_config(const ControlConfig& control,
                                           const model::StageParams& stage,
                                           const control::DeviceLimits& limits);

}  // namespace idm::daemon
