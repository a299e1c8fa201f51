#include "analysis/simulated_sweep.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <sstream>

#include "model/waveform.h"
#include "recording/dataset.h"

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
  if (!(p.plant_rate_hz >= 1e4 && p.plant_rate_hz <= 1e9))
    fail("plant_rate_hz: allowed [1e4, 1e9]");
  if (!(p.max_step_s > 0 && p.max_step_s <= 1e-3)) fail("max_step_s: allowed (0, 1e-3]");
}

namespace {

// One burst from rest, sampled at `rate_hz` from -pre_s to the burst's end + post_s: the stage is
// stepped to every corner of the triangle and to every sample, in steps of at most max_step_s.
recording::TrialSeries run_trial(model::SimulatedStage& stage, const model::TriangleWave& w,
                                 const SweepPlan& plan, const HiddenDistortion* distortion) {
  const double rate = plan.sample_rate_hz;
  const long n_pre = std::lround(plan.rest_before_s * rate);
  const double post_s = plan.rest_cycles_after * w.period_s();
  const long n_total = n_pre + std::lround((w.duration_s() + post_s) * rate) + 1;
  const std::vector<double> corners = w.corner_times_s();
  const double max_step =
      distortion ? std::min(plan.max_step_s, 1.0 / plan.plant_rate_hz) : plan.max_step_s;
  auto command = [&](double t) {
    return distortion ? distortion->command_m(t, w.xi_m(t)) : w.xi_m(t);
  };
  double t = -static_cast<double>(n_pre) / rate;
  // Instants closer than a billionth of a period are one (a step over a rounding error would make
  // up an actuator rate from it).
  const double min_step = 1e-9 * w.period_s();
  auto advance = [&](double t_end) {
    if (t_end - t < min_step) return;
    while (t < t_end) {
      const double t_next = t_end - t - max_step < min_step ? t_end : t + max_step;
      stage.step(t_next - t, command(t_next));
      t = t_next;
    }
  };
  recording::TrialSeries out;
  out.t_s.reserve(static_cast<std::size_t>(n_total));
  out.xi_cmd_m.reserve(static_cast<std::size_t>(n_total));
  out.x_m.reserve(static_cast<std::size_t>(n_total));
  std::size_t next = 0;
  for (long k = 0; k < n_total; ++k) {
    const double t_k = static_cast<double>(k - n_pre) / rate;
    while (next < corners.size() && corners[next] <= t_k + min_step) advance(corners[next++]);
    advance(t_k);
    out.t_s.push_back(t_k);
    out.xi_cmd_m.push_back(w.xi_m(t_k));
    out.x_m.push_back(stage.measured_m());
  }
  return out;
}

}  // namespace

std::size_t simulate_sweep(
    const model::StageFile& stage, const model::SimConfig& sim, const SweepPlan& plan,
    const std::function<void(const recording::TrialInfo&, recording::TrialSeries&&)>& sink) {
  validate(plan);
  const std::vector<double> strokes =
      plan.strokes_m.empty() ? std::vector<double>{stage.stage.stroke_m} : plan.strokes_m;
  model::SimConfig generator = sim;
  generator.internal_rate_hz = plan.plant_rate_hz;
  model::SimulatedStage sim_stage(stage.stage, stage.interferometer, generator);
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
          if (plan.distortion) plan.distortion->start(f, duty, stroke, x0);
          recording::TrialSeries series = run_trial(sim_stage, wave, plan, plan.distortion);
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
  return simulate_sweep(stage, sim, plan,
                        [&](const recording::TrialInfo& info, recording::TrialSeries&& series) {
                          recording::TrialInfo row = info;
                          row.id.clear();  // the writer names it
                          writer.add_trial(row, series);
                        });
}

}  // namespace idm::analysis
