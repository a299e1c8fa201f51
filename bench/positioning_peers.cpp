// The positioning benchmark's peers: open-loop steps of one cell, judged by the reading.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <memory>

#include "bench/positioning_rig.h"

namespace idm::bench {

using control::Positioner;
using control::PositionerConfig;
using control::RegionMap;

namespace {

// A peer's rig: whole bursts (max_chunk_s 10: 2,000 cycles at most, the sim's 2^20 samples), and a
// capture that holds a whole 10 s burst.
std::unique_ptr<daemon::SimAxis> peer_rig(drivers::sim::SimDeviceConfig device,
                                          const RegionMap& map) {
  PositionerConfig pc;
  pc.max_chunk_s = 10.0;
  device.stream_capacity = std::size_t{1} << 21;
  return std::make_unique<daemon::SimAxis>(map, device, pc);
}

// The step per cycle of a 200-cycle burst `dir` (+1 / -1) of the cell, as an operator measures it
// once (the motor record's MRES).
double measured_step_m(daemon::SimAxis& rig, int dir, double freq_hz, double duty,
                       double stroke_m) {
  Positioner& p = *rig.positioner;
  const double before = p.status().position_m;
  p.step_open_loop(dir * 200, duty, freq_hz, stroke_m);
  rig.run();
  return std::fabs(p.status().position_m - before) / 200;
}

// One burst of a peer's move: its passes and faults join the move's outcome.
void play_part(daemon::SimAxis& rig, double start_m, double target_m, MoveOutcome& r,
               const std::function<void()>& start) {
  Positioner& p = *rig.positioner;
  const MoveOutcome part = run_move(rig, start_m, target_m, start);
  r.overshoot_m = std::max(r.overshoot_m, part.overshoot_m);
  r.overshot_by_more_than_step = r.overshot_by_more_than_step || part.overshot_by_more_than_step;
  r.overshot_by_more_than_mean_step =
      r.overshot_by_more_than_mean_step || part.overshot_by_more_than_mean_step;
  r.worst_pass_in_steps = std::max(r.worst_pass_in_steps, part.worst_pass_in_steps);
  r.left_soft_limits = r.left_soft_limits || part.left_soft_limits;
  if (part.faulted) {
    r.faulted = true;
    p.reset_fault();
    rig.tick();
  }
}

// Every target in turn: `approach(target, start, outcome)` plays the peer's bursts; the time,
// cycles and bursts are counted around it and the move judged at rest.
Summary run_peer(daemon::SimAxis& rig, const std::vector<double>& targets, double step_m,
                 const std::function<void(double, double, MoveOutcome&)>& approach) {
  Summary s;
  Positioner& p = *rig.positioner;
  const auto w0 = std::chrono::steady_clock::now();
  for (double target : targets) {
    const double start = rig.sim->true_position_m();
    MoveOutcome r = run_move(rig, start, target, [] {});
    const double t0 = rig.sim->now_s();
    const std::uint64_t cycles0 = p.status().cycles, bursts0 = p.status().bursts;
    r.corrections = 0;  // the peer's own retries
    approach(target, start, r);
    r.time_s = rig.sim->now_s() - t0;
    r.cycles = p.status().cycles - cycles0;
    r.bursts = p.status().bursts - bursts0;
    r.step_m = step_m;
    finish(r, rig, target);
    s.moves.push_back(r);
  }
  s.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - w0).count();
  return s;
}

}  // namespace

// The baseline: fixed steps of (200 Hz, duty 0.1 / 0.9, full stroke) whose size the operator
// measured once (a 200-cycle burst each way, as one sets the motor record's MRES); a move asks
// for round(error / step) steps, reads the encoder and retries while outside the deadband (one
// count), up to 10 retries; it gives up when the error rounds to zero steps.
Summary run_baseline(const std::vector<double>& targets,
                     const drivers::sim::SimDeviceConfig& device, const RegionMap& map) {
  const std::unique_ptr<daemon::SimAxis> rig = peer_rig(device, map);
  Positioner& p = *rig->positioner;
  const double freq = 200, duty_positive = 0.9, stroke = map.config().limits.max_stroke_m;
  double step_m[2] = {0, 0};  // [0] negative, [1] positive, measured
  for (int dir : {1, -1})
    step_m[dir > 0 ? 1 : 0] = measured_step_m(*rig, dir, freq, duty_positive, stroke);
  const auto approach = [&](double target, double start, MoveOutcome& r) {
    for (int attempt = 0; attempt <= 10; ++attempt) {
      const double error = target - p.status().position_m;
      if (std::fabs(error) <= p.count_m()) break;
      const int dir = error > 0 ? 1 : -1;
      const double n = std::round(std::fabs(error) / step_m[dir > 0 ? 1 : 0]);
      if (n < 1) break;  // the error rounds to no step: the motor record stops here
      if (attempt > 0) ++r.corrections;
      for (double left = n; left > 0;) {
        const double burst = std::min(left, 2000.0);
        left -= burst;
        play_part(*rig, start, target, r, [&] {
          p.step_open_loop(static_cast<std::int64_t>(dir * burst), duty_positive, freq, stroke);
        });
      }
    }
  };
  const Summary s = run_peer(*rig, targets, std::max(step_m[0], step_m[1]), approach);
  std::printf("baseline steps measured: +%.4g um, -%.4g um per cycle\n", step_m[1] * 1e6,
              step_m[0] * 1e6);
  return s;
}

// A vendor-style closed loop: the same cell (200 Hz, duty 0.1 / 0.9), full amplitude while the
// error is more than two full steps (bursts of floor(error / step) - 1 cycles), then one cycle
// at a time with the amplitude lowered as the error falls: stroke = S_cut + error / slope, from
// the step measured at full and at half stroke (the step is linear in the stroke above the
// cut-off stroke S_cut, eq 22). Done within one count; at most 200 cycles of fine approach.
Summary run_vendor(const std::vector<double>& targets, const drivers::sim::SimDeviceConfig& device,
                   const RegionMap& map) {
  const std::unique_ptr<daemon::SimAxis> rig = peer_rig(device, map);
  Positioner& p = *rig->positioner;
  const double freq = 200, duty_positive = 0.9, full = map.config().limits.max_stroke_m;
  const double min_stroke = map.config().limits.min_stroke_m;
  double step_full[2] = {0, 0}, step_half[2] = {0, 0};
  for (int dir : {1, -1}) {
    step_full[dir > 0 ? 1 : 0] = measured_step_m(*rig, dir, freq, duty_positive, full);
    step_half[dir > 0 ? 1 : 0] = measured_step_m(*rig, dir, freq, duty_positive, 0.5 * full);
  }
  const auto approach = [&](double target, double start, MoveOutcome& r) {
    for (int fine = 0; fine < 200;) {
      const double error = target - p.status().position_m;
      if (std::fabs(error) <= p.count_m()) break;
      const int dir = error > 0 ? 1 : -1;
      const int d = dir > 0 ? 1 : 0;
      const double slope = (step_full[d] - step_half[d]) / (0.5 * full);
      const double s_cut = std::max(min_stroke, full - step_full[d] / std::max(slope, 1e-12));
      double stroke = full;
      std::int64_t n = 1;
      if (std::fabs(error) > 2 * step_full[d]) {
        n = static_cast<std::int64_t>(
            std::min(2000.0, std::floor(std::fabs(error) / step_full[d]) - 1));
      } else {
        stroke = std::clamp(s_cut + std::fabs(error) / std::max(slope, 1e-12), min_stroke, full);
        ++fine;
      }
      play_part(*rig, start, target, r,
                [&] { p.step_open_loop(dir * n, duty_positive, freq, stroke); });
    }
  };
  const Summary s = run_peer(*rig, targets, std::max(step_full[0], step_full[1]), approach);
  std::printf(
      "vendor steps measured: full stroke +%.4g / -%.4g um, half stroke +%.4g / -%.4g um per "
      "cycle\n",
      step_full[1] * 1e6, step_full[0] * 1e6, step_half[1] * 1e6, step_half[0] * 1e6);
  return s;
}

}  // namespace idm::bench
