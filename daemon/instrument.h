// What the command server asks of the daemon: one typed call per protocol command
// (docs/command-protocol.md). The protocol layer (protocol.h: parsing, short forms,
// error queue, reply formatting) and the socket server (server.h) call it; the daemon core
// (daemon.h) implements it on top of the real-time loop.
//
// CONTRACT between the protocol/server side and the daemon core: extend it, do not change what
// is here without changing both sides.
//
// Threading: called from the server thread only (one call at a time). Implementations never block
// on motion: a move is queued to the real-time loop and the call returns; queries read the latest
// published status. A call that fails returns a CommandError; the protocol layer puts it in the
// client's error queue.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "recording/dataset_limits.h"

namespace idm::daemon {

// SCPI-style codes: negative are the standard ones, positive are the device's own.
namespace error_code {
inline constexpr int kNoError = 0;
inline constexpr int kCommandError = -100;
inline constexpr int kInvalidCharacter = -101;
inline constexpr int kSyntaxError = -102;
inline constexpr int kDataTypeError = -104;        // e.g. a quoted string where a number belongs
inline constexpr int kParameterNotAllowed = -108;  // too many arguments
inline constexpr int kMissingParameter = -109;     // too few arguments
inline constexpr int kUndefinedHeader = -113;
inline constexpr int kHeaderSuffixOutOfRange = -114;  // AXIS<n> with no axis n
inline constexpr int kNumericDataError = -120;        // not a number, not finite
inline constexpr int kExecutionError = -200;
inline constexpr int kCommandProtected = -203;    // a motion command on TCP before *AUTH
inline constexpr int kSettingsConflict = -221;    // e.g. a move while in FAULT or busy
inline constexpr int kDataOutOfRange = -222;      // e.g. a target past the soft limits
inline constexpr int kDataCorruptOrStale = -230;  // a position that cannot be trusted
inline constexpr int kMassStorageError = -250;    // a SWEEP's data_dir too full for its dataset
inline constexpr int kHardwareError = -240;
inline constexpr int kHardwareMissing = -241;  // e.g. a simulation command on a real backend
inline constexpr int kQueueOverflow = -350;
inline constexpr int kInputBufferOverrun = -363;  // a line longer than the limit
// Device faults (positive): see kDeviceFaults.
inline constexpr int kFaultInvalidSample = 101;
inline constexpr int kFaultStall = 102;
inline constexpr int kFaultRetryLimit = 103;
inline constexpr int kFaultDriver = 104;
inline constexpr int kFaultNoPlan = 105;
inline constexpr int kFaultCaptureOverrun = 106;
inline constexpr int kFaultDeviceLost = 107;
inline constexpr int kFaultWindowUnreachable = 108;
// A move (or a STEP) that ended without reaching its window, without a fault or a STOP: see
// kMoveResults.
inline constexpr int kMoveLimit = 111;
inline constexpr int kMoveEndOfTravel = 112;
inline constexpr int kMoveTimeout = 113;
// A motion this client started was stopped by another client's STOP or *RST (or a reload).
inline constexpr int kMoveStoppedByOther = 114;
}  // namespace error_code

// MOVE:RESult?'s words other than OK/NONE/FAULT/STOPPED, and the error a move that ended so
// queues for the client that started it (a FAULT queues the fault's code, kDeviceFaults; a move
// the client stopped queues nothing: MOVE:RESult? says STOPPED).
struct MoveResultCode {
  const char* word;
  int code;
  const char* text;
};
inline constexpr MoveResultCode kMoveResults[] = {
    {"LIMIT", error_code::kMoveLimit, "Move ended at a soft limit"},
    {"END_OF_TRAVEL", error_code::kMoveEndOfTravel, "End of travel"},
    {"TIMEOUT", error_code::kMoveTimeout, "Move timed out"},
};

// The one table of device faults: the name a status reports (control::motion_fault_name), the
// positive code a motion that ended in it queues, and the code's standard text.
struct DeviceFault {
  const char* name;
  int code;
  const char* text;
};
inline constexpr DeviceFault kDeviceFaults[] = {
    {"invalid_sample", error_code::kFaultInvalidSample, "Invalid interferometer sample"},
    {"stall", error_code::kFaultStall, "Stall"},
    {"retry_limit", error_code::kFaultRetryLimit, "Retry limit"},
    {"driver", error_code::kFaultDriver, "Driver error"},
    {"no_plan", error_code::kFaultNoPlan, "No plan"},
    {"capture_overrun", error_code::kFaultCaptureOverrun, "Capture overrun"},
    {"device_lost", error_code::kFaultDeviceLost, "Device lost"},
    {"window_unreachable", error_code::kFaultWindowUnreachable, "Window unreachable"},
};

// SWEEP's per-cell trials and per-trial cycles: the protocol's check and the daemon's; the
// dataset's own limits (recording/dataset_limits.h), which every reader of a sweep checks.
inline constexpr int kMaxSweepTrials = recording::kMaxTrialsPerCell;
inline constexpr int kMaxSweepCycles = recording::kMaxCycles;

// The largest user offset, m: the config's travel lies within [-10, 10] m, so every user-frame
// position stays within [-20, 20] m, where a double still resolves 4e-15 m.
inline constexpr double kMaxUserOffsetM = 10.0;

struct CommandError {
  int code = error_code::kNoError;
  std::string text;  // without quotes; the protocol layer quotes it
  bool ok() const { return code == error_code::kNoError; }
};

// A plain snapshot of one axis for STATus? and friends. Positions (position, target, soft limits)
// are in the user frame: the axis's own (dial) position plus its user offset.
struct InstrumentStatus {
  std::string name;   // the axis's name ("x")
  std::string state;  // "IDLE", "MOVING", "SETTLING", "FAULT"
  bool position_valid = false;
  double position_m = 0;  // meaningful only when position_valid
  double target_m = 0;
  double user_offset_m = 0;  // POSition:OFFSet: user = dial + offset
  std::string fault;         // "none", "invalid_sample", "stall", ...
  bool motion_done = true;
  double soft_lower_m = 0;
  double soft_upper_m = 0;
  double resolution_m = 0;  // one interferometer count
  bool referenced = false;  // the position is known against the stage (not only relative)
  std::string device;       // the device link: "up", "lost"
  std::uint64_t moves = 0;
  std::uint64_t bursts = 0;
  std::uint64_t cycles = 0;
  // The daemon core's last error for this axis, "" for none: the fault the last failed motion
  // ended in (with the driver's message), a failed calibration save (file and reason), a sweep's
  // failures, a deferred *RST that could not reload the settings, a device lost or back. *RST
  // clears it.
  std::string last_error;
  // Why the last motion ended: NONE, OK, STOPPED, LIMIT, END_OF_TRAVEL, FAULT, TIMEOUT, and the
  // final distance to its target; the motion: "move", "step", "reference", "" before any.
  std::string result = "NONE";
  double result_distance_m = 0;
  // After FAULT window_unreachable: the narrowest window the axis is expected to meet, m; else 0.
  double least_window_m = 0;
  std::string motion;
  int eot = 0;               // -1 / +1: stopped at the end of travel that way
  bool in_position = false;  // at rest within the window of the target
  bool holding = false;
  bool referencing = false;
};

// Settings of the motions that follow, per axis (MOVE:WINDow, MOVE:DWELl, EOT:STEP, EOT:CYCLes,
// HOLD, HOLD:WINDow).
enum class MotionSetting : std::uint8_t {
  Window,
  Dwell,
  EotStep,
  EotCycles,
  Hold,
  HoldWindow,
  MaxSpeed
};
// REFerence's argument (Default: the axis's configured one).
enum class ReferenceMethod : std::uint8_t { Default, Negative, Positive, Mark };

// The last (or running) sweep: SWEEP?.
struct SweepStatus {
  std::string state = "NONE";  // NONE, RUNNING, DONE, STOPPED, FAILED
  int axis = -1;               // 0-based; -1 before the first sweep
  std::uint64_t planned = 0, written = 0, failed = 0;
  std::string directory;
  std::string error;  // FAILED: the error that ended it ("" otherwise)
};

// The real-time loop's timing, for the loop-statistics queries.
struct LoopStats {
  double period_s = 0;
  std::uint64_t wakeups = 0;
  std::uint64_t deadline_misses = 0;
  double latency_min_s = 0, latency_avg_s = 0, latency_max_s = 0;
  // Wake-up latency histogram: counts of [k, k+1) * bin_width_s; the last bin holds the rest.
  double bin_width_s = 0;
  std::uint64_t bins[32] = {};
};

// `axis` is 0-based here (the protocol's AXIS1 is 0) and always < axis_count(): the protocol
// layer checks it (-114) before it calls.
class Instrument {
 public:
  virtual ~Instrument() = default;

  // *IDN? fields: maker, model ("idmd"), serial (or "0"), version.
  virtual std::string identity() = 0;
  virtual int axis_count() = 0;
  virtual std::string axis_name(int axis) = 0;
  // *RST: stop motion on every axis, clear the faults, reload control settings (soft limits a
  // client set stay).
  virtual CommandError reset() = 0;
  // *OPC?: every motion started before, on every axis, has finished.
  virtual bool motion_done() = 0;
  // MOVE:DONE? of one axis.
  virtual bool motion_done(int axis) = 0;
  virtual InstrumentStatus status(int axis) = 0;
  // POSition:ALL?: every axis's position read at one instant (NaN where not valid).
  virtual std::vector<double> positions() = 0;

  // Every position below is in the user frame (InstrumentStatus).
  virtual CommandError move_absolute(int axis, double target_m) = 0;
  virtual CommandError move_relative(int axis, double distance_m) = 0;
  // STEP n[,duty,freq_hz[,stroke_m]]: n != 0; an omitted argument is NaN (duty and freq both
  // omitted: the daemon's cell; stroke omitted: the largest stroke). Every given argument is used
  // or the step is refused (-222 naming it and its range); so is a burst whose predicted end lies
  // outside the soft limits.
  virtual CommandError step(int axis, std::int64_t cycles, double duty, double freq_hz,
                            double stroke_m) = 0;
  // STOP: every axis (and a running sweep); AXIS<n>:STOP: that axis (and a sweep on it).
  virtual CommandError stop() = 0;
  virtual CommandError stop(int axis) = 0;

  virtual CommandError set_soft_limits(int axis, double lower_m, double upper_m) = 0;

  // POSition:SET: the axis at rest with a trusted position, that position becomes `position_m`
  // (the user offset changes; nothing moves). POSition:OFFSet: the user offset itself. The soft
  // limits, the target and the travel stay where they are on the stage: their user-frame values
  // move with the offset. Offsets within +-kMaxUserOffsetM.
  virtual CommandError set_position(int axis, double position_m) = 0;
  virtual CommandError set_user_offset(int axis, double offset_m) = 0;

  // A setting out of its range is -222 naming the command and the range.
  virtual CommandError set_motion_setting(int axis, MotionSetting which, double value) = 0;
  virtual double motion_setting(int axis, MotionSetting which) = 0;
  // REFerence: finds the end stop or mark and sets the position there (in the background).
  virtual CommandError reference(int axis, ReferenceMethod method) = 0;

  // REGion? f,duty[,stroke]: region name ("CUTOFF", "ONESTEP", "MULTISTEP") and predicted step.
  // stroke_m NaN: the largest stroke.
  virtual CommandError region(int axis, double freq_hz, double duty, double stroke_m,
                              std::string& region, double& step_m) = 0;
  // REGion:RANGe?: what the axis's map covers, the device's limits applied: the frequencies, and
  // the strokes.
  struct RegionRange {
    double min_freq_hz = 0, max_freq_hz = 0, min_stroke_m = 0, max_stroke_m = 0;
  };
  virtual RegionRange region_range(int axis) = 0;

  // SWEEP dir,freqs,duties,trials[,cycles]: starts the characterization sweep of one axis in the
  // background (motion_done() is false until it ends); errors of the arguments are returned at
  // once.
  virtual CommandError sweep(int axis, const std::string& dir, const std::vector<double>& freqs_hz,
                             const std::vector<double>& duties, int trials, int cycles) = 0;
  virtual SweepStatus sweep_status() = 0;

  // Simulated axes only (-241 on a real backend): SIMulation:PUSH displaces the slider by
  // distance_m at once; SIMulation:FAULt sets an injected fault: beam_lost, stalled, glitches
  // (value: probability per word), disconnect (1: pulled, 0: back), power_cycle, timeouts.
  virtual CommandError sim_push(int axis, double distance_m) = 0;
  virtual CommandError sim_fault(int axis, const std::string& fault, double value) = 0;

  virtual LoopStats loop_stats() = 0;
};

}  // namespace idm::daemon
