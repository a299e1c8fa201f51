// The daemon core: implements Instrument for 1..N axes on top of the parts that each have one job:
//
//   device links (drivers/link.h)   one per device, each on its own I/O thread: the only code
//                                   that calls a driver
//   MotionSupervisor (supervisor.h) the real-time loop's body: per-axis state machines
//                                   (Axis: region map, positioner, trials), lock-free in and out
//   SweepRunner (sweep_runner.h)    SWEEP's recorder thread
//   Housekeeping (housekeeping.h)   calibration saves, device health, deferred *RST, notes
//   the server thread               calls the Instrument methods below (one at a time)
//
// Before start() and after shutdown() the caller's thread owns the devices.
#pragma once

#include <memory>
#include <mutex>
#include <stdexcept>
#include <string>
#include <vector>

#include "daemon/axis.h"
#include "daemon/config.h"
#include "daemon/housekeeping.h"
#include "daemon/instrument.h"
#include "daemon/rt_loop.h"
#include "daemon/supervisor.h"
#include "daemon/sweep_runner.h"
#include "drivers/link.h"

namespace idm::daemon {

// idmd's exit codes (daemon/README.md).
namespace exit_code {
inline constexpr int kOk = 0;
inline constexpr int kRuntimeError = 1;  // a failure while running (logged)
inline constexpr int kBadConfig = 2;     // bad command line or configuration: nothing touched
inline constexpr int kNoHardware = 3;    // a device could not be opened, or no valid position
inline constexpr int kListenFailed = 4;  // the TCP port or Unix socket could not be bound
}  // namespace exit_code

// start() failed; exit_code says how idmd should exit.
class StartError : public std::runtime_error {
 public:
  StartError(int code, const std::string& what) : std::runtime_error(what), code_(code) {}
  int exit_code() const { return code_; }

 private:
  int code_;
};

class Daemon final : public Instrument, public Reloader {
 public:
  // Parses nothing and opens nothing: the config is already checked.
  explicit Daemon(DaemonConfig config);
  ~Daemon() override;
  Daemon(const Daemon&) = delete;
  Daemon& operator=(const Daemon&) = delete;

  // Builds and opens every device (configure, activate: outputs at zero), builds each axis's map
  // and positioner, loads the calibrations, starts the I/O threads and the real-time loop, and
  // returns once every axis reads a valid position (server.ready_timeout_s). Throws StartError
  // (kNoHardware for a device that fails or an axis without a valid position in time, kBadConfig
  // for settings the device cannot meet). Returns the real-time setup warning ("" when all was
  // permitted); the calibration notes come through take_notes().
  std::string start();
  // Stops motion and any sweep, waits for rest (bounded), ends the threads, brings every output
  // to zero, shuts the devices down, saves the calibrations. Idempotent. `why` is what a sweep
  // it stops says stopped it (its plan.yaml and the log), e.g. "the daemon stopped (SIGTERM)".
  void shutdown(const std::string& why = "the daemon stopped");
  // *RST (no sweep running): re-read every axis's control: section and rebuild now, the motions
  // stopped at their chunks' ends and the loop parked at rest. The soft limits come from the file
  // (FromFile) or stay (Keep: limits a client set are never wiped by another's reset). false +
  // error when the file is bad (the old settings stay).
  enum class SoftLimits : std::uint8_t { FromFile, Keep };
  bool reload_control(std::string& error, SoftLimits limits = SoftLimits::FromFile);
  // SIGHUP: the same with the file's limits, carried out by housekeeping once no sweep runs and
  // every motion in progress has ended (never cut short; new ones are refused meanwhile with
  // -221). `why` names it in the log. reload_pending() until it is done (the log says how).
  void request_reload(const std::string& why);
  bool reload_pending() const;
  // ---- Reloader (housekeeping) ----
  std::string prepare_reload(bool limits_from_file) override;
  std::string apply_reload() override;

  const DaemonConfig& config() const { return config_; }
  std::uint64_t loop_ticks() const { return loop_ ? loop_->ticks() : 0; }
  bool loop_running() const { return loop_ && loop_->running(); }
  void set_loop_thread_hook(LoopThreadHook hook) { loop_hook_ = hook; }
  // The commanded elongation of a `sim` axis's output after shutdown (tests); NaN otherwise.
  double sim_output_m(int axis = 0);
  // The simulated stage behind a `sim` axis (tests, fault injection); null otherwise.
  drivers::sim::SimBackend* sim(int axis = 0);
  drivers::DeviceLink& link_of(int axis) {
    return axes_.at(static_cast<std::size_t>(axis))->link();
  }
  // Description of the last finished SWEEP ("" before any).
  std::string last_sweep_report() const;
  // Lines to log since the last call (warnings and news).
  std::vector<Housekeeping::Note> take_notes();

  // ---- Instrument ----
  std::string identity() override;
  int axis_count() override { return static_cast<int>(axes_.size()); }
  std::string axis_name(int axis) override;
  CommandError reset() override;
  bool motion_done() override;
  bool motion_done(int axis) override;
  InstrumentStatus status(int axis) override;
  std::vector<double> positions() override;
  CommandError move_absolute(int axis, double target_m) override;
  CommandError move_relative(int axis, double distance_m) override;
  CommandError step(int axis, std::int64_t cycles, double duty, double freq_hz,
                    double stroke_m) override;
  CommandError stop() override;
  CommandError stop(int axis) override;
  CommandError set_soft_limits(int axis, double lower_m, double upper_m) override;
  CommandError set_position(int axis, double position_m) override;
  CommandError set_user_offset(int axis, double offset_m) override;
  CommandError set_motion_setting(int axis, MotionSetting which, double value) override;
  double motion_setting(int axis, MotionSetting which) override;
  CommandError reference(int axis, ReferenceMethod method) override;
  CommandError region(int axis, double freq_hz, double duty, double stroke_m, std::string& region,
                      double& step_m) override;
  CommandError sweep(int axis, const std::string& dir, const std::vector<double>& freqs_hz,
                     const std::vector<double>& duties, int trials, int cycles) override;
  SweepStatus sweep_status() override;
  RegionRange region_range(int axis) override;
  CommandError sim_push(int axis, double distance_m) override;
  CommandError sim_fault(int axis, const std::string& fault, double value) override;
  LoopStats loop_stats() override;

 private:
  void build_devices();
  void open_devices();
  void build_axes();
  // The axis's reference_file: restored when it holds, else a note says why not.
  void restore_reference(Axis& axis);
  void wait_until_ready();
  CommandError submit(AxisCommand command);
  CommandError refusal_error(const AxisCommand& command, control::Refusal refusal, double target_m);
  CommandError fault_error(control::MotionFault fault);
  bool wait_at_rest(double timeout_s);
  // A setting a command changes, checked as the config file's reader checks it
  // (set_motion_setting).
  CommandError check_setting(int axis, const MotionSettings& now, const char* command,
                             const char* key, double value);
  CommandError check_sweep(int axis, const std::vector<double>& freqs_hz,
                           const std::vector<double>& duties, int trials, int cycles);
  // -250 when recording.data_dir has too little room for the sweep's dataset.
  CommandError check_sweep_space(Axis& a, const std::vector<double>& freqs_hz, std::size_t duties,
                                 int trials, int cycles);

  DaemonConfig config_;
  std::vector<std::unique_ptr<drivers::DeviceLink>> links_;
  std::vector<std::unique_ptr<Axis>> axes_;
  std::unique_ptr<MotionSupervisor> supervisor_;
  std::unique_ptr<RtLoop> loop_;
  LoopThreadHook loop_hook_ = nullptr;
  std::unique_ptr<SweepRunner> sweeps_;
  std::unique_ptr<Housekeeping> housekeeping_;
  std::mutex control_mutex_;  // reloads against readers of an axis's map, limits and settings
  double errors_cleared_s_ = -1;
  bool started_ = false;
  bool shut_down_ = false;
  std::vector<Housekeeping::Note> start_notes_;
  std::vector<ControlConfig> reload_plan_;  // prepared, not yet applied (control_mutex_)
  // recording.data_dir, held open from the start (created when missing): datasets are made below
  // this descriptor, never by walking the path again. Invalid: why in data_dir_error_.
  void open_data_dir();
  recording::DirFd data_dir_;
  std::string data_dir_error_;
  bool reload_limits_from_file_ = false;
};

}  // namespace idm::daemon
