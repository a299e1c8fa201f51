// The daemon core: implements Instrument on top of the real-time loop.
//
// Threads and who owns what (daemon/README.md has the picture):
//   * the real-time loop (RtLoop) is the only thread that touches the device while the daemon
//     runs: it ticks control::Positioner, plays the sweep's trial bursts and streams their samples
//     out; it never allocates, locks or logs.
//   * the server thread calls the Instrument methods: commands go in through an SPSC ring and are
//     acknowledged by the loop (an atomic sequence number), status comes out of a seqlock.
//   * the recorder thread runs a SWEEP: it sends one trial at a time through its own SPSC ring,
//     receives the trial's samples through another, and writes the dataset (DatasetWriter).
//   * the main thread (signals) parks the loop to reload control settings, and shuts down.
// Before start() and after shutdown() the caller's thread owns the device.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "control/calibration.h"
#include "control/positioner.h"
#include "control/region_map.h"
#include "daemon/config.h"
#include "daemon/instrument.h"
#include "daemon/lockfree.h"
#include "daemon/rt_loop.h"
#include "daemon/thread.h"
#include "drivers/interfaces.h"
#include "drivers/position_word.h"
#include "recording/dataset.h"

namespace idm::daemon {

// idmd's exit codes (daemon/README.md).
namespace exit_code {
inline constexpr int kOk = 0;
inline constexpr int kRuntimeError = 1;   // a failure while running (logged)
inline constexpr int kBadConfig = 2;      // bad command line or configuration: nothing touched
inline constexpr int kNoHardware = 3;     // the device could not be opened or activated
inline constexpr int kListenFailed = 4;   // the TCP port or Unix socket could not be bound
}  // namespace exit_code

// start() failed; exit_code says how idmd should exit.
class StartError : public std::runtime_error {
 public:
  StartError(int code, const std::string& what) : std::runtime_error(what), code_(code) {}
  int exit_code() const { return code_; }

 private:
  int code_;
};

class Daemon final : public Instrument, private LoopBody {
 public:
  // Parses nothing and opens nothing: the config is already checked.
  explicit Daemon(DaemonConfig config);
  ~Daemon() override;
  Daemon(const Daemon&) = delete;
  Daemon& operator=(const Daemon&) = delete;

  // Builds the device (drivers' factory), configures and activates it, loads the calibration,
  // builds the region map and the positioner, starts the recorder and the real-time loop.
  // Throws StartError (kNoHardware when the device fails, kBadConfig for limits the device cannot
  // meet). Returns the real-time setup warning ("" when everything was permitted).
  std::string start();
  // Stops motion (the playing chunk ends, or a sweep burst is stopped), waits for rest (bounded),
  // stops the recorder (finished trials are on disk) and the loop, brings the output to zero,
  // deactivates and shuts the device down, saves the calibration. Idempotent.
  void shutdown();
  // SIGHUP and *RST: re-read the control: section from the config file and rebuild the
  // positioner (and the region map when its settings changed) while the loop is parked at rest.
  // The soft limits come from the file (SIGHUP: the administrator's reload) or stay as they are
  // (*RST: limits a client set with LIM are never wiped by another's reset). The target, the
  // position and the counters carry over. false + error when the file is bad (the old settings
  // stay).
  enum class SoftLimits : std::uint8_t { FromFile, Keep };
  bool reload_control(std::string& error, SoftLimits limits = SoftLimits::FromFile);

  const DaemonConfig& config() const { return config_; }
  std::uint64_t loop_ticks() const { return loop_.ticks(); }
  bool loop_running() const { return loop_.running(); }
  void set_loop_thread_hook(LoopThreadHook hook) { loop_.set_thread_hook(hook); }
  // The output's commanded elongation after shutdown, for a `sim` device (tests); NaN otherwise.
  double sim_output_m() const;
  // The device (tests, after shutdown() or before start()).
  drivers::Device& device() { return device_; }
  // Description of the last finished SWEEP ("" before any): trials written, failures, errors.
  std::string last_sweep_report();
  // Lines to log (warnings) that arose on the daemon's own threads since the last call: a failed
  // calibration save (once per distinct failure, naming the file and the reason), a deferred
  // *RST that failed. idmd logs them; also after shutdown() (the final save).
  std::vector<std::string> take_notes();

  // ---- Instrument ----
  std::string identity() override;
  CommandError reset() override;
  bool motion_done() override;
  InstrumentStatus status() override;
  CommandError move_absolute(double target_m) override;
  CommandError move_relative(double distance_m) override;
  CommandError step(std::int64_t cycles, double duty, double freq_hz, double stroke_m) override;
  CommandError stop() override;
  CommandError set_soft_limits(double lower_m, double upper_m) override;
  CommandError region(double freq_hz, double duty, double stroke_m, std::string& region,
                      double& step_m) override;
  CommandError sweep(const std::string& dir, const std::vector<double>& freqs_hz,
                     const std::vector<double>& duties, int trials, int cycles) override;
  LoopStats loop_stats() override;

 private:
  // ---- loop <-> other threads ----
  enum class CommandKind : std::uint8_t { MoveAbsolute, MoveRelative, Step, Stop, SetLimits };
  struct Command {
    CommandKind kind = CommandKind::Stop;
    std::uint64_t seq = 0;
    double a = 0, b = 0, c = 0;
    std::int64_t n = 0;
  };
  // One trial of a sweep, recorder -> loop.
  struct TrialRequest {
    std::uint32_t index = 0;
    double freq_hz = 0, duty = 0, stroke_m = 0;
    std::uint32_t cycles = 0;
    std::uint32_t period_samples = 0, extension_samples = 0;  // buffered output; 0 for parameters
    std::uint32_t rest_samples = 0, settle_samples = 0;
    double return_to_m = 0;  // NaN: start where the slider is
  };
  enum class TrialEvent : std::uint8_t { Begin, Sample, End, Failed };
  enum class TrialFailure : std::uint8_t { None, Positioning, Driver, Overflow, Stopped, Busy };
  // loop -> recorder. Begin: word = latched position, t_s = time offset of the waveform's t = 0 on
  // the stream's clock. Sample: t_s, word from the stream. Failed: word = TrialFailure.
  struct TrialRecord {
    TrialEvent event = TrialEvent::Sample;
    std::uint32_t index = 0;
    double t_s = 0;
    std::uint64_t word = 0;
  };
  // An error text with the time it happened (CLOCK_MONOTONIC), through a seqlock. text is NUL
  // terminated (truncated to fit).
  struct ErrorNote {
    double t_s = -1;  // < 0: none
    char text[224] = {};
  };
  // Published by the loop after every tick.
  struct Published {
    control::MotionStatus motion;
    double soft_lower_m = 0, soft_upper_m = 0;
    bool sweep_trial_active = false;
    bool parked = false;
  };

  void tick(double now_s) override;
  void apply(const Command& cmd);
  void sweep_tick(double now_s);
  void sweep_fail(TrialFailure why);
  void publish();
  void note_fault();  // loop: the fault the positioner just entered -> fault_note_

  // Server side.
  CommandError submit(Command cmd);
  CommandError refusal_error(control::Refusal refusal, double value, CommandKind kind);
  CommandError fault_error(control::MotionFault fault);
  bool wait_at_rest(double timeout_s);

  // Park the loop (it stops ticking the positioner once at rest), run fn, unpark. Non-RT threads.
  template <typename Fn>
  bool with_loop_parked(double timeout_s, Fn&& fn);
  void build_positioner();  // new Positioner from config_.control and the current map
  void build_map();

  // Recorder (housekeeping) thread.
  void recorder_main();
  void save_calibration_if_changed();
  // Saves a snapshot; on failure logs once per distinct error (note) and sets the housekeeping
  // error. Recorder thread, or the main thread after the recorder has ended.
  void save_calibration(const control::CalibrationState& state);
  void set_housekeeping_error(const std::string& text);
  void add_note(std::string line);
  struct SweepJob;
  void run_sweep(SweepJob& job);

  DaemonConfig config_;
  drivers::Device device_;
  bool started_ = false;
  bool shut_down_ = false;
  control::DeviceLimits limits_;
  std::unique_ptr<control::RegionMap> map_;
  std::unique_ptr<control::Calibration> calibration_;
  std::unique_ptr<control::Positioner> positioner_;
  std::mutex control_mutex_;  // non-RT threads: map_, positioner_ rebuilds, config_.control

  RtLoop loop_;
  SpscRing<Command, 64> commands_;          // server -> loop
  std::uint64_t next_seq_ = 0;              // server thread
  std::atomic<std::uint64_t> acked_seq_{0};
  std::atomic<std::uint8_t> acked_refusal_{0};
  std::atomic<double> acked_target_m_{0};  // the refused (or accepted) command's target, NaN: none
  std::atomic<bool> stop_all_{false};       // shutdown: stop and keep stopped
  std::atomic<bool> park_request_{false};
  std::atomic<bool> parked_{false};
  Seqlock<Published> published_;
  Published pub_;                           // loop thread's copy
  // Last errors: the loop's (faults) and the recorder's (calibration save, sweep, deferred *RST);
  // STATus? shows the later one. errors_cleared_s_: *RST's time (server thread).
  Seqlock<ErrorNote> fault_note_;
  Seqlock<ErrorNote> housekeeping_note_;
  control::MotionFault noted_fault_ = control::MotionFault::None;  // loop thread
  double errors_cleared_s_ = -1;
  // Calibration: the loop publishes a snapshot whenever its update count changes; the recorder
  // thread saves it once the motion is done.
  Seqlock<control::CalibrationState> calibration_snapshot_;
  std::uint64_t calibration_published_updates_ = 0;  // loop thread
  std::uint64_t calibration_saved_updates_ = 0;      // recorder thread (main after shutdown)
  std::string calibration_save_error_;               // the last failure logged ("" after a success)
  // *RST while a sweep winds down: the recorder reloads the settings after it (motion_done() is
  // false until then).
  std::atomic<bool> reset_pending_{false};
  double soft_lower_m_ = 0, soft_upper_m_ = 0;  // loop thread

  // Sweep: loop-side state (preallocated).
  SpscRing<TrialRequest, 8> trial_requests_;  // recorder -> loop
  SpscRing<TrialRecord, 1u << 16> trial_records_;  // loop -> recorder
  enum class SweepPhase : std::uint8_t { Idle, Positioning, Playing };
  SweepPhase sweep_phase_ = SweepPhase::Idle;
  TrialRequest trial_{};
  std::vector<double> burst_;                  // sized at start()
  std::vector<drivers::TimedWord> stream_buf_;  // sized at start()
  double trial_t0_s_ = 0;
  std::atomic<bool> sweep_abort_{false};

  // Sweep: recorder-side state.
  StackThread recorder_;
  std::mutex recorder_mutex_;
  std::condition_variable recorder_cv_;
  std::unique_ptr<SweepJob> pending_job_;
  bool recorder_quit_ = false;
  std::vector<std::string> notes_;  // recorder_mutex_
  std::atomic<bool> sweep_active_{false};
  std::string sweep_report_;
};

}  // namespace idm::daemon
