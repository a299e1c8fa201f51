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

#include "control/calibration.h"
#include "control/planner.h"
#include "control/region_map.h"
#include "drivers/interfaces.h"
#include "drivers/position_word.h"

namespace idm::control {

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
  // An approach burst (not the plan's last) is cut so that its prediction, grown by this
  // share, still stops the planner's approach margin short of the target: the step model's own
  // error (alpha, which the mu interval of the map does not cover) must not carry it past.
  double approach_uncertainty = 0.2;
  // Only chunks predicted to move at least this many interferometer counts are judged for a
  // stall (a one-count step cannot be told from noise).
  double stall_min_counts = 3.0;
  // Most chunks in one move (a guard; 0: the planner's max_bursts).
  int max_chunks_per_move = 0;
  // ---- the step ladder (control/README.md, "Positioner") ----
  // The last chunks of a move use a rung whose learned step is at most this many counts (a step
  // under two counts always lands in the +/- one count window when played one cycle at a time).
  double final_step_counts = 2.0;
  // A rung whose learned step falls below this many counts per cycle is treated as not moving.
  double min_step_counts = 0.3;
  // A rung judged not to move (or to move the wrong way) is left out for this many moves, then
  // tried again from its seed.
  int dead_rung_moves = 100;
  // Time a chunk costs beyond its cycles (device settle, the positioner's settle, the reading),
  // used to weigh fewer, longer chunks against more, shorter ones.
  double chunk_overhead_s = 5e-3;
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
  CaptureOverrun, // the interferometer's capture filled before it was read (a chunk too long for it)
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
  // duty (1 - duty) to move the other way. duty and freq_hz NaN (omitted): the map's largest-step
  // cell for that direction; stroke_m NaN: the map's largest stroke. A given value outside the
  // device limits is refused (OutOfRange), never replaced; so is a burst whose predicted end,
  // grown by approach_uncertainty, lies outside the soft limits (OutsideSoftLimits).
  static constexpr double kOmitted = std::numeric_limits<double>::quiet_NaN();
  Refusal step_open_loop(std::int64_t cycles, double duty = kOmitted, double freq_hz = kOmitted,
                         double stroke_m = kOmitted);
  // Ends motion at the next chunk end (see above). No effect when idle.
  void stop();
  // Leaves FAULT for IDLE (the output is already at zero); re-reads the position.
  void reset_fault();
  Refusal set_soft_limits(double lower_m, double upper_m);
  // After a rebuild at rest (new settings): carry on from the previous positioner's status (the
  // target, the position read at rest, the counters), so that a reset does not show target 0.
  void continue_from(const MotionStatus& previous);

  // ---- the state machine ----
  // Advances by polling the devices; now_s on any monotonic clock (seconds). Never blocks.
  void tick(double now_s);

  const MotionStatus& status() const { return status_; }
  // The target of the last move or step command, accepted or refused (NaN when it had none, e.g.
  // a non-finite argument): what a refusal's message names.
  double requested_target_m() const { return requested_target_m_; }
  bool at_rest() const;  // IDLE or FAULT (the motor record's DMOV = 1)
  const PositionerConfig& config() const { return config_; }
  double tolerance_m() const;
  // The driver's message for MotionFault::Driver (empty otherwise). Not real-time safe to copy.
  const std::string& last_driver_error() const { return last_driver_error_; }

  // ---- for tests, tools and benchmarks ----
  const Planner& planner() const { return planner_; }
  const RegionMap& map() const { return map_; }
  // The plan made for the last chunk (its first burst is what was played, cut to a chunk).
  const Plan& last_plan() const { return plan_; }
  // One interferometer count.
  double count_m() const { return count_m_; }
  // The sample_status bits of the word behind MotionFault::InvalidSample (0 otherwise); see
  // drivers::describe_sample_status.
  std::uint8_t invalid_sample_status() const { return invalid_sample_status_; }
  // Chunks of the current/last move, and the cycles they played.
  std::uint64_t move_chunks() const { return move_chunks_; }
  std::uint64_t move_cycles() const { return move_cycles_; }

  // The step ladder: per direction, the rungs built from the map at construction (one usable
  // cell per stroke and frequency band), coarse to fine by the model's step. `estimate` is what
  // the positioner currently believes a burst of the rung moves (along the motion).
  struct RungInfo {
    std::size_t cell = 0;        // into map().cells()
    RungEstimate estimate;       // learned (offset, step), seeded from the map
    bool dead = false;           // judged not to move that way (left out for a while)
    bool proven = false;         // has moved as predicted in this session
    std::uint64_t chunks = 0;    // chunks played with it since construction
  };
  std::size_t rung_count(int direction) const { return ladder_[direction > 0 ? 1 : 0].size(); }
  RungInfo rung(int direction, std::size_t index) const;
  // Marks a rung dead for dead_rung_moves moves (for tests and tools; the loop does it itself).
  void mark_rung_dead(int direction, std::size_t index);
  // The learned step of the finest live rung toward `direction` (0: none).
  double finest_live_step_m(int direction) const;

 private:
  enum class Phase : std::uint8_t { Idle, Pending, Playing, Settling, Fault };
  struct Chunk {
    double freq_hz = 0, duty = 0, stroke_m = 0;
    std::uint32_t period_samples = 0, extension_samples = 0;
    std::uint64_t cycles = 0;
    double predicted_m = 0;               // signed, 0: not judged for a stall
    const RegionCell* cell = nullptr;     // the map cell (closed loop), for calibration
    bool completes_last_burst = false;    // ends the plan's last burst (a try at the target)
    int direction = 0;                    // +1 / -1
    int rung = -1;                        // index into the ladder of `direction`; -1 open loop
    double predicted_along_m = 0;         // the rung's estimate for the chunk (closed loop)
  };
  struct Rung {
    std::size_t cell = 0;
    int direction = 0;
    RungEstimate seed;      // the map's prediction, low confidence
    RungEstimate est;       // current
    bool dead = false;
    bool killed_in_streak = false;  // marked dead during the current run of non-moving chunks
    bool proven = false;
    std::uint64_t dead_until_move = 0;
    double pending_pred_m = 0, pending_moved_m = 0;  // small chunks awaiting a stall judgement
    std::uint64_t pending_cycles = 0;
    std::uint64_t chunks = 0;
    // The scatter of its chunks about the estimate: a running mean of the squared relative
    // error of their displacements (friction along the guide moves a fine rung's step by tens
    // of per cent), and how many chunks it holds.
    double scatter_var = 0;
    std::uint64_t scatter_chunks = 0;
  };
  // How far this rung's next chunk may move beyond its estimate, as a share of it.
  double rung_uncertainty(const Rung& r) const;
  // A final chunk of rung r for the remaining distance: the cycles that land nearest, cut so that
  // the pessimistic landing passes by at most 0.8 step (`cut`), never below the cycles predicted
  // to move half a step; `safe`: the result keeps to that.
  struct FinalChunk {
    std::uint64_t cycles = 1;
    bool cut = false, safe = false;
  };
  FinalChunk final_chunk_for(const Rung& r, double distance) const;
  void build_ladder();
  void load_rung_estimates();           // at a move's start: from the calibration, or the seeds
  bool rung_live(Rung& r);              // revives a rung whose dead time is over
  void kill_rung(Rung& r);
  bool judge_and_learn(double moved_m);  // false: a fault was entered

  void enter_fault(MotionFault fault);
  void driver_fault(const drivers::DriverStatus& status);
  bool latch_position(double& position_m);  // false: a fault was entered
  bool drain_stream();                      // false: a fault was entered
  bool start_chunk();                       // false: a fault was entered
  void after_chunk(double now_s);
  void plan_next_chunk(double now_s);
  void next_open_loop_chunk(double now_s);
  void finish(double now_s);
  std::uint64_t chunk_cycle_limit(double freq_hz, std::uint32_t period_samples,
                                  std::uint64_t max_cycles) const;
  double nominal_open_loop_step_m(double freq_hz, double duty, double stroke_m) const;

  const RegionMap& map_;
  Planner planner_;
  PositionerConfig config_;
  drivers::WaveformOutput& output_;
  drivers::Interferometer& interferometer_;
  Calibration* calibration_;
  MotionStatus status_;
  std::string last_driver_error_;

  // Sized in the constructor; never grown afterwards.
  Plan plan_;
  std::vector<double> samples_;               // one chunk at the output's clock
  std::vector<drivers::TimedWord> stream_;    // a slice of the burst stream
  drivers::PositionDecoder latch_decoder_;    // latched words (reset per reading)
  drivers::PositionDecoder stream_decoder_;   // the stream of one chunk (reset per chunk)
  double count_m_ = 0;
  bool buffered_ = true;          // write_burst (samples) or write_burst_parameters
  double sample_rate_hz_ = 0;     // the output clock for buffered bursts
  int max_chunks_ = 0;
  std::vector<Rung> ladder_[2];
  CalibrationConfig rung_cfg_;  // the calibration's (or the default) RLS settings for the rungs
  std::size_t largest_cell_[2] = {0, 0};  // [0] negative, [1] positive: largest |step|
  bool has_largest_cell_[2] = {false, false};

  std::uint8_t invalid_sample_status_ = 0;
  double requested_target_m_ = std::numeric_limits<double>::quiet_NaN();
  bool target_known_ = false;  // target_m holds a move's target or the first position read
  Phase phase_ = Phase::Idle;
  bool stop_requested_ = false;
  bool poll_due_ = true;
  double last_poll_s_ = 0;
  double move_start_s_ = 0;
  double settle_until_s_ = 0;
  bool move_started_ = false;     // move_start_s_ is set (the first tick after the command)
  Chunk chunk_;
  double chunk_start_position_m_ = 0;
  bool last_try_done_ = false;    // the chunk just played ended a try (last burst, or passed)
  int stall_count_ = 0;
  std::uint64_t move_chunks_ = 0;
  std::uint64_t move_cycles_ = 0;
  // Open loop: the whole step and what is left of it.
  Chunk open_loop_;
  std::uint64_t open_loop_remaining_ = 0;
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
