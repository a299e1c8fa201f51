// gap_bench: idm-gap diagnose timed on the machine, read from disk, on 2 threads.
//   * the paper-size sweep: 8 frequencies 100-800 Hz x 10 duties 0.05-0.50 x 10
//     trials, one stroke, 12 cycles, 100 kHz, a 3 kHz second-order amplifier hidden;
//   * a lab's 20-cell sweep: 4 x 5 cells, 4 trials, 25 kHz, the same amplifier;
//   * how it grows: 20, 40 and 80 cells at 4 trials; 3, 5 and 10 trials at 40 cells; and a pair
//     (amplifier + tilt, both directions), which adds the joint fits;
//   * the paper-size sweep with the other effects its one stroke and one direction can show, alone
//     and in pairs (the slowest fits: Stribeck's scans, a friction spread's quantiles).
//   gap_bench [--quick]   (--quick: the 20-cell sweep only, 3 trials; CI checks that it runs)
#include <sys/resource.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <string>

#include "analysis/selection.h"
#include "analysis/simulated_sweep.h"

using namespace idm;

namespace {

double cpu_s() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return static_cast<double>(u.ru_utime.tv_sec) + 1e-6 * static_cast<double>(u.ru_utime.tv_usec);
}

struct Case {
  std::string name;
  int freqs, duties, trials;
  bool both_directions;
  double rate_hz;
  std::vector<model::EffectSpec> effects;
};

void run(const Case& c) {
  analysis::SweepPlan plan;
  for (int i = 0; i < c.freqs; ++i)
    plan.freqs_hz.push_back(100 + 700.0 * i / std::max(1, c.freqs - 1));
  for (int i = 0; i < c.duties; ++i)
    plan.duties.push_back(std::round(1000 * (0.05 + 0.45 * i / std::max(1, c.duties - 1))) / 1000);
  if (c.both_directions)
    for (int i = 0; i < c.duties; ++i)
      plan.duties.push_back(std::round(1000 * (1 - plan.duties[static_cast<std::size_t>(i)])) /
                            1000);
  plan.trials = c.trials;
  plan.cycles = 12;
  plan.sample_rate_hz = c.rate_hz;
  plan.seed = 7;
  model::SimConfig sim;
  sim.noise_m = 2e-9;
  sim.seed = 7;
  for (const model::EffectSpec& e : c.effects)
    sim.effects.push_back(model::complete_effect(e, "bench"));
  const auto dir =
      std::filesystem::temp_directory_path() / ("gap_bench_" + std::to_string(getpid()));
  std::filesystem::remove_all(dir);
  analysis::run_simulated_sweep(model::StageFile{}, sim, plan, dir.string());
  const auto t0 = std::chrono::steady_clock::now();
  const double c0 = cpu_s();
  const analysis::SweepCells cells = analysis::collect_cells(recording::read_dataset(dir.string()));
  analysis::DiagnoseOptions opt;
  opt.fit.threads = 2;
  const analysis::Diagnosis d = analysis::diagnose(cells, opt);
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::string named;
  for (const model::EffectSpec& e : d.chosen) named += (named.empty() ? "" : "+") + e.name;
  std::printf(
      "%-34s %3zu cells x %2d trials: %6.1f s wall, %6.1f s cpu; named %s, gap %.3g -> %.3g\n",
      c.name.c_str(), cells.cells.size(), c.trials, wall, cpu_s() - c0,
      named.empty() ? "(nothing)" : named.c_str(), d.gap_before, d.gap_after);
  std::fflush(stdout);
  std::filesystem::remove_all(dir);
}

}  // namespace

int main(int argc, char** argv) {
  const bool quick = argc == 2 && std::strcmp(argv[1], "--quick") == 0;
  if (argc > 2 || (argc == 2 && !quick)) {
    std::fprintf(stderr, "gap_bench: '%s' is not an option; usage: gap_bench [--quick]\n",
                 argv[argc > 2 && quick ? 2 : 1]);
    return 2;
  }
  const model::EffectSpec amp{"amplifier", {{"cutoff_hz", 3000}, {"order", 2}}};
  const model::EffectSpec tilt{"tilt", {{"angle_deg", 1.5}}};
  if (quick) {
    run({"20-cell sweep", 4, 5, 3, false, 25e3, {amp}});
    return 0;
  }
  run({"paper-size sweep (target <= 60 s)", 8, 10, 10, false, 100e3, {amp}});
  run({"20-cell sweep (target <= 15 s)", 4, 5, 4, false, 25e3, {amp}});
  run({"cells: 40", 8, 5, 4, false, 25e3, {amp}});
  run({"cells: 80", 8, 10, 4, false, 25e3, {amp}});
  run({"trials: 3", 8, 5, 3, false, 25e3, {amp}});
  run({"trials: 5", 8, 5, 5, false, 25e3, {amp}});
  run({"trials: 10", 8, 5, 10, false, 25e3, {amp}});
  run({"a pair: amplifier + tilt", 8, 5, 4, true, 25e3, {amp, tilt}});
  // the paper-size sweep with the other effects (the stage's K and C: a 1.8 kHz resonance)
  const model::EffectSpec compliance{"actuator_compliance",
                                     {{"stiffness_n_m", 5.7e6}, {"damping_n_s_m", 230}}};
  const model::EffectSpec stribeck{"stribeck",
                                   {{"static_over_kinetic", 1.5}, {"stribeck_velocity_m_s", 5e-3}}};
  const model::EffectSpec spread{"friction_spread", {{"relative_sd", 0.1}}};
  run({"paper size: actuator_compliance", 8, 10, 10, false, 100e3, {compliance}});
  run({"paper size: stribeck", 8, 10, 10, false, 100e3, {stribeck}});
  run({"paper size: friction_spread", 8, 10, 10, false, 100e3, {spread}});
  run({"paper size: amplifier + stribeck", 8, 10, 10, false, 100e3, {amp, stribeck}});
  run({"paper size: compliance + stribeck", 8, 10, 10, false, 100e3, {compliance, stribeck}});
  run({"paper size: amplifier + spread", 8, 10, 10, false, 100e3, {amp, spread}});
  run({"paper size: stribeck + spread", 8, 10, 10, false, 100e3, {stribeck, spread}});
  return 0;
}
