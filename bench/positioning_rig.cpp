// The positioning benchmark's rig: the realistic plant, one move run to rest and judged.
#include "bench/positioning_rig.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "model/simulation.h"

namespace idm::bench {

using control::MotionKind;
using control::MotionState;
using control::Positioner;

bool g_trace = false;

drivers::sim::SimDeviceConfig realistic_device(std::uint64_t seed) {
  drivers::sim::SimDeviceConfig c = daemon::realistic_sim_device(seed);
  c.stream_rate_hz = 1e5;
  return c;
}

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const double pos = q * static_cast<double>(v.size() - 1);
  const std::size_t i = static_cast<std::size_t>(pos);
  const double f = pos - static_cast<double>(i);
  return i + 1 < v.size() ? v[i] * (1 - f) + v[i + 1] * f : v[i];
}

MoveOutcome run_move(daemon::SimAxis& axis, double start_m, double target_m,
                     const std::function<void()>& start) {
  Positioner& p = *axis.positioner;
  drivers::sim::SimBackend& sim = *axis.sim;
  MoveOutcome r;
  const double sign = target_m >= start_m ? 1.0 : -1.0;
  const double t0 = sim.now_s();
  const std::uint64_t cycles0 = p.status().cycles, bursts0 = p.status().bursts;
  // Chunks are told apart by the positioner's burst counter; a chunk runs from the rest position
  // before the tick that started it to the rest position before the next one (or the move's end).
  double x_before_tick = sim.true_position_m();
  double chunk_x0 = x_before_tick;
  std::uint64_t chunk_cycles = 0, bursts_seen = bursts0, cycles_seen = cycles0;
  double chunk_planned_step_m = 0;
  const double count_m = p.count_m();
  auto close_chunk = [&](double x_end) {
    if (chunk_cycles == 0) return;
    const double moved = x_end - chunk_x0;
    const double dir = moved >= 0 ? 1.0 : -1.0;
    const double mean_step =
        std::max(count_m, std::fabs(moved) / static_cast<double>(chunk_cycles));
    const double step = std::max(mean_step, chunk_planned_step_m);
    const double pass = dir * (x_end - target_m);
    if (dir * (chunk_x0 - target_m) < 0 && pass > 0) {
      r.worst_pass_in_steps = std::max(r.worst_pass_in_steps, pass / step);
      if (pass > mean_step * (1 + 1e-9)) r.overshot_by_more_than_mean_step = true;
      if (pass > step * (1 + 1e-9)) {
        r.overshot_by_more_than_step = true;
        if (g_trace)
          std::printf(
              "  chunk of %llu cycles moved %.1f nm and passed the target by %.1f nm (%.2f "
              "steps)\n",
              static_cast<unsigned long long>(chunk_cycles), moved * 1e9, pass * 1e9, pass / step);
      }
    }
  };
  auto observe = [&] {
    const double x = sim.true_position_m();
    if (p.status().bursts != bursts_seen) {  // a chunk started in this tick
      close_chunk(x_before_tick);
      chunk_x0 = x_before_tick;
      chunk_cycles = p.status().cycles - cycles_seen;
      chunk_planned_step_m = p.status().closed_loop && !p.last_plan().bursts.empty()
                                 ? std::fabs(p.last_plan().bursts.front().step_m)
                                 : 0.0;
      bursts_seen = p.status().bursts;
      cycles_seen = p.status().cycles;
    }
    r.overshoot_m = std::max(r.overshoot_m, sign * (x - target_m));
    if (std::fabs(x) > kSoftLimitM) r.left_soft_limits = true;
    x_before_tick = x;
  };
  start();
  axis.tick();
  observe();
  while (!p.at_rest() && sim.now_s() - t0 < 600) {
    sim.advance_s(1e-4);
    axis.tick();
    observe();
  }
  close_chunk(sim.true_position_m());
  r.faulted = p.status().state == MotionState::Fault;
  r.fault = p.status().fault;
  r.time_s = sim.now_s() - t0;
  r.cycles = p.status().cycles - cycles0;
  r.bursts = p.status().bursts - bursts0;
  return r;
}

void finish(MoveOutcome& r, daemon::SimAxis& rig, double target_m) {
  const Positioner& p = *rig.positioner;
  const drivers::sim::SimBackend& sim = *rig.sim;
  r.within_count =
      p.status().position_valid && std::fabs(p.status().position_m - target_m) <= p.count_m();
  r.within_count_true = std::fabs(sim.true_position_m() - target_m) <= p.count_m();
  r.done_error_m = p.status().position_m - target_m;
  r.not_ok = p.status().kind == MotionKind::Move && p.status().result != control::MoveResult::Ok;
  // A moment later, as a client's POS? after *OPC?: the latest single reading at rest.
  rig.run_for(5e-3);
  r.within_count_fresh =
      p.status().position_valid && std::fabs(p.status().position_m - target_m) <= p.count_m();
  r.within_count_fresh_true = std::fabs(sim.true_position_m() - target_m) <= p.count_m();
  r.fresh_error_m = p.status().position_m - target_m;
}

}  // namespace idm::bench
