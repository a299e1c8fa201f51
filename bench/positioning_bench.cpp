// Positioning benchmark: the closed-loop positioner (region map, planner, online calibration) on
// the simulated stage with a realistic plant, side by side in the same run with a baseline of
// fixed steps (duty 0.1, 200 Hz, full stroke) and motor-record-style retries (deadband one count,
// up to 10 retries), over the same seeded random moves.
//
// Plant: mass-damper-spring actuator (K 5.7e6 N/m, C 230 N s/m), amplifier 3 kHz, Stribeck
// friction (static/kinetic 1.15), friction varying along the guide (relative sd 0.05: +/-10 % at
// two sd), interferometer lambda/64 with 2 nm rms noise; 100 kHz output and stream.
//
//   positioning_bench [--quick] [--moves N] [--seed S]
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "control/calibration.h"
#include "control/positioner.h"
#include "daemon/sim_axis.h"
#include "drivers/sim/sim_backend.h"
#include "model/impulse_model.h"

using namespace idm;
using namespace idm::control;

namespace {

constexpr double kSoftLimitM = 8e-3;

drivers::sim::SimDeviceConfig realistic_device(std::uint64_t seed) {
  drivers::sim::SimDeviceConfig c;
  c.sim.plant = model::PlantKind::MassDamperSpring;
  c.sim.effects = {
      model::complete_effect({"amplifier", {{"cutoff_hz", 3000}}}, "bench"),
      model::complete_effect({"stribeck", {{"static_over_kinetic", 1.15}}}, "bench"),
      model::complete_effect({"friction_spread", {{"relative_sd", 0.05}}}, "bench"),
  };
  c.sim.seed = seed;
  c.sim.noise_m = 2e-9;
  c.interferometer.word.max_velocity_m_s = 1.0;  // above the slider's fastest velocity jump
  c.stream_rate_hz = 1e5;
  return c;
}

// The operator's one measurement of the stage (used by both sides): the mean step of a 200-cycle
// burst each way at the baseline's cell (200 Hz, duty 0.9 / 0.1, full stroke), m per cycle.
double g_uncertainty = 0.15;
double g_max_freq_hz = 2000;
bool g_trace = false;  // --trace: one line per move of ours, and the ladder at the end
double uncertainty() { return g_uncertainty; }

struct StepMeasurement {
  double positive_m = 0, negative_m = 0;
};

StepMeasurement measure_steps(std::uint64_t seed) {
  drivers::Device dev = drivers::sim::make_sim_device(realistic_device(seed));
  drivers::sim::SimBackend& sim = *dev.sim;
  dev.configure();
  dev.activate();
  StepMeasurement m;
  for (double duty : {0.9, 0.1}) {
    const double before = sim.true_position_m();
    const model::TriangleWave wave{200, duty, 20.35e-6, 200};
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

// The stage as configured for the positioner: Table 1, with alpha set from the one measurement
// (eq 22 at the baseline's cell); calibration refines it from there.
RegionMapConfig map_config(const StepMeasurement& m) {
  RegionMapConfig c;  // Table 1 stage (mu 0.4)
  c.friction_uncertainty = uncertainty();
  c.limits.max_freq_hz = g_max_freq_hz;
  model::StageParams ideal = c.stage;
  ideal.step_correction = 1.0;
  const double ideal_step = std::fabs(model::steady_step_ideal_m(ideal, 200, 0.9, 20.35e-6));
  c.stage.step_correction = std::min(1.0, 0.5 * (m.positive_m + m.negative_m) / ideal_step);
  c.limits.min_stroke_m = 0.1e-6;
  c.grid = RegionGrid::covering(c.limits, 10, 0.005, 6);
  return c;
}

struct MoveResult {
  bool within_count = false;       // by the interferometer reading
  bool within_count_true = false;  // by the simulated true position
  bool faulted = false;
  double time_s = 0;
  std::uint64_t cycles = 0;
  std::uint64_t bursts = 0;
  std::uint32_t corrections = 0;
  double overshoot_m = 0;  // furthest past the target along the move, at rest after a burst
  double step_m = 0;       // the step size the side works with (ours: the final rung's learned step)
  // A chunk that started short of the target and ended past it by more than one of its own steps:
  // the planner committed more than one cycle past the target. Its step: the larger of its
  // displacement / its cycles and the steady step it was planned with (a burst whose first cycle
  // does not move, offset about -step, moves less than a step per cycle on average), at least
  // one count. The strict count (displacement / cycles alone) is kept beside it.
  bool overshot_by_more_than_step = false;
  bool overshot_by_more_than_mean_step = false;
  double worst_pass_in_steps = 0;  // the largest pass past the target, in steps of the chunk
  MotionFault fault = MotionFault::None;
  bool left_soft_limits = false;
};

struct Summary {
  std::vector<MoveResult> moves;
  double wall_s = 0;
};

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const double pos = q * static_cast<double>(v.size() - 1);
  const std::size_t i = static_cast<std::size_t>(pos);
  const double f = pos - static_cast<double>(i);
  return i + 1 < v.size() ? v[i] * (1 - f) + v[i + 1] * f : v[i];
}

// Runs one move to rest, tracking the true position after every tick (overshoot, soft limits).
template <class Start>
MoveResult run_move(daemon::SimAxis& axis, double start_m, double target_m, Start&& start) {
  Positioner& p = *axis.positioner;
  drivers::sim::SimBackend& sim = *axis.sim;
  MoveResult r;
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
    const double mean_step = std::max(count_m, std::fabs(moved) / static_cast<double>(chunk_cycles));
    const double step = std::max(mean_step, chunk_planned_step_m);
    const double pass = dir * (x_end - target_m);
    if (dir * (chunk_x0 - target_m) < 0 && pass > 0) {
      r.worst_pass_in_steps = std::max(r.worst_pass_in_steps, pass / step);
      if (pass > mean_step * (1 + 1e-9)) r.overshot_by_more_than_mean_step = true;
      if (pass > step * (1 + 1e-9)) {
        r.overshot_by_more_than_step = true;
        if (g_trace)
          std::printf("  chunk of %llu cycles moved %.1f nm and passed the target by %.1f nm (%.2f steps)\n",
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

void finish(MoveResult& r, const Positioner& p, const drivers::sim::SimBackend& sim, double target_m) {
  r.within_count = p.status().position_valid && std::fabs(p.status().position_m - target_m) <= p.count_m();
  r.within_count_true = std::fabs(sim.true_position_m() - target_m) <= p.count_m();
}

Summary run_ours(const std::vector<double>& targets, std::uint64_t seed, const RegionMap& map,
                 Calibration& cal, double& final_step_bound_m) {
  Summary s;
  PositionerConfig pc;
  pc.soft_lower_m = -kSoftLimitM;
  pc.soft_upper_m = kSoftLimitM;
  daemon::SimAxis rig(map, realistic_device(seed), pc, &cal);
  Positioner& p = *rig.positioner;
  final_step_bound_m = std::max(p.finest_live_step_m(1), p.finest_live_step_m(-1));
  const auto w0 = std::chrono::steady_clock::now();
  for (double target : targets) {
    if (p.status().state == MotionState::Fault) {
      p.reset_fault();
      rig.tick();
    }
    const double start = rig.sim->true_position_m();
    MoveResult r = run_move(rig, start, target, [&] { p.move_absolute(target); });
    r.corrections = p.status().corrections;
    r.step_m = std::max(p.count_m(), std::fabs(p.last_plan().final_step_m));
    if (!r.faulted) r.time_s = p.status().last_move_time_s;
    finish(r, p, *rig.sim, target);
    if (g_trace)
      std::printf("move %3zu  %+11.4g um  %-8s %-12s err %+7.2f counts  t %.4f s  chunks %3llu  corr %2u  over %.1f nm\n",
                  s.moves.size(), (target - start) * 1e6, motion_state_name(p.status().state),
                  motion_fault_name(p.status().fault), (p.status().position_m - target) / p.count_m(),
                  r.time_s, static_cast<unsigned long long>(p.move_chunks()), p.status().corrections, r.overshoot_m * 1e9);
    s.moves.push_back(r);
  }
  s.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - w0).count();
  if (g_trace) {
    for (int dir : {-1, 1}) {
      for (std::size_t i = 0; i < p.rung_count(dir); ++i) {
        const Positioner::RungInfo r = p.rung(dir, i);
        const RegionCell& c = map.cells()[r.cell];
        std::printf("rung %+d %2zu  %6.0f Hz d %.3f S %6.3f um  model %8.2f nm  learned %8.2f nm + %8.2f  %s%s chunks %llu\n",
                    dir, i, c.freq_hz, c.duty, c.stroke_m * 1e6, std::fabs(c.step_m) * 1e9,
                    r.estimate.step_m * 1e9, r.estimate.offset_m * 1e9, r.dead ? "DEAD " : "",
                    r.proven ? "proven" : "", static_cast<unsigned long long>(r.chunks));
      }
    }
  }
  return s;
}

// The baseline: fixed steps of (200 Hz, duty 0.1 / 0.9, full stroke) whose size the operator
// measured once (a 200-cycle burst each way, as one sets the motor record's MRES); a move asks
// for round(error / step) steps, reads the encoder and retries while outside the deadband (one
// count), up to 10 retries; it gives up when the error rounds to zero steps.
Summary run_baseline(const std::vector<double>& targets, std::uint64_t seed, const RegionMap& map) {
  Summary s;
  PositionerConfig pc;
  pc.max_chunk_s = 10.0;  // whole bursts (2,000 cycles at most: the sim's 2^20 samples)
  drivers::sim::SimDeviceConfig device = realistic_device(seed);
  device.stream_capacity = std::size_t{1} << 21;  // a whole 10 s burst's capture
  daemon::SimAxis rig(map, device, pc);
  Positioner& p = *rig.positioner;
  const double freq = 200, duty_positive = 0.9, stroke = 20.35e-6;
  double step_m[2] = {0, 0};  // [0] negative, [1] positive, measured
  for (int dir : {1, -1}) {
    const double before = p.status().position_m;
    p.step_open_loop(dir * 200, duty_positive, freq, stroke);
    rig.run();
    step_m[dir > 0 ? 1 : 0] = std::fabs(p.status().position_m - before) / 200;
  }
  const auto w0 = std::chrono::steady_clock::now();
  for (double target : targets) {
    const double start = rig.sim->true_position_m();
    std::uint32_t retries = 0;
    MoveResult r = run_move(rig, start, target, [] {});
    const double t0 = rig.sim->now_s();
    const std::uint64_t cycles0 = p.status().cycles, bursts0 = p.status().bursts;
    for (int attempt = 0; attempt <= 10; ++attempt) {
      const double error = target - p.status().position_m;
      if (std::fabs(error) <= p.count_m()) break;
      const int dir = error > 0 ? 1 : -1;
      const double n = std::round(std::fabs(error) / step_m[dir > 0 ? 1 : 0]);
      if (n < 1) break;  // the error rounds to no step: the motor record stops here
      if (attempt > 0) ++retries;
      for (double left = n; left > 0;) {
        const double burst = std::min(left, 2000.0);
        left -= burst;
        const MoveResult part = run_move(rig, start, target, [&] {
          p.step_open_loop(static_cast<std::int64_t>(dir * burst), duty_positive, freq, stroke);
        });
        r.overshoot_m = std::max(r.overshoot_m, part.overshoot_m);
        r.overshot_by_more_than_step = r.overshot_by_more_than_step || part.overshot_by_more_than_step;
        r.overshot_by_more_than_mean_step = r.overshot_by_more_than_mean_step || part.overshot_by_more_than_mean_step;
        r.worst_pass_in_steps = std::max(r.worst_pass_in_steps, part.worst_pass_in_steps);
        r.left_soft_limits = r.left_soft_limits || part.left_soft_limits;
        if (part.faulted) {
          r.faulted = true;
          p.reset_fault();
          rig.tick();
        }
      }
    }
    r.time_s = rig.sim->now_s() - t0;
    r.cycles = p.status().cycles - cycles0;
    r.bursts = p.status().bursts - bursts0;
    r.corrections = retries;
    r.step_m = std::max(step_m[0], step_m[1]);
    finish(r, p, *rig.sim, target);
    s.moves.push_back(r);
  }
  s.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - w0).count();
  std::printf("baseline steps measured: +%.4g um, -%.4g um per cycle\n", step_m[1] * 1e6, step_m[0] * 1e6);
  return s;
}

// Time to target: the time a move takes to end within one count (by the reading); a move that
// never gets there has no time to target (infinite). The median over all moves is infinite when
// fewer than half arrive.
double time_to_target_s(const MoveResult& m) {
  return m.within_count ? m.time_s : std::numeric_limits<double>::infinity();
}

double median_time_to_target_s(const Summary& s) {
  std::vector<double> t;
  for (const MoveResult& m : s.moves) t.push_back(time_to_target_s(m));
  std::sort(t.begin(), t.end());
  return t.empty() ? 0 : t[(t.size() - 1) / 2];
}

void print_row(const char* name, const Summary& s) {
  std::vector<double> times, cycles, corrections;
  std::size_t within = 0, within_true = 0, faults = 0, over_step = 0, over_mean_step = 0, outside = 0;
  double max_overshoot = 0, worst_pass = 0;
  for (const MoveResult& m : s.moves) {
    within += m.within_count;
    within_true += m.within_count_true;
    faults += m.faulted;
    outside += m.left_soft_limits;
    times.push_back(m.time_s);
    cycles.push_back(static_cast<double>(m.cycles));
    corrections.push_back(m.corrections);
    max_overshoot = std::max(max_overshoot, m.overshoot_m);
    worst_pass = std::max(worst_pass, m.worst_pass_in_steps);
    over_step += m.overshot_by_more_than_step;
    over_mean_step += m.overshot_by_more_than_mean_step;
  }
  const double n = static_cast<double>(s.moves.size());
  const double ttt = median_time_to_target_s(s);
  char ttt_text[32];
  if (std::isfinite(ttt)) std::snprintf(ttt_text, sizeof ttt_text, "%.4f", ttt);
  else std::snprintf(ttt_text, sizeof ttt_text, "never");
  std::printf("%-9s %6.1f %% %6.1f %% %8s %7.3f %7.3f %8.0f %8.0f %6.1f %5zu %9.1f %5zu %5zu %6.2f %5zu %7.2f\n", name,
              100.0 * within / n, 100.0 * within_true / n, ttt_text, percentile(times, 0.5),
              percentile(times, 0.95), percentile(cycles, 0.5), percentile(cycles, 0.95),
              percentile(corrections, 0.5), faults, max_overshoot * 1e9, over_step, over_mean_step, worst_pass,
              outside, s.wall_s);
}

}  // namespace

int main(int argc, char** argv) {
  bool quick = false;
  int moves = 200;
  std::uint64_t seed = 1;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--quick") == 0) quick = true;
    else if (std::strcmp(argv[i], "--moves") == 0 && i + 1 < argc) moves = std::atoi(argv[++i]);
    else if (std::strcmp(argv[i], "--max-freq") == 0 && i + 1 < argc) g_max_freq_hz = std::atof(argv[++i]);
    else if (std::strcmp(argv[i], "--uncertainty") == 0 && i + 1 < argc) g_uncertainty = std::atof(argv[++i]);
    else if (std::strcmp(argv[i], "--trace") == 0) g_trace = true;
    else if (std::strcmp(argv[i], "--seed") == 0 && i + 1 < argc) seed = std::strtoull(argv[++i], nullptr, 10);
    else {
      std::fprintf(stderr, "usage: positioning_bench [--quick] [--moves N] [--seed S] [--uncertainty U] [--max-freq HZ] [--trace]\n");
      return 2;
    }
  }
  if (quick) moves = std::min(moves, 12);
  // Seeded moves: |distance| log-uniform in [10 nm, 5 mm], random sign (flipped when the target
  // would leave the soft limits).
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> log_d(std::log(10e-9), std::log(5e-3));
  std::vector<double> targets;
  double x = 0;
  for (int i = 0; i < moves; ++i) {
    double d = std::exp(log_d(rng)) * ((rng() & 1u) ? 1 : -1);
    if (std::fabs(x + d) > kSoftLimitM * 0.95) d = -d;
    x += d;
    targets.push_back(x);
  }
  const StepMeasurement measured = measure_steps(seed);
  const RegionMap map(map_config(measured));
  std::printf("measured at 200 Hz / 0.9, 0.1 / 20.35 um: +%.4g um, -%.4g um per cycle -> alpha %.4f\n",
              measured.positive_m * 1e6, measured.negative_m * 1e6, map.config().stage.step_correction);
  Calibration cal(map.config().stage);
  double final_step_bound = 0;
  const Summary ours = run_ours(targets, seed, map, cal, final_step_bound);
  const Summary base = run_baseline(targets, seed, map);
  std::printf("positioning: %d seeded moves (seed %llu), 10 nm .. 5 mm log-uniform, both directions\n", moves,
              static_cast<unsigned long long>(seed));
  std::printf("plant: mck (K 5.7e6, C 230) + amplifier 3 kHz + stribeck 1.15 + friction_spread 0.05; "
              "lambda/64, 2 nm rms\n");
  std::printf("one count %.4g nm; '>step': moves with a chunk that started short of the target and ended past it "
              "by more than one of its own steps (the larger of displacement / cycles and the steady step it was "
              "planned with, at least one count); '>d/n': the same with displacement / cycles alone; 'pass/st': "
              "the largest such pass in steps\n", 9.89048e-9 * 1e9);
  std::printf("%-9s %8s %8s %8s %7s %7s %8s %8s %6s %5s %9s %5s %5s %6s %5s %7s\n", "", "within1", "true<=1",
              "ttt50[s]", "t50[s]", "t95[s]", "cyc50", "cyc95", "corr50", "fault", "maxover", ">step", ">d/n",
              "pass/st", "soft", "wall[s]");
  print_row("ours", ours);
  print_row("baseline", base);
  std::vector<double> t_ours, t_base;
  for (const MoveResult& m : ours.moves) t_ours.push_back(m.time_s);
  for (const MoveResult& m : base.moves) t_base.push_back(m.time_s);
  {
    int by_fault[6] = {};
    for (const MoveResult& m : ours.moves) ++by_fault[static_cast<int>(m.fault)];
    std::printf("ours: faults by kind:");
    for (int f = 1; f < 6; ++f) std::printf(" %s %d", motion_fault_name(static_cast<MotionFault>(f)), by_fault[f]);
    std::printf("\n");
  }
  // The ratio is of the median time to target; the median time to the end of the move
  // (the motor record's DMOV, whether or not it arrived) is printed beside it.
  const double ttt_ours = median_time_to_target_s(ours), ttt_base = median_time_to_target_s(base);
  if (std::isfinite(ttt_base))
    std::printf("median time-to-target ratio ours/baseline: %.3f\n", ttt_ours / ttt_base);
  else
    std::printf("median time-to-target ratio ours/baseline: 0 (the baseline's median move never arrives "
                "within one count)\n");
  std::printf("median time-to-done ratio ours/baseline: %.3f (done = at rest, arrived or not)\n",
              percentile(t_ours, 0.5) / percentile(t_base, 0.5));
  const CalibrationState cs = cal.state();
  std::printf("calibration after the run: %llu updates; one-step +: alpha %.4f mu %.4f; -: alpha %.4f mu %.4f\n",
              static_cast<unsigned long long>(cs.total_updates), cs.estimates[1][1].alpha,
              cs.estimates[1][1].mu(), cs.estimates[1][0].alpha, cs.estimates[1][0].mu());
  // Corrections in the first and second half of the session (calibration at work).
  std::uint64_t first = 0, second = 0;
  for (std::size_t i = 0; i < ours.moves.size(); ++i)
    (i < ours.moves.size() / 2 ? first : second) += ours.moves[i].corrections;
  std::printf("ours: corrections in the first half %llu, second half %llu\n",
              static_cast<unsigned long long>(first), static_cast<unsigned long long>(second));
  return 0;
}
