// The closed-loop positioner of one axis: burst -> read the interferometer -> correct, until the
// slider is within tolerance of the target (default: one interferometer count). Pure: it never
// calls a driver. The device link (drivers/link.h) feeds it position readings and segment events
// (on_event), and tick() hands out what the output must do (a segment to play, a stop, a request
// for fresh readings) as a model::OutputRequest. tick(), on_event() and every command below never
// block, allocate, lock or log (buffers are sized at construction).
//
// CONTRACT (shared with daemon/): the names and meanings in this header are what the daemon codes
// against. Extend it; do not change what is here without changing the daemon with it.
//
//   IDLE      at rest, nothing commanded (after a move that reached its target, a stop, or start)
//   MOVING    a burst (or a chunk of one) is requested or playing
//   SETTLING  the output is at rest; waiting settle_s, then for fresh readings
//   FAULT     something is wrong; the output has been told to stop (zero). Commands other than
//             stop/reset_fault are refused until reset_fault().
//
// Stop at any time: a burst is played in chunks of whole cycles no longer than max_chunk_s, each
// ending with the actuator at 0 and the slider at rest; stop() lets the playing chunk end (never
// a step cut short, never a fast edge) and plays nothing after it. A fault stops the output at
// once (an OutputRequest::Stop).
#pragma once

#include <cstddef>
#include <cstdint>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "control/calibration.h"
#include "control/motion_gate.h"
#include "control/planner.h"
#include "control/positioner_config.h"
#include "control/region_map.h"
#include "control/rest_mean.h"
#include "control/step_ladder.h"
#include "model/axis_io.h"
#include "model/param_table.h"

namespace idm::control {

enum class MotionState : std::uint8_t { Idle, Moving, Settling, Fault };
const char* motion_state_name(MotionState state);  // "IDLE", "MOVING", "SETTLING", "FAULT"

enum class MotionFault : std::uint8_t {
  None,
  InvalidSample,   // an interferometer word with an error bit, a glitch or lost continuity
  Stall,           // stall_bursts bursts in a row without progress
  RetryLimit,      // still outside tolerance after max_retries corrections
  Driver,          // a driver call failed (the driver's message is in last_driver_error())
  NoPlan,          // no usable cell moves toward the target (map empty for that direction)
  CaptureOverrun,  // the interferometer's capture filled before it was read (a chunk too long for
                   // it)
  DeviceLost,      // the device stopped answering (the link reconnects by itself)
  // The window cannot be met: the live rungs' finest placement (their steps, verniers and learned
  // scatter) is less likely than not to land within it in max_retries + 1 tries
  // (landing_plan.h, landing_reach). Said at the first landing try, never after the hunting;
  // MotionStatus::least_window_m is the narrowest window that can be met.
  WindowUnreachable,
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
  NotReferenced,      // an absolute move on an axis that must be referenced first (the daemon's)
  EndOfTravel,        // a motion further into the end of travel the axis stopped at
  Reloading,          // a reload waits for the motions in progress to end (the daemon's)
};

// Why the last motion ended (MOVE:RESult?).
enum class MoveResult : std::uint8_t {
  None,     // no motion yet
  Ok,       // a move: in its window for the dwell; a STEP: every cycle played; a reference: found
  Stopped,  // STOP (or a new command) ended it
  Limit,    // a reading left the soft limits
  EndOfTravel,  // the mean step collapsed while driving (eot_step_m over eot_cycles)
  Fault,        // it ended in a fault (MotionStatus::fault)
  Timeout,      // not done within move_timeout_s
};
const char* move_result_name(MoveResult result);  // "NONE", "OK", "STOPPED", ...

// What the last motion was.
enum class MotionKind : std::uint8_t { None, Move, Step, Reference };
const char* refusal_name(Refusal refusal);  // "none", "not_finite", ...

// A plain snapshot (trivially copyable) for the daemon to publish through a latest-value buffer.
struct MotionStatus {
  MotionState state = MotionState::Idle;
  MotionFault fault = MotionFault::None;
  bool position_valid = false;
  double position_m =
      0.0;  // at rest: the mean of the latest latch_words readings; moving: the latest
  double target_m = 0.0;               // of the current or last move
  bool closed_loop = false;            // the current/last motion is a move (not an open-loop STEP)
  std::uint64_t moves = 0;             // moves started since construction
  std::uint64_t bursts = 0;            // chunks played since construction
  std::uint64_t cycles = 0;            // cycles played since construction
  std::uint32_t corrections = 0;       // correction rounds of the current/last move
  double last_move_time_s = 0.0;       // time the last finished move took
  MotionKind kind = MotionKind::None;  // the current/last motion
  MoveResult result = MoveResult::None;  // why the last motion ended (None while one runs)
  double result_distance_m = 0.0;        // target - position when it ended
  // Motions that ended (a result set: a move, STEP or reference, or a hold's correction that did
  // not arrive) since construction, carried across rebuilds: the daemon logs each that ended
  // other than OK or STOPPED, once.
  std::uint64_t motions_ended = 0;
  int eot = 0;                   // -1 / +1: stopped at the end of travel that way; 0: not
  double eot_position_m = 0.0;   // where it met it (motion beyond is refused)
  std::uint8_t moved_dirs = 0;   // bit 0 negative, bit 1 positive: the slider has stepped that way
  bool holding = false;          // keeping the last move's target (HOLD)
  bool in_window = false;        // at rest within the window of the target
  std::uint64_t references = 0;  // references found since construction
  double window_m = 0.0;         // the move window in force (MOVE:WINDow)
  // When the last motion ended in FAULT window_unreachable: the narrowest window the axis is
  // expected to meet (MOVE:WINDow); 0 otherwise.
  double least_window_m = 0.0;
  double offset_m = 0.0;  // readings are the device's plus this (set by a reference)
};

// What the positioner knows of its device: plain numbers the daemon takes from the drivers'
// capabilities (drivers/interfaces.h), so that control needs no driver.
struct AxisDeviceInfo {
  double count_m = 9.8906e-9;     // one interferometer count
  double max_velocity_m_s = 0.1;  // the position decoder's limit (faster reads as a glitch)
  double stream_rate_hz = 1e5;    // the capture's sample rate during a burst
  std::size_t stream_capacity = 1u << 20;    // records the capture holds for one burst
  bool buffered = true;                      // the output takes samples (else burst parameters)
  std::size_t max_burst_samples = 1u << 20;  // buffered: the longest burst
  std::uint32_t max_cycles = 1000000;        // parameters: most cycles in one burst
};

class Positioner {
 public:
  // The map and the (optional) calibration must outlive the positioner. Throws
  // model::InputError on a bad config, or a device that cannot carry out the map (a chunk that
  // overruns its capture, a decoder slower than the map's fastest slider).
  Positioner(const RegionMap& map, const PlannerConfig& planner, const PositionerConfig& config,
             const AxisDeviceInfo& device, Calibration* calibration = nullptr);
  // The step ladder reads this positioner's settings in place: not copied.
  Positioner(const Positioner&) = delete;
  Positioner& operator=(const Positioner&) = delete;
  Positioner(Positioner&&) = delete;
  Positioner& operator=(Positioner&&) = delete;
  ~Positioner() = default;

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
  // The motion gate for a burst the positioner does not play itself (a sweep's trial) starting at
  // from_m: None, OutsideSoftLimits (its worst-case excursion, control/motion_gate.h, could leave
  // the soft limits), EndOfTravel (it could reach the end of travel met before), NoPosition.
  Refusal check_burst(const model::Segment& segment, double from_m) const;
  // Ends motion at the next chunk end (see above). No effect when idle.
  void stop();
  // Leaves FAULT for IDLE (the output is already at zero); re-reads the position.
  void reset_fault();
  Refusal set_soft_limits(double lower_m, double upper_m);
  // Settings for the motions that follow (checked by the caller; NaN/negative where not allowed
  // is refused with OutOfRange). window_m 0: half a count.
  Refusal set_window(double window_m);
  // Sets keys of the config (PositionerConfig's table names) all or none, each checked by the
  // table's range: OutOfRange / NotFinite otherwise.
  Refusal set_settings(const std::vector<std::pair<const char*, double>>& values);
  Refusal set_dwell(double dwell_s);
  Refusal set_eot(double step_m, int cycles);
  Refusal set_hold(double hold_s, double window_m);
  // Finds the end stop toward `direction` (+1/-1) open loop at the largest step, then sets the
  // position there to position_at_stop_m. Soft limits do not apply to it.
  Refusal reference(int direction, double position_at_stop_m);
  // Finds the reference mark (the interferometer's words report crossing it: AxisEvent::mark):
  // drives open loop at the largest step toward `direction` (+1/-1); at an end stop before the
  // mark it reverses once. The mark's reading sets the offset so that the mark reads
  // position_at_mark_m; a closed-loop move backs off before the mark, a slow open-loop crawl
  // crosses it again (its reading sets the offset once more, to about a count), and a closed-loop
  // move brings the slider onto the mark. Ends OK and counted in status().references once there;
  // a second end stop without the mark ends with END_OF_TRAVEL, the cycles running out (of the
  // search or the crawl) with TIMEOUT (not referenced either way).
  Refusal reference_mark(int direction, double position_at_mark_m);
  // Ends a hold (any motion command does).
  void end_hold();
  // After a rebuild at rest: keep holding the target until `until_s` (the previous positioner's
  // hold_until_s(); +inf: until the next motion command), as the hold before the rebuild did.
  void resume_hold(double until_s);
  double hold_until_s() const { return hold_until_s_; }
  // After a rebuild at rest (new settings): carry on from the previous positioner's status (the
  // target, the position read at rest, the counters), so that a reset does not show target 0.
  void continue_from(const MotionStatus& previous);

  // ---- the state machine ----
  // Everything the device link reports for this axis, in order.
  void on_event(const model::AxisEvent& event);
  // Advances to now_s (the link's clock). Returns true with `request` filled when the output must
  // be told something (push it to the link); at most one per tick. Never blocks.
  bool tick(double now_s, model::OutputRequest& request);

  const MotionStatus& status() const { return status_; }
  // The target of the last move or step command, accepted or refused (NaN when it had none, e.g.
  // a non-finite argument): what a refusal's message names.
  double requested_target_m() const { return requested_target_m_; }
  bool at_rest() const;  // IDLE or FAULT (the motor record's DMOV = 1)
  // At rest, or holding (a hold's corrections do not make a move undone).
  bool done() const { return at_rest() || status_.holding; }
  const PositionerConfig& config() const { return config_; }
  double tolerance_m() const;  // the in-position window
  double landing_m() const;    // what a move aims for inside it
  // The window (MOVE:WINDow) whose landing_m() is landing_m.
  double window_for_landing_m(double landing_m) const;
  // How far inside the travel's end a stop may lie and still be that end: five actuator strokes
  // (stage.stroke_m; no cycle moves the slider farther than one), so a stop a few cycles' travel
  // before the end stage.travel_m gives is the end; one farther inside is an obstruction.
  double end_margin_m() const;

  // ---- for tests, tools and benchmarks ----
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
    std::size_t cell = 0;      // into map().cells()
    RungEstimate estimate;     // learned (offset, step), seeded from the map
    bool dead = false;         // judged not to move that way (left out for a while)
    bool proven = false;       // has moved as predicted in this session
    std::uint64_t chunks = 0;  // chunks played with it since construction
  };
  std::size_t rung_count(int direction) const { return ladder_.size(direction); }
  RungInfo rung(int direction, std::size_t index) const;
  // Marks a rung dead for dead_rung_moves moves (for tests and tools; the loop does it itself).
  void mark_rung_dead(int direction, std::size_t index);
  // The learned step of the finest live rung toward `direction` (0: none).
  double finest_live_step_m(int direction) const { return ladder_.finest_live_step_m(direction); }

 private:
  // Index of a direction in the per-direction arrays: [0] negative, [1] positive.
  static int direction_index(int sign) { return sign > 0 ? 1 : 0; }
  enum class Phase : std::uint8_t { Idle, Pending, Playing, Settling, Fault, Dwell };
  // Fresh readings: the average of latch_words valid readings taken at or after fresh_after_s_,
  // more when their mean says arrived but is not known well enough (fresh_position).
  struct Fresh {
    double after_s = 0;
    int count = 0;
    int wanted = 0;  // readings to average (latch_words, doubled while unsure)
    double sum_m = 0;
    double sum_sq_m = 0;  // of (reading - the first reading), for their scatter
    double first_m = 0;
    bool requested = false;  // a Read request went out for them
    double worst_m = 0;      // the largest |target - reading| among them
  };
  // A mean that says arrived is taken once the window's edge lies this many of its standard
  // errors beyond it (a slider outside the window read inside: once in 30,000 landings), or
  // once kMaxFreshFactor x latch_words readings are in.
  static constexpr double kArrivalStandardErrors = 4.0;
  static constexpr int kMaxFreshFactor = 16;
  // The readings' scatter at rest pooled over the batches (weights: their degrees of freedom,
  // the older forgotten by this factor a batch, so a noisier stretch is seen within a few).
  static constexpr double kReadingVarForgetting = 0.95;
  struct Chunk {
    double freq_hz = 0, duty = 0, stroke_m = 0;
    std::uint32_t period_samples = 0, extension_samples = 0;
    std::uint64_t cycles = 0;
    double predicted_m = 0;             // signed, 0: not judged for a stall
    const RegionCell* cell = nullptr;   // the map cell (closed loop), for calibration
    bool completes_last_burst = false;  // ends the plan's last burst (a try at the target)
    int direction = 0;                  // +1 / -1
    int rung = -1;                      // index into the ladder of `direction`; -1 open loop
    double predicted_along_m = 0;       // the rung's estimate for the chunk (closed loop)
  };
  // A chunk that plays the map cell's wave (the rest of it unset).
  static Chunk cell_chunk(const RegionCell& cell) {
    Chunk c;
    c.freq_hz = cell.freq_hz;
    c.duty = cell.duty;
    c.stroke_m = cell.stroke_m;
    c.period_samples = cell.period_samples;
    c.extension_samples = cell.extension_samples;
    return c;
  }
  void enter_fault(MotionFault fault);
  void on_reading(const model::AxisEvent& e);
  void want_fresh(double after_s);          // start collecting fresh readings
  bool fresh_position(double& position_m);  // true once they are in (position_m: their mean)
  void start_chunk();                       // the request for chunk_
  void after_chunk(double now_s, double position_m);
  // The next chunk of a closed-loop motion: arrived, a try counted, or the ladder's choice.
  void plan_next_chunk(double now_s);
  // The chunk of the ladder's choice (its planned cycles cut to a chunk), and its request.
  void play(const StepLadder::Choice& choice, double error);
  // After a closed-loop chunk: the ladder judges its rung; a run of chunks that did not move is
  // a stall or the end of travel (false: a fault or the end of travel was entered).
  bool judge_chunk(double moved_m);
  void next_open_loop_chunk(double now_s);
  // The references: the open-loop drive toward `sign` (false: no cell moves that way), the start
  // of both kinds, and the mark search's steps (the mark found; an end stop met while searching).
  bool reference_drive(int sign);
  Refusal start_reference(int direction, double position_m, bool mark);
  void mark_found(double now_s);
  void mark_search_end_stop(double now_s, int sign);
  // The most the slider moves between two stream samples in a chunk (its predicted_m per cycle
  // set); the open-loop chunk of the crawl across the mark toward `sign` (false: no cell).
  double sample_travel_m(const Chunk& c) const;
  bool crawl_chunk(int sign, Chunk& out);
  void start_crawl(double now_s);
  void crawl_failed(double now_s);                // back onto the mark as the search found it
  void move_onto(double now_s, double target_m);  // a closed-loop move within the reference
  void finish(double now_s, MoveResult result);
  void arrived(double now_s);
  bool end_of_travel_seen(double moved_m);  // after a chunk: the mean step collapsed
  // The collapse, met driving toward `sign`: the end of travel (the reference's stop, the mark
  // search's), or a stall fault when it lies farther inside the travel than end_margin_m().
  void end_of_travel(double now_s, int sign);
  void start_motion(MotionKind kind);
  // A new motion, or a new leg of the mark search: the stall, streak, chunk and end-of-travel
  // counts start afresh.
  void reset_progress();
  void hold_tick(double now_s);
  void dwell_tick(double now_s);
  bool toward_eot(double end_m) const;
  double nominal_open_loop_step_m(double freq_hz, double duty, double stroke_m) const;

  const RegionMap& map_;
  PlannerConfig planner_;
  PositionerConfig config_;
  AxisDeviceInfo device_;
  Calibration* calibration_;
  MotionStatus status_;

  // Sized in the constructor; never grown afterwards.
  Plan plan_;
  double count_m_ = 0;
  bool buffered_ = true;               // clocked segments (samples) or burst parameters
  double sample_rate_hz_ = 0;          // the output clock for buffered bursts
  std::size_t max_chunk_samples_ = 0;  // buffered: the longest chunk the output takes
  // The link: what tick() has to say, the segment in flight, fresh readings.
  bool request_due_ = false;
  model::OutputRequest request_;
  std::uint32_t seq_ = 0;  // of the last segment requested
  Fresh fresh_;
  double reading_var_m2_ = 0, reading_var_weight_ = 0;  // the pooled scatter (fresh_position)
  double now_s_ = 0;                                    // the last tick's time
  bool device_lost_ = false;                            // between DeviceLost and DeviceBack
  bool lost_at_rest_ = false;                           // the loss came with nothing moving
  int max_chunks_ = 0;
  ChunkLimits chunk_limits_;              // what the device lets one chunk be
  StepLadder ladder_;                     // what to play next toward a target (reads config_)
  std::size_t largest_cell_[2] = {0, 0};  // [0] negative, [1] positive: largest |step|
  double largest_step_m_[2] = {0, 0};     // their |step|
  bool has_largest_cell_[2] = {false, false};

  std::uint8_t invalid_sample_status_ = 0;
  double requested_target_m_ = std::numeric_limits<double>::quiet_NaN();
  bool target_known_ = false;  // target_m holds a move's target or the first position read
  Phase phase_ = Phase::Idle;
  bool stop_requested_ = false;
  double move_start_s_ = 0;
  double settle_until_s_ = 0;
  bool move_started_ = false;  // move_start_s_ is set (the first tick after the command)
  Chunk chunk_;
  double chunk_start_position_m_ = 0;
  bool last_try_done_ = false;  // the chunk just played ended a try (last burst, or passed)
  int stall_count_ = 0;
  std::uint64_t move_chunks_ = 0;
  std::uint64_t move_cycles_ = 0;
  // Open loop: the whole step and what is left of it.
  Chunk open_loop_;
  std::uint64_t open_loop_remaining_ = 0;
  // Readings are reported as the device's plus this (set by a reference).
  double offset_m_ = 0;
  // End of travel: the last chunks that were expected to move (cycles, displacement along).
  struct EotChunk {
    std::uint64_t cycles = 0;
    double along_m = 0;
  };
  static constexpr int kEotChunks = 16;
  EotChunk eot_chunks_[kEotChunks];
  int eot_count_ = 0, eot_next_ = 0;
  bool referencing_ = false;
  double reference_position_m_ = 0;
  // The mark search (reference_mark): driving until a reading carries the mark, then the
  // closed-loop move back onto it.
  // Searching (fast, open loop) -> Approaching (closed loop to a point before the mark) ->
  // Crawling (slow, open loop across it) -> Returning (closed loop onto it).
  enum class MarkSearch : std::uint8_t { Off, Searching, Approaching, Crawling, Returning };
  MarkSearch mark_search_ = MarkSearch::Off;
  bool mark_seen_ = false;      // a reading with the mark came in while searching or crawling
  bool mark_reversed_ = false;  // the search met an end stop and drives the other way
  double mark_reading_m_ = 0;   // that reading (with the offset then in force)
  Chunk crawl_;                 // the crawl's cell, and the cycles it may take
  std::uint64_t crawl_cycles_ = 0;
  int crawl_rung_ = -1;  // the crawl cell's rung (left out when it fails)
  int crawl_tries_ = 0;  // crawls that failed
  static constexpr int kCrawlTries = 4;
  double crawl_start_m_ = 0;  // the point before the mark each crawl starts from
  double dwell_until_s_ = 0;
  bool hold_armed_ = false;       // holding: at rest, watching the readings
  bool arrived_ = false;          // the last move arrived: in_window follows the readings at rest
  double motion_start_m_ = 0;     // where the current motion started (the gate lets it come back)
  double hold_until_s_ = 0;       // +inf: until the next command
  bool hold_correcting_ = false;  // a correction of a hold is playing
  double chunk_lo_m_ = 0, chunk_hi_m_ = 0;  // the readings' extent during the chunk
  RestMean rest_mean_;                      // the position shown at rest
  double hold_sum_m_ = 0;
  int hold_n_ = 0;
  bool hold_correction_due_ = false;
  MoveResult stop_result_ = MoveResult::Stopped;  // what a requested stop ends as
  std::uint64_t streak_cycles_ = 0;  // the chunks of the current run of non-moving chunks
  double streak_along_m_ = 0;
  int dwell_failures_ = 0;  // dwells of this move that saw a reading outside the window
};

}  // namespace idm::control
