// The settings of one axis's positioner (the control: keys of the config, control/README.md):
// PositionerConfig, its table of keys with units and ranges, and the check of values set in code.
// Every part of the positioner reads them: the step ladder, the arrival, the references.
#pragma once

#include <limits>
#include <string>

#include "model/param_table.h"

namespace idm::control {

struct PositionerConfig {
  // The in-position window (MOVE:WINDow): |target - reading| that counts as arrived; 0: one
  // interferometer count (the loop then aims for half a count: the reading nearest the target).
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
  // Readings averaged for a position at rest: the landing judges their mean, and at rest the
  // position shown is the mean of the latest latch_words readings.
  int latch_words = 8;
  // Soft limits: a move whose target lies outside is refused before anything moves.
  double soft_lower_m = -std::numeric_limits<double>::infinity();
  double soft_upper_m = std::numeric_limits<double>::infinity();
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
  // under two counts, played one cycle at a time, reaches the half-count window within a few
  // tries).
  double final_step_counts = 2.0;
  // A rung whose learned step falls below this many counts per cycle is treated as not moving.
  double min_step_counts = 0.3;
  // A rung judged not to move (or to move the wrong way) is left out for this many moves, then
  // tried again from its seed.
  int dead_rung_moves = 100;
  // Time a chunk costs beyond its cycles (device settle, the positioner's settle, the reading),
  // used to weigh fewer, longer chunks against more, shorter ones.
  double chunk_overhead_s = 5e-3;
  // The speed limit (MOVE:VELocity, EPICS VELO): the approach uses only rungs whose learned step
  // times frequency is at most this; 0: no limit. The final chunks' rung (the finest that lands
  // within the window) plays whatever its speed: it is the slowest that can arrive.
  double max_speed_m_s = 0.0;
  // ---- in position, end of travel, hold (the protocol's MOVE:DWELl, EOT:, HOLD) ----
  // A move is done once fresh readings have stayed within the window (tolerance_m) of the target
  // for this long (0: the first fresh reading inside).
  double dwell_s = 0.0;
  // A move still not done after this long ends with result TIMEOUT (0: no limit).
  double move_timeout_s = 120.0;
  // End of travel: while driving, the mean step over the last eot_cycles cycles below eot_step_m
  // stops the axis (0: detection off).
  double eot_step_m = 2e-9;
  int eot_cycles = 20;
  // After a move that arrived: keep the target for hold_s (0: no hold; -1: until the next motion
  // command or STOP), correcting whenever a reading leaves hold_window_m (0: the move's window).
  double hold_s = 0.0;
  double hold_window_m = 0.0;
  // The stage's travel (stage.travel_m; not a key of control:, the daemon fills it in): a
  // collapse of the step met farther inside it than end_margin_m() from the end it drove toward
  // is an obstruction (FAULT stall), not the end of travel. Infinite: unknown (every collapse
  // after stepping that way is the end of travel).
  double travel_lower_m = -std::numeric_limits<double>::infinity();
  double travel_upper_m = std::numeric_limits<double>::infinity();
};

// The keys of PositionerConfig, and the check of values set in code (model::InputError naming the
// key and the allowed range). The soft limits are checked here as a pair (lower < upper).
const model::ParamTable<PositionerConfig>& positioner_params();
void validate(const PositionerConfig& config, const std::string& where = "control");

}  // namespace idm::control
