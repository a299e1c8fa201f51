// The positioning benchmark's rig (README.md here): the realistic simulated stage, one move run
// to rest and judged, and the two peers that ours is compared with.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "control/positioner.h"
#include "control/region_map.h"
#include "daemon/sim_axis.h"
#include "drivers/sim/sim_backend.h"

namespace idm::bench {

constexpr double kSoftLimitM = 8e-3;
extern bool g_trace;  // --trace: one line per move of ours, and the ladder at the end

// The plant: daemon::realistic_sim_device (mass-damper-spring actuator, amplifier 3 kHz, Stribeck
// friction, friction varying along the guide, 2 nm rms noise), its stream at 100 kHz.
drivers::sim::SimDeviceConfig realistic_device(std::uint64_t seed);

struct MoveOutcome {
  bool within_count = false;       // by the interferometer reading
  bool within_count_true = false;  // by the simulated true position
  bool within_count_fresh =
      false;  // by a fresh reading 5 ms after done (what POS? after *OPC? sees)
  bool within_count_fresh_true = false;  // by the true position then
  double done_error_m = 0;               // the reading the move ended on - the target
  double fresh_error_m = 0;              // the fresh reading - the target
  bool not_ok = false;                   // ours: MOVE:RESult? other than OK
  bool faulted = false;
  double time_s = 0;
  std::uint64_t cycles = 0;
  std::uint64_t bursts = 0;
  std::uint32_t corrections = 0;
  double overshoot_m = 0;  // furthest past the target along the move, at rest after a burst
  double step_m = 0;  // the step size the side works with (ours: the final rung's learned step)
  // A chunk that started short of the target and ended past it by more than one of its own steps:
  // the planner committed more than one cycle past the target. Its step: the larger of its
  // displacement / its cycles and the steady step it was planned with (a burst whose first cycle
  // does not move, offset about -step, moves less than a step per cycle on average), at least
  // one count. The strict count (displacement / cycles alone) is kept beside it.
  bool overshot_by_more_than_step = false;
  bool overshot_by_more_than_mean_step = false;
  double worst_pass_in_steps = 0;  // the largest pass past the target, in steps of the chunk
  control::MotionFault fault = control::MotionFault::None;
  bool left_soft_limits = false;
  std::vector<std::string> chunk_log;  // --trace: one line per chunk (its burst, what it moved)
};

struct Summary {
  std::vector<MoveOutcome> moves;
  double wall_s = 0;
};

double percentile(std::vector<double> v, double q);

// Runs one move to rest, tracking the true position after every tick (overshoot, soft limits).
MoveOutcome run_move(daemon::SimAxis& axis, double start_m, double target_m,
                     const std::function<void()>& start);
// Judges a move at rest by the reading and the true position, then a fresh reading 5 ms later.
void finish(MoveOutcome& r, daemon::SimAxis& rig, double target_m);

// The operator's one measurement of a stage: the mean step per cycle of a 200-cycle burst each way
// at 200 Hz, duty 0.9 / 0.1 and `stroke_m`, on a fresh device of `device`.
struct StepMeasurement {
  double positive_m = 0, negative_m = 0;
};
StepMeasurement measure_steps(const drivers::sim::SimDeviceConfig& device, double stroke_m);

// Ours: one MOVE:ABS of the rig's positioner (a FAULT left by the move before reset first), run
// to rest and judged.
MoveOutcome run_closed_loop_move(daemon::SimAxis& rig, double target_m);

// --trace: the positioner's step ladder each way (cell, the model's and the learned step).
void print_ladder(const control::Positioner& p, const control::RegionMap& map);

// The peers (positioning_peers.cpp): the motor record's fixed steps with retries, and a
// vendor-style loop that lowers the amplitude as the error falls.
// `device`: the stage they drive (the same plant and seed as ours); the full stroke is the map's.
Summary run_baseline(const std::vector<double>& targets,
                     const drivers::sim::SimDeviceConfig& device, const control::RegionMap& map);
Summary run_vendor(const std::vector<double>& targets, const drivers::sim::SimDeviceConfig& device,
                   const control::RegionMap& map);

}  // namespace idm::bench
