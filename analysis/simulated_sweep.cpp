#include "analysis/simulated_sweep.h"

#include <random>
#include <sstream>

#include "recording/dataset.h"
#include "model/waveform.h"

namespace idm::analysis {

void validate(const SweepPlan& p) {
  auto fail = [](const std::string& what) { throw model::InputError(what); };
  if (p.freqs_hz.empty()) fail("freq: empty list, allowed one or more frequencies > 0");
  if (p.duties.empty()) fail("duty: empty list, allowed one or more duties in (0, 1)");
  for (double f : p.freqs_hz) model::validate(model::TriangleWave{f, 0.25, 1e-6, p.cycles});
  for (double d : p.duties) model::validate(model::TriangleWave{100.0, d, 1e-6, p.cycles});
  for (double s : p.strokes_m) model::validate(model::TriangleWave{100.0, 0.25, s, p.cycles});
  if (p.trials < 1 || p.trials > 100000)
    fail("trials: " + std::to_string(p.trials) + " is out of range, allowed [1, 100000]");
  if (p.cycles < 1 || p.cycles > 100000)
    fail("cycles: " + std::to_string(p.cycles) + " is out of range, allowed [1, 100000]");
  if (!(p.sample_rate_hz >= 1e3 && p.sample_rate_hz <= 10e6)) {
    std::ostringstream m;
    m << "sample-rate: " << p.sample_rate_hz << " is out of range, allowed [1000, 1e7]";
    fail(m.str());
  }
  for (double f : p.freqs_hz)
    if (p.sample_rate_hz < 10 * f) {
      std::ostringstream m;
      m << "sample-rate: " << p.sample_rate_hz << " Hz is too slow for " << f
        << " Hz, allowed >= 10 samples per period";
      fail(m.str());
    }
  if (!(p.guide_length_m > 0 && p.guide_length_m <= 10)) fail("guide_length_m: allowed (0, 10]");
}

std::size_t simulate_sweep(const model::StageFile& stage, const model::SimConfig& sim, const SweepPlan& plan,
                           const std::function<void(const recording::TrialInfo&, recording::TrialSeries&&)>& sink) {
  validate(plan);
  const std::vector<double> strokes =
      plan.strokes_m.empty() ? std::vector<double>{stage.stage.stroke_m} : plan.strokes_m;
  model::SimulatedStage sim_stage(stage.stage, stage.interferometer, sim);
  std::mt19937_64 rng(plan.seed);
  std::uniform_real_distribution<double> guide(0.0, plan.guide_length_m);
  std::size_t count = 0;
  for (double stroke : strokes)
    for (double f : plan.freqs_hz)
      for (double duty : plan.duties)
        for (int trial = 0; trial < plan.trials; ++trial) {
          const double x0 = guide(rng);
          sim_stage.reset(x0, rng());
          const model::TriangleWave wave{f, duty, stroke, plan.cycles};
          model::TrialSamples samples;
          sim_stage.run_burst(wave, plan.sample_rate_hz, plan.rest_before_s,
                              plan.rest_cycles_after * wave.period_s(), samples);
          recording::TrialSeries series;
          series.t_s = std::move(samples.t_s);
          series.xi_cmd_m = std::move(samples.xi_cmd_m);
          series.x_m = std::move(samples.x_m);
          recording::TrialInfo info;
          info.id = recording::trial_name(f, duty, stroke, trial);
          info.freq_hz = f;
          info.duty = duty;
          info.stroke_m = stroke;
          info.cycles = plan.cycles;
          info.sample_rate_hz = plan.sample_rate_hz;
          info.guide_pos_m = series.x_m.front();
          sink(info, std::move(series));
          ++count;
        }
  return count;
}

std::size_t run_simulated_sweep(const model::StageFile& stage, const model::SimConfig& sim,
                                const SweepPlan& plan, const std::string& out_dir) {
  validate(plan);
  model::StageFile written = stage;
  written.interferometer.noise_m = sim.noise_m;
  recording::DatasetWriter writer(out_dir, written);
  return simulate_sweep(stage, sim, plan, [&](const recording::TrialInfo& info, recording::TrialSeries&& series) {
    recording::TrialInfo row = info;
    row.id.clear();  // the writer names it
    writer.add_trial(row, series);
  });
}

}  // namespace idm::analysis
