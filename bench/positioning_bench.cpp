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
#include <random>
#include <string>
#include <vector>

#include "control/calibration.h"
#include "control/positioner.h"
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
  double step_m = 0;       // the step overshoot is judged against (ours: the final rung's learned step)
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

struct Rig {
  drivers::Device device;
  drivers::sim::SimBackend* sim = nullptr;
  explicit Rig(const drivers::sim::SimDeviceConfig& cfg) {
    device = drivers::sim::make_sim_device(cfg);
    sim = device.sim.get();
    if (!device.configure().ok() || !device.activate().ok()) {
      std::fprintf(stderr, "positioning_bench: the sim device did not come up\n");
      std::exit(1);
    }
  }
  ~Rig() { device.shutdown(); }
};

// Runs one move to rest, tracking the true position after every tick (overshoot, soft limits).
template <class Start>
MoveResult run_move(Positioner& p, drivers::sim::SimBackend& sim, double start_m, double target_m,
                    Start&& start) {
  MoveResult r;
  const double sign = target_m >= start_m ? 1.0 : -1.0;
  const double t0 = sim.now_s();
  const std::uint64_t cycles0 = p.status().cycles, bursts0 = p.status().bursts;
  start();
  auto observe = [&] {
    const double x = sim.true_position_m();
    r.overshoot_m = std::max(r.overshoot_m, sign * (x - target_m));
    if (std::fabs(x) > kSoftLimitM) r.left_soft_limits = true;
  };
  p.tick(sim.now_s());
  while (!p.at_rest() && sim.now_s() - t0 < 600) {
    sim.advance_s(1e-4);
    p.tick(sim.now_s());
    observe();
  }
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
  Rig rig(realistic_device(seed));
  PositionerConfig pc;
  pc.soft_lower_m = -kSoftLimitM;
  pc.soft_upper_m = kSoftLimitM;
  Positioner p(map, PlannerConfig{}, pc, *rig.device.output, *rig.device.interferometer, &cal);
  final_step_bound_m = std::max(p.planner().final_step_bound_m(1), p.planner().final_step_bound_m(-1));
  p.tick(rig.sim->now_s());
  const auto w0 = std::chrono::steady_clock::now();
  for (double target : targets) {
    if (p.status().state == MotionState::Fault) {
      p.reset_fault();
      p.tick(rig.sim->now_s());
    }
    const double start = rig.sim->true_position_m();
    MoveResult r = run_move(p, *rig.sim, start, target, [&] { p.move_absolute(target); });
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
  Rig rig(realistic_device(seed));
  PositionerConfig pc;
  pc.max_chunk_s = 10.0;  // whole bursts (2,000 cycles at most: the sim's 2^20 samples)
  Positioner p(map, PlannerConfig{}, pc, *rig.device.output, *rig.device.interferometer);
  auto now = [&] { return rig.sim->now_s(); };
  auto advance = [&](double dt) { rig.sim->advance_s(dt); };
  p.tick(now());
  const double freq = 200, duty_positive = 0.9, stroke = 20.35e-6;
  double step_m[2] = {0, 0};  // [0] negative, [1] positive, measured
  for (int dir : {1, -1}) {
    const double before = p.status().position_m;
    p.step_open_loop(dir * 200, duty_positive, freq, stroke);
    run_until_rest(p, now, advance, 60);
    step_m[dir > 0 ? 1 : 0] = std::fabs(p.status().position_m - before) / 200;
  }
  const auto w0 = std::chrono::steady_clock::now();
  for (double target : targets) {
    const double start = rig.sim->true_position_m();
    std::uint32_t retries = 0;
    MoveResult r = run_move(p, *rig.sim, start, target, [] {});
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
        const MoveResult part = run_move(p, *rig.sim, start, target, [&] {
          p.step_open_loop(static_cast<std::int64_t>(dir * burst), duty_positive, freq, stroke);
        });
        r.overshoot_m = std::max(r.overshoot_m, part.overshoot_m);
        r.left_soft_limits = r.left_soft_limits || part.left_soft_limits;
        if (part.faulted) {
          r.faulted = true;
          p.reset_fault();
          p.tick(now());
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

void print_row(const char* name, const Summary& s, double step_bound_m) {
  std::vector<double> times, cycles, corrections;
  std::size_t within = 0, within_true = 0, faults = 0, over_step = 0, outside = 0;
  double max_overshoot = 0;
  for (const MoveResult& m : s.moves) {
    within += m.within_count;
    within_true += m.within_count_true;
    faults += m.faulted;
    outside += m.left_soft_limits;
    times.push_back(m.time_s);
    cycles.push_back(static_cast<double>(m.cycles));
    corrections.push_back(m.corrections);
    max_overshoot = std::max(max_overshoot, m.overshoot_m);
    over_step += m.overshoot_m > std::max(step_bound_m, m.step_m) * (1 + 1e-9);
  }
  const double n = static_cast<double>(s.moves.size());
  std::printf("%-9s %6.1f %% %6.1f %% %7.3f %7.3f %8.0f %8.0f %6.1f %5zu %9.1f %5zu %5zu %7.2f\n", name,
              100.0 * within / n, 100.0 * within_true / n, percentile(times, 0.5), percentile(times, 0.95),
              percentile(cycles, 0.5), percentile(cycles, 0.95), percentile(corrections, 0.5) , faults,
              max_overshoot * 1e9, over_step, outside, s.wall_s);
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
  double step_bound = 0;
  const Summary ours = run_ours(targets, seed, map, cal, step_bound);
  const Summary base = run_baseline(targets, seed, map);
  std::printf("positioning: %d seeded moves (seed %llu), 10 nm .. 5 mm log-uniform, both directions\n", moves,
              static_cast<unsigned long long>(seed));
  std::printf("plant: mck (K 5.7e6, C 230) + amplifier 3 kHz + stribeck 1.15 + friction_spread 0.05; "
              "lambda/64, 2 nm rms\n");
  std::printf("one count %.4g nm; overshoot judged against one step: ours max(one count, the final rung's learned "
              "step), baseline its measured step\n", 9.89048e-9 * 1e9);
  step_bound = 0;
  std::printf("%-9s %8s %8s %7s %7s %8s %8s %6s %5s %9s %5s %5s %7s\n", "", "within1", "true<=1", "t50[s]",
              "t95[s]", "cyc50", "cyc95", "corr50", "fault", "maxover", ">step", "soft", "wall[s]");
  print_row("ours", ours, step_bound);
  print_row("baseline", base, 0.0);
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
  std::printf("median time ratio ours/baseline: %.3f\n", percentile(t_ours, 0.5) / percentile(t_base, 0.5));
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
