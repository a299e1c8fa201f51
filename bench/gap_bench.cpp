// gap_bench: idm-gap diagnose on a paper-size sweep (8 frequencies 100-800 Hz x 10 duties
// 0.05-0.50 x 10 trials, one stroke, 12 cycles, 100 kHz), read from disk, on both cores (std::thread)
// and on one for comparison. The stage hides a 3 kHz second-order amplifier.
//   gap_bench [--quick]   (--quick: 2 x 3 cells x 4 trials, CI checks that it runs)
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <string>

#include "analysis/selection.h"
#include "analysis/simulated_sweep.h"

using namespace idm;

namespace {
double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}
}  // namespace

int main(int argc, char** argv) {
  const bool quick = argc > 1 && std::strcmp(argv[1], "--quick") == 0;
  analysis::SweepPlan plan;
  if (quick) {
    plan.freqs_hz = {200, 600};
    plan.duties = {0.1, 0.25, 0.4};
    plan.trials = 4;
  } else {
    for (int f = 100; f <= 800; f += 100) plan.freqs_hz.push_back(f);
    for (int d = 1; d <= 10; ++d) plan.duties.push_back(0.05 * d);
    plan.trials = 10;
  }
  plan.cycles = 12;
  plan.sample_rate_hz = 100e3;
  plan.seed = 7;
  model::SimConfig sim;
  sim.noise_m = 2e-9;
  sim.seed = 7;
  sim.effects.push_back(model::complete_effect({"amplifier", {{"cutoff_hz", 3000}, {"order", 2}}}, "bench"));
  const auto dir = std::filesystem::temp_directory_path() / ("gap_bench_" + std::to_string(getpid()));
  std::filesystem::remove_all(dir);
  auto t0 = std::chrono::steady_clock::now();
  const std::size_t n = analysis::run_simulated_sweep(model::StageFile{}, sim, plan, dir.string());
  std::printf("sweep: %zu cells x %d trials, %zu trials written in %.1f s (setup, not timed)\n",
              plan.freqs_hz.size() * plan.duties.size(), plan.trials, n, seconds_since(t0));
  double two = 0;
  for (int threads : {2, 1}) {
    if (quick && threads == 1) break;
    t0 = std::chrono::steady_clock::now();
    const analysis::SweepCells cells = analysis::collect_cells(recording::read_dataset(dir.string()));
    const double load = seconds_since(t0);
    analysis::DiagnoseOptions opt;
    opt.fit.threads = threads;
    const analysis::Diagnosis d = analysis::diagnose(cells, opt);
    const double total = seconds_since(t0);
    std::string named;
    for (const model::EffectSpec& e : d.chosen) named += (named.empty() ? "" : "+") + e.name;
    std::printf("diagnose, %d thread%s: %.1f s (read and features %.1f s); named %s, gap %.3g -> %.3g\n", threads,
                threads > 1 ? "s" : "", total, load, named.empty() ? "(nothing)" : named.c_str(), d.gap_before,
                d.gap_after);
    if (threads == 2) two = total;
    else std::printf("speed-up on 2 threads: %.2fx\n", total / two);
  }
  std::filesystem::remove_all(dir);
  return 0;
}
