// The positioning benchmark's rig: the realistic plant, one move run to rest and judged.
#include "bench/positioning_rig.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "model/impulse_model.h"
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
  std::string chunk_text;
  auto close_chunk = [&](double x_end) {
    if (chunk_cycles == 0) return;
    const double moved = x_end - chunk_x0;
    if (g_trace) {
      char line[96];
      std::snprintf(line, sizeof line, " moved %+9.2f nm, error after %+8.2f nm", moved * 1e9,
                    (x_end - target_m) * 1e9);
      r.chunk_log.push_back(chunk_text + line);
    }
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
      if (g_trace && !p.last_plan().bursts.empty()) {
        const control::Burst& b = p.last_plan().bursts.front();
        char line[160];
        std::snprintf(
            line, sizeof line,
            "    %5.0f Hz d %.3f S %6.3f um x %5llu of %5llu (step %7.2f nm, predicted "
            "%+9.2f nm)",
            b.freq_hz, b.duty, b.stroke_m * 1e6, static_cast<unsigned long long>(chunk_cycles),
            static_cast<unsigned long long>(b.cycles), b.step_m * 1e9, b.displacement_m * 1e9);
        chunk_text = line;
      }
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

StepMeasurement measure_steps(const drivers::sim::SimDeviceConfig& device, double stroke_m) {
  drivers::Device dev = drivers::sim::make_sim_device(device);
  drivers::sim::SimBackend& sim = *dev.sim;
  dev.configure();
  dev.activate();
  StepMeasurement m;
  for (double duty : {0.9, 0.1}) {
    const double before = sim.true_position_m();
    const model::TriangleWave wave{200, duty, stroke_m, 200};
    std::vector<double> xi;
    model::sample(wave, 1e5, 0.0, 100001, xi);
    xi.back() = 0;
    dev.output->write_burst(xi.data(), xi.size(), 1e5);
    dev.output->start();
    sim.advance_s(0.01);
    (duty > 0.5 ? m.positive_m : m.negative_m) = std::fabs(sim.true_position_m() - before) / 200;
  }
  dev.shutdown();
  return m;
}

MoveOutcome run_closed_loop_move(daemon::SimAxis& rig, double target_m) {
  Positioner& p = *rig.positioner;
  if (p.status().state == MotionState::Fault) {
    p.reset_fault();
    rig.tick();
  }
  const double start = rig.sim->true_position_m();
  MoveOutcome r = run_move(rig, start, target_m, [&] { p.move_absolute(target_m); });
  r.corrections = p.status().corrections;
  r.step_m = std::max(p.count_m(), std::fabs(p.last_plan().final_step_m));
  if (!r.faulted) r.time_s = p.status().last_move_time_s;
  finish(r, rig, target_m);
  return r;
}

void print_ladder(const Positioner& p, const control::RegionMap& map) {
  for (int dir : {-1, 1}) {
    for (std::size_t i = 0; i < p.rung_count(dir); ++i) {
      const Positioner::RungInfo r = p.rung(dir, i);
      const control::RegionCell& c = map.cells()[r.cell];
      std::printf(
          "rung %+d %2zu  %6.0f Hz d %.3f S %6.3f um  model %8.2f nm  learned %8.2f nm + %8.2f  "
          "%s%s chunks %llu\n",
          dir, i, c.freq_hz, c.duty, c.stroke_m * 1e6, std::fabs(c.step_m) * 1e9,
          r.estimate.step_m * 1e9, r.estimate.offset_m * 1e9, r.dead ? "DEAD " : "",
          r.proven ? "proven" : "", static_cast<unsigned long long>(r.chunks));
    }
  }
}

}  // namespace idm::bench
