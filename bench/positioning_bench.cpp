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
//
// The plant and the peers: positioning_rig.h.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <functional>
#include <limits>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "bench/positioning_rig.h"
#include "control/calibration.h"
#include "control/positioner.h"
#include "daemon/sim_axis.h"
#include "drivers/sim/sim_backend.h"
#include "model/impulse_model.h"

using namespace idm;
using namespace idm::control;
using namespace idm::bench;

namespace {

// The operator's one measurement of the stage (used by both sides): the mean step of a 200-cycle
// burst each way at the baseline's cell (200 Hz, duty 0.9 / 0.1, full stroke), m per cycle.
double g_uncertainty = 0.15;
double g_max_freq_hz = 2000;
double g_dwell_s = 0;        // --dwell S: ours, MOVE:DWELl
double g_window_counts = 0;  // --window W: ours, MOVE:WINDow in counts (0: half a count)
double uncertainty() {
  return g_uncertainty;
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

Summary run_ours(const std::vector<double>& targets, std::uint64_t seed, const RegionMap& map,
                 Calibration& cal, double& final_step_bound_m) {
  Summary s;
  PositionerConfig pc;
  pc.soft_lower_m = -kSoftLimitM;
  pc.soft_upper_m = kSoftLimitM;
  pc.dwell_s = g_dwell_s;
  pc.tolerance_m = g_window_counts > 0 ? g_window_counts * 632.991e-9 / 64 : 0.0;
  daemon::SimAxis rig(map, realistic_device(seed), pc, &cal);
  Positioner& p = *rig.positioner;
  final_step_bound_m = std::max(p.finest_live_step_m(1), p.finest_live_step_m(-1));
  const auto w0 = std::chrono::steady_clock::now();
  for (double target : targets) {
    const double start = rig.sim->true_position_m();
    MoveOutcome r = run_closed_loop_move(rig, target);
    if (g_trace)
      std::printf(
          "move %3zu  %+11.4g um  %-8s %-12s %-10s err %+7.2f fresh %+7.2f true %+7.2f counts  "
          "t %.4f s  chunks %3llu  corr %2u  over %.1f nm\n",
          s.moves.size(), (target - start) * 1e6, motion_state_name(p.status().state),
          motion_fault_name(p.status().fault), move_result_name(p.status().result),
          r.done_error_m / p.count_m(), r.fresh_error_m / p.count_m(),
          (rig.sim->true_position_m() - target) / p.count_m(), r.time_s,
          static_cast<unsigned long long>(p.move_chunks()), p.status().corrections,
          r.overshoot_m * 1e9);
    s.moves.push_back(r);
  }
  s.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - w0).count();
  if (g_trace) print_ladder(p, map);
  return s;
}

// Time to target: the time a move takes to end within one count (by the reading); a move that
// never gets there has no time to target (infinite). The median over all moves is infinite when
// fewer than half arrive.
double time_to_target_s(const MoveOutcome& m) {
  return m.within_count ? m.time_s : std::numeric_limits<double>::infinity();
}

double median_time_to_target_s(const Summary& s) {
  std::vector<double> t;
  for (const MoveOutcome& m : s.moves) t.push_back(time_to_target_s(m));
  std::sort(t.begin(), t.end());
  return t.empty() ? 0 : t[(t.size() - 1) / 2];
}

void print_row(const char* name, const Summary& s) {
  std::vector<double> times, cycles, corrections;
  std::size_t within = 0, within_true = 0, faults = 0, over_step = 0, over_mean_step = 0,
              outside = 0;
  std::size_t fresh = 0, fresh_true = 0, not_ok = 0;
  double max_overshoot = 0, worst_pass = 0;
  for (const MoveOutcome& m : s.moves) {
    within += m.within_count;
    within_true += m.within_count_true;
    fresh += m.within_count_fresh;
    fresh_true += m.within_count_fresh_true;
    not_ok += m.not_ok;
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
  if (std::isfinite(ttt))
    std::snprintf(ttt_text, sizeof ttt_text, "%.4f", ttt);
  else
    std::snprintf(ttt_text, sizeof ttt_text, "never");
  std::printf(
      "%-9s %6.1f %% %6.1f %% %8s %7.3f %7.3f %8.0f %8.0f %6.1f %5zu %9.1f %5zu %5zu %6.2f %5zu "
      "%7.2f\n",
      name, 100.0 * within / n, 100.0 * within_true / n, ttt_text, percentile(times, 0.5),
      percentile(times, 0.95), percentile(cycles, 0.5), percentile(cycles, 0.95),
      percentile(corrections, 0.5), faults, max_overshoot * 1e9, over_step, over_mean_step,
      worst_pass, outside, s.wall_s);
  std::printf(
      "%-9s fresh reading 5 ms after done within one count %.1f %%, true position then %.1f %%; "
      "results other than OK %zu\n",
      name, 100.0 * fresh / n, 100.0 * fresh_true / n, not_ok);
}

// The settling study: the same moves with in-position windows of 1, 2, 5 and 10 counts (dwell
// g_dwell_s), the distribution of the time to done; a table on stdout and an SVG of the
// cumulative distributions (log time axis, ticks at round numbers).
void settling_study(const std::vector<double>& targets, std::uint64_t seed, const RegionMap& map,
                    const std::string& svg_path) {
  const double windows[] = {1, 2, 5, 10};
  std::vector<std::vector<double>> times;
  std::printf("settling study: %zu moves, dwell %g s; time to done [s]\n", targets.size(),
              g_dwell_s);
  std::printf("%-8s %8s %8s %8s %8s %8s %8s %6s\n", "window", "p10", "p50", "p90", "p95", "p99",
              "max", "OK");
  for (double w : windows) {
    g_window_counts = w;
    Calibration cal(map.config().stage);
    double bound = 0;
    const Summary s = run_ours(targets, seed, map, cal, bound);
    std::vector<double> t;
    std::size_t ok = 0;
    for (const MoveOutcome& m : s.moves) {
      t.push_back(m.time_s);
      ok += !m.not_ok && !m.faulted;
    }
    std::printf("%5.0f ct %8.4f %8.4f %8.4f %8.4f %8.4f %8.4f %5.1f%%\n", w, percentile(t, 0.1),
                percentile(t, 0.5), percentile(t, 0.9), percentile(t, 0.95), percentile(t, 0.99),
                percentile(t, 1.0),
                100.0 * static_cast<double>(ok) / static_cast<double>(t.size()));
    std::sort(t.begin(), t.end());
    times.push_back(t);
  }
  g_window_counts = 0;
  if (svg_path.empty()) return;
  FILE* f = std::fopen(svg_path.c_str(), "w");
  if (!f) {
    std::printf("cannot write %s\n", svg_path.c_str());
    return;
  }
  const double W = 640, H = 400, L = 70, R = 20, T = 30, B = 50;
  const double lo = 1e-3, hi = 10;  // s, log axis
  auto X = [&](double t) {
    return L + (W - L - R) * (std::log10(std::clamp(t, lo, hi)) - std::log10(lo)) /
                   (std::log10(hi) - std::log10(lo));
  };
  auto Y = [&](double q) { return H - B - (H - T - B) * q; };
  std::fprintf(f,
               "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"%g\" height=\"%g\" "
               "font-family=\"sans-serif\" font-size=\"12\">\n",
               W, H);
  std::fprintf(f, "<rect width=\"100%%\" height=\"100%%\" fill=\"white\"/>\n");
  for (double t : {1e-3, 1e-2, 1e-1, 1.0, 10.0}) {
    std::fprintf(f, "<line x1=\"%.1f\" y1=\"%.1f\" x2=\"%.1f\" y2=\"%.1f\" stroke=\"#ddd\"/>\n",
                 X(t), Y(0), X(t), Y(1));
    std::fprintf(f, "<text x=\"%.1f\" y=\"%.1f\" text-anchor=\"middle\">%g</text>\n", X(t),
                 Y(0) + 18, t);
  }
  for (int q = 0; q <= 100; q += 25) {
    std::fprintf(f, "<line x1=\"%.1f\" y1=\"%.1f\" x2=\"%.1f\" y2=\"%.1f\" stroke=\"#ddd\"/>\n",
                 X(lo), Y(q / 100.0), X(hi), Y(q / 100.0));
    std::fprintf(f, "<text x=\"%.1f\" y=\"%.1f\" text-anchor=\"end\">%d %%</text>\n", L - 6,
                 Y(q / 100.0) + 4, q);
  }
  std::fprintf(f, "<text x=\"%.1f\" y=\"%.1f\" text-anchor=\"middle\">time to done [s]</text>\n",
               (L + W - R) / 2, H - 12);
  std::fprintf(f,
               "<text x=\"16\" y=\"%.1f\" transform=\"rotate(-90 16 %.1f)\" "
               "text-anchor=\"middle\">moves done</text>\n",
               (T + H - B) / 2, (T + H - B) / 2);
  const char* colors[] = {"#1f77b4", "#ff7f0e", "#2ca02c", "#d62728"};
  for (std::size_t k = 0; k < times.size(); ++k) {
    std::fprintf(f, "<polyline fill=\"none\" stroke=\"%s\" stroke-width=\"2\" points=\"",
                 colors[k]);
    const std::vector<double>& t = times[k];
    for (std::size_t i = 0; i < t.size(); ++i) {
      const double q0 = static_cast<double>(i) / static_cast<double>(t.size());
      const double q1 = static_cast<double>(i + 1) / static_cast<double>(t.size());
      std::fprintf(f, "%.1f,%.1f %.1f,%.1f ", X(t[i]), Y(q0), X(t[i]), Y(q1));
    }
    std::fprintf(f, "\"/>\n<text x=\"%.1f\" y=\"%.1f\" fill=\"%s\">window %g counts</text>\n",
                 L + 10, T + 16 * static_cast<double>(k + 1), colors[k], windows[k]);
  }
  std::fprintf(f, "</svg>\n");
  std::fclose(f);
  std::printf("wrote %s\n", svg_path.c_str());
}

}  // namespace

int main(int argc, char** argv) {
  bool quick = false;
  int moves = 200;
  std::string settling_svg;  // --settling FILE.svg: the settling study instead of the comparison
  std::uint64_t seed = 1;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--quick") == 0)
      quick = true;
    else if (std::strcmp(argv[i], "--moves") == 0 && i + 1 < argc)
      moves = std::atoi(argv[++i]);
    else if (std::strcmp(argv[i], "--max-freq") == 0 && i + 1 < argc)
      g_max_freq_hz = std::atof(argv[++i]);
    else if (std::strcmp(argv[i], "--uncertainty") == 0 && i + 1 < argc)
      g_uncertainty = std::atof(argv[++i]);
    else if (std::strcmp(argv[i], "--trace") == 0)
      g_trace = true;
    else if (std::strcmp(argv[i], "--dwell") == 0 && i + 1 < argc)
      g_dwell_s = std::atof(argv[++i]);
    else if (std::strcmp(argv[i], "--window") == 0 && i + 1 < argc)
      g_window_counts = std::atof(argv[++i]);
    else if (std::strcmp(argv[i], "--settling") == 0 && i + 1 < argc)
      settling_svg = argv[++i];
    else if (std::strcmp(argv[i], "--seed") == 0 && i + 1 < argc)
      seed = std::strtoull(argv[++i], nullptr, 10);
    else {
      std::fprintf(stderr,
                   "usage: positioning_bench [--quick] [--moves N] [--seed S] [--uncertainty U] "
                   "[--max-freq HZ] [--dwell S] [--window COUNTS] [--settling FILE.svg] "
                   "[--trace]\n");
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
  const StepMeasurement measured = measure_steps(realistic_device(seed), 20.35e-6);
  const RegionMap map(map_config(measured));
  if (!settling_svg.empty()) {
    settling_study(targets, seed, map, settling_svg);
    return 0;
  }
  std::printf(
      "measured at 200 Hz / 0.9, 0.1 / 20.35 um: +%.4g um, -%.4g um per cycle -> alpha %.4f\n",
      measured.positive_m * 1e6, measured.negative_m * 1e6, map.config().stage.step_correction);
  Calibration cal(map.config().stage);
  double final_step_bound = 0;
  const Summary ours = run_ours(targets, seed, map, cal, final_step_bound);
  const Summary base = run_baseline(targets, realistic_device(seed), map);
  const Summary vendor = run_vendor(targets, realistic_device(seed), map);
  std::printf(
      "positioning: %d seeded moves (seed %llu), 10 nm .. 5 mm log-uniform, both directions\n",
      moves, static_cast<unsigned long long>(seed));
  std::printf(
      "plant: mck (K 5.7e6, C 230) + amplifier 3 kHz + stribeck 1.15 + friction_spread 0.05; "
      "lambda/64, 2 nm rms\n");
  std::printf(
      "one count %.4g nm; '>step': moves with a chunk that started short of the target and ended "
      "past it "
      "by more than one of its own steps (the larger of displacement / cycles and the steady step "
      "it was "
      "planned with, at least one count); '>d/n': the same with displacement / cycles alone; "
      "'pass/st': "
      "the largest such pass in steps\n",
      9.89048e-9 * 1e9);
  std::printf("%-9s %8s %8s %8s %7s %7s %8s %8s %6s %5s %9s %5s %5s %6s %5s %7s\n", "", "within1",
              "true<=1", "ttt50[s]", "t50[s]", "t95[s]", "cyc50", "cyc95", "corr50", "fault",
              "maxover", ">step", ">d/n", "pass/st", "soft", "wall[s]");
  print_row("ours", ours);
  print_row("baseline", base);
  print_row("vendor", vendor);
  std::vector<double> t_ours, t_base;
  for (const MoveOutcome& m : ours.moves) t_ours.push_back(m.time_s);
  for (const MoveOutcome& m : base.moves) t_base.push_back(m.time_s);
  {
    // Every fault control names (the enum's underlying type bounds it).
    int by_fault[256] = {};
    for (const MoveOutcome& m : ours.moves) ++by_fault[static_cast<std::uint8_t>(m.fault)];
    std::printf("ours: faults by kind:");
    for (int f = 1; f < 256; ++f) {
      const char* name = motion_fault_name(static_cast<MotionFault>(f));
      if (std::strcmp(name, "?") == 0) break;
      std::printf(" %s %d", name, by_fault[f]);
    }
    std::printf("\n");
  }
  // The ratio is of the median time to target; the median time to the end of the move
  // (the motor record's DMOV, whether or not it arrived) is printed beside it.
  const double ttt_ours = median_time_to_target_s(ours), ttt_base = median_time_to_target_s(base);
  if (std::isfinite(ttt_base))
    std::printf("median time-to-target ratio ours/baseline: %.3f\n", ttt_ours / ttt_base);
  else
    std::printf(
        "median time-to-target ratio ours/baseline: 0 (the baseline's median move never arrives "
        "within one count)\n");
  std::printf("median time-to-done ratio ours/baseline: %.3f (done = at rest, arrived or not)\n",
              percentile(t_ours, 0.5) / percentile(t_base, 0.5));
  {
    // Against the vendor-style loop: time to target (arrived within one count by the reading)
    // over the moves both arrived at, median and p95, and the shares arriving.
    std::vector<double> a, b;
    std::size_t arrived_ours = 0, arrived_vendor = 0;
    for (std::size_t i = 0; i < ours.moves.size(); ++i) {
      arrived_ours += ours.moves[i].within_count_fresh;
      arrived_vendor += vendor.moves[i].within_count_fresh;
      if (ours.moves[i].within_count && vendor.moves[i].within_count) {
        a.push_back(ours.moves[i].time_s);
        b.push_back(vendor.moves[i].time_s);
      }
    }
    const double n = static_cast<double>(ours.moves.size());
    std::printf(
        "vs vendor-style loop, over the %zu moves both arrived at: time to target median %.4f / "
        "%.4f s "
        "(ratio %.3f), p95 %.4f / %.4f s (ratio %.3f); arriving (fresh reading) %.1f %% / %.1f "
        "%%\n",
        a.size(), percentile(a, 0.5), percentile(b, 0.5), percentile(a, 0.5) / percentile(b, 0.5),
        percentile(a, 0.95), percentile(b, 0.95), percentile(a, 0.95) / percentile(b, 0.95),
        100.0 * arrived_ours / n, 100.0 * arrived_vendor / n);
  }
  const CalibrationState cs = cal.state();
  std::printf(
      "calibration after the run: %llu updates; one-step +: alpha %.4f mu %.4f; -: alpha %.4f mu "
      "%.4f\n",
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
