// The closed-loop positioner: burst -> read the interferometer -> correct, until the slider is
// within tolerance of the target (default: one interferometer count). A state machine advanced by
// tick(), so that the daemon's real-time loop can drive it: tick() and every command below never
// block, allocate, lock or log (buffers are sized at construction).
//
// CONTRACT (shared with daemon/): the names and meanings in this header are what the daemon codes
// against. Extend it; do not change what is here without changing the daemon with it.
//
//   IDLE      at rest, nothing commanded (after a move that reached its target, a stop, or start)
//   MOVING    a burst (or a chunk of one) is loaded or playing
//   SETTLING  the output is at rest; waiting settle_s, then reading the position
//   FAULT     something is wrong; the output has been stopped (zero). Commands other than
//             stop/reset_fault are refused until reset_fault().
//
// Stop at any time: a burst is played in chunks of whole cycles no longer than max_chunk_s, each
// ending with the actuator at 0 and the slider at rest; stop() lets the playing chunk end (never
// a step cut short, never a fast edge) and plays nothing after it. A fault stops the output at
// once (WaveformOutput::stop brings it to zero).
#pragma once

#include <cstddef>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "control/planner.h"
#include "control/region_map.h"
#include "drivers/interfaces.h"
#include "drivers/position_word.h"

namespace idm::control {

class Calibration;

struct PositionerConfig {
  // |target - position| that counts as arrived; 0: one interferometer count.
  double tolerance_m = 0.0;
  // Correction rounds after the first plan (the motor record's RTRY); one more -> FAULT.
  int max_retries = 10;
  // Bursts in a row that each moved less than stall_fraction of their prediction -> FAULT.
  int stall_bursts = 3;
  double stall_fraction = 0.2;
  // After a burst ends, wait this long before the position is read.
  double settle_s = 2e-3;
  // Longest chunk played in one piece (whole cycles; at least one cycle).
  double max_chunk_s = 0.05;
  // Words latched and averaged for a position at rest.
  int latch_words = 4;
  // Soft limits: a move whose target lies outside is refused before anything moves.
  double soft_lower_m = -std::numeric_limits<double>::infinity();
  double soft_upper_m = std::numeric_limits<double>::infinity();
  // While IDLE, the position is re-latched at most this often (for POS? queries).
  double idle_poll_s = 0.01;
};

// Throws model::InputError naming the key and the allowed range.
void validate(const PositionerConfig& config, const std::string& where = "control");

enum class MotionState : std::uint8_t { Idle, Moving, Settling, Fault };
const char* motion_state_name(MotionState state);  // "IDLE", "MOVING", "SETTLING", "FAULT"

enum class MotionFault : std::uint8_t {
  None,
  InvalidSample,  // an interferometer word with an error bit, a glitch or lost continuity
  Stall,          // stall_bursts bursts in a row without progress
  RetryLimit,     // still outside tolerance after max_retries corrections
  Driver,         // a driver call failed (the driver's message is in last_driver_error())
  NoPlan,         // no usable cell moves toward the target (map empty for that direction)
};
const char* motion_fault_name(MotionFault fault);  // "none", "invalid_sample", ...

// Why a command was refused (nothing moved).
enum class Refusal : std::uint8_t {
  None,               // accepted
  NotFinite,          // a NaN or infinite argument
  OutsideSoftLimits,  // the target lies outside [soft_lower_m, soft_upper_m]
  Faulted,            // in FAULT: reset_fault() first
  Busy,               // a move is in progress (stop it first)
  OutOfRange,         // an open-loop step's cycles/duty/frequency/stroke outside the device limits
  NoPosition,         // the position is not known (no valid word yet)
};
const char* refusal_name(Refusal refusal);  // "none", "not_finite", ...

// A plain snapshot (trivially copyable) for the daemon to publish through a latest-value buffer.
struct MotionStatus {
  MotionState state = MotionState::Idle;
  MotionFault fault = MotionFault::None;
  bool position_valid = false;
  double position_m = 0.0;   // last position read at rest (or during a burst, from the stream)
  double target_m = 0.0;     // of the current or last move
  bool closed_loop = false;  // the current/last motion is a move (not an open-loop STEP)
  std::uint64_t moves = 0;           // moves started since construction
  std::uint64_t bursts = 0;          // chunks played since construction
  std::uint64_t cycles = 0;          // cycles played since construction
  std::uint32_t corrections = 0;     // correction rounds of the current/last move
  double last_move_time_s = 0.0;     // time the last finished move took
};

class Positioner {
 public:
  // The map, output, interferometer and (optional) calibration must outlive the positioner; the
  // devices must be active before tick() moves anything. Throws model::InputError on a bad config.
  Positioner(const RegionMap& map, const PlannerConfig& planner, const PositionerConfig& config,
             drivers::WaveformOutput& output, drivers::Interferometer& interferometer,
             Calibration* calibration = nullptr);

  // ---- commands (real-time safe; nothing moves until tick()) ----
  Refusal move_absolute(double target_m);
  Refusal move_relative(double distance_m);
  // Open-loop burst of |cycles| cycles of (duty, freq_hz, stroke_m); negative cycles mirror the
  // duty (1 - duty) to move the other way. duty/freq/stroke <= 0: the map's largest-step cell
  // for that direction.
  Refusal step_open_loop(std::int64_t cycles, double duty = 0, double freq_hz = 0,
                         double stroke_m = 0);
  // Ends motion at the next chunk end (see above). No effect when idle.
  void stop();
  // Leaves FAULT for IDLE (the output is already at zero); re-reads the position.
  void reset_fault();
  Refusal set_soft_limits(double lower_m, double upper_m);

  // ---- the state machine ----
  // Advances by polling the devices; now_s on any monotonic clock (seconds). Never blocks.
  void tick(double now_s);

  const MotionStatus& status() const { return status_; }
  bool at_rest() const;  // IDLE or FAULT (the motor record's DMOV = 1)
  const PositionerConfig& config() const { return config_; }
  double tolerance_m() const;
  // The driver's message for MotionFault::Driver (empty otherwise). Not real-time safe to copy.
  const std::string& last_driver_error() const { return last_driver_error_; }

 private:
  const RegionMap& map_;
  Planner planner_;
  PositionerConfig config_;
  drivers::WaveformOutput& output_;
  drivers::Interferometer& interferometer_;
  Calibration* calibration_;
  MotionStatus status_;
  std::string last_driver_error_;
  // (implementation state: preallocated plan, sample buffer, stream buffer, decoder, ...)
};

// For tools, tests and benchmarks: ticks until at_rest() or timeout_s of `clock` time has passed;
// `advance(dt)` is called between ticks (for the simulated stage's synthetic clock:
// sim->advance_s(dt); on the wall clock: a sleep). Returns the final state.
template <typename Clock, typename Advance>
MotionState run_until_rest(Positioner& positioner, Clock&& now_s, Advance&& advance,
                           double timeout_s, double tick_s = 1e-4) {
  const double start = now_s();
  positioner.tick(start);
  while (!positioner.at_rest() && now_s() - start < timeout_s) {
    advance(tick_s);
    positioner.tick(now_s());
  }
  return positioner.status().state;
}

}  // namespace idm::control
