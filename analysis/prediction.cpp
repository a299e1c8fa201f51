#include "analysis/prediction.h"

#include <algorithm>
#include <array>
#include <cmath>

#include "analysis/parallel.h"
#include "model/waveform.h"

namespace idm::analysis {

namespace {

TrialFeatures one_trial(const SweepCells& sweep, model::SimulatedStage& stage, const Cell& cell, double x0) {
  const model::TriangleWave w{cell.key.freq_hz, cell.key.duty, cell.key.stroke_m, cell.cycles};
  const double T = w.period_s();
  const double rate = cell.sample_rate_hz > 0 ? cell.sample_rate_hz : 20.0 * cell.key.freq_hz;
  stage.reset(x0, 1);
  const std::vector<double> corners = w.corner_times_s();
  const long n_samples = static_cast<long>(std::floor(w.duration_s() * rate * (1 + 1e-12))) + 1;
  TrialSeries s;
  s.t_s.reserve(static_cast<std::size_t>(n_samples) + 1);
  s.x_m.reserve(static_cast<std::size_t>(n_samples) + 1);
  double t = 0;
  std::size_t next = 1;  // corners[0] = 0
  for (long j = 0; j <= n_samples; ++j) {
    double tj = static_cast<double>(j) / rate;
    if (j == n_samples) {
      if (s.t_s.back() >= w.duration_s() * (1 - 1e-12)) break;
      tj = w.duration_s();  // the burst's end, so that the series covers it
    }
    while (next < corners.size() && corners[next] < tj - 1e-12 * T) {
      if (corners[next] > t) {
        stage.step(corners[next] - t, w.xi_m(corners[next]));
        t = corners[next];
      }
      ++next;
    }
    if (tj > t) {
      stage.step(tj - t, w.xi_m(tj));
      t = tj;
    }
    s.t_s.push_back(tj);
    s.x_m.push_back(stage.position_m());
  }
  s.xi_cmd_m.assign(s.t_s.size(), 0.0);
  TrialInfo info{"model", cell.key.freq_hz, cell.key.duty, cell.key.stroke_m, cell.cycles, rate, x0, ""};
  return trial_features(info, s, sweep.resolution_m, sweep.noise_m);
}

}  // namespace

namespace {
double dac_rate_hz(const model::SimConfig& sim) {
  const model::EffectSpec* q = sim.find("quantization");
  return q ? 2.0 * q->params.at("update_rate_hz") : 0.0;
}
}  // namespace

double internal_rate_for(const model::SimConfig& sim) {
  // A command smoothed by the actuator chain breaks the slider loose between two plant steps; the
  // rigid plant finds that moment to within a step, and the steady step's error grows with the
  // square of the step (measured against 16 MHz, cutoffs 0.8-30 kHz: up to 36 nm a cycle at
  // 100 kHz, within 1.5 nm at 2 MHz).
  return std::max(2e6, dac_rate_hz(sim));
}

double search_rate_for(const model::SimConfig& sim) {
  double rate = 50e3;
  if (const model::EffectSpec* a = sim.find("amplifier")) rate = std::max(rate, 20.0 * a->params.at("cutoff_hz"));
  return std::max(std::min(rate, 1e6), dac_rate_hz(sim));
}

const std::array<double, kSpreadTrials>& spread_quadrature() {
  // z_k = the normal quantiles at (k + 1/2) / K, rescaled so that their mean square is 1: K equally
  // weighted points with the mean and the variance of a standard normal.
  static const std::array<double, kSpreadTrials> z = [] {
    std::array<double, kSpreadTrials> q{};
    double ss = 0;
    for (int k = 0; k < kSpreadTrials; ++k) {
      const double p = (k + 0.5) / kSpreadTrials;
      // Inverse of the normal CDF by bisection on erfc (only once, K points).
      double lo = -10, hi = 10;
      for (int i = 0; i < 200; ++i) {
        const double mid = 0.5 * (lo + hi);
        (0.5 * std::erfc(-mid / std::sqrt(2.0)) < p ? lo : hi) = mid;
      }
      q[static_cast<std::size_t>(k)] = 0.5 * (lo + hi);
      ss += q[static_cast<std::size_t>(k)] * q[static_cast<std::size_t>(k)];
    }
    for (double& v : q) v /= std::sqrt(ss / kSpreadTrials);
    return q;
  }();
  return z;
}

CellPrediction predict_cell_exact(const SweepCells& sweep, const model::SimConfig& sim, const Cell& cell) {
  model::InterferometerParams exact;
  exact.resolution_m = 1e-12;
  model::SimConfig quiet = sim;
  quiet.noise_m = 0;
  std::vector<TrialFeatures> f;
  const model::EffectSpec* spread = sim.find("friction_spread");
  if (spread == nullptr) {
    model::SimulatedStage stage(sweep.stage.stage, exact, quiet);
    f.push_back(one_trial(sweep, stage, cell, 0.0));
  } else {
    // Friction along the guide: a burst covers a small part of the correlation length, so each
    // trial sees one friction coefficient, mu (1 + mean_shift + relative_sd n), n standard normal. Its
    // distribution is integrated by quadrature (K equally weighted normal quantiles), not sampled,
    // so the predicted mean and spread carry no sampling error of their own.
    const double sd = spread->params.at("relative_sd");
    const double shift = spread->params.at("mean_shift");
    quiet.effects.erase(std::remove_if(quiet.effects.begin(), quiet.effects.end(),
                                       [](const model::EffectSpec& e) { return e.name == "friction_spread"; }),
                        quiet.effects.end());
    f.reserve(kSpreadTrials);
    for (double z : spread_quadrature()) {
      model::StageParams stage = sweep.stage.stage;
      stage.friction_coefficient *= std::max(0.05, 1.0 + shift + sd * z);  // as model::GuideProfile bounds it
      model::SimulatedStage sim_stage(stage, exact, quiet);
      f.push_back(one_trial(sweep, sim_stage, cell, 0.0));
    }
  }
  const double trials = static_cast<double>(f.size());
  CellPrediction p;
  std::vector<model::Region> votes;
  for (const TrialFeatures& t : f) {
    p.steady_step_m += t.steady_step_m / trials;
    p.first_step_m += t.first_step_m / trials;
    p.reverse_m += t.reverse_m / trials;
    votes.push_back(t.region);
  }
  double ss = 0;
  for (const TrialFeatures& t : f) ss += (t.steady_step_m - p.steady_step_m) * (t.steady_step_m - p.steady_step_m);
  p.step_sd_m = std::sqrt(ss / trials);  // the spread of the integrated distribution (0 without spread)
  p.region = majority_region(votes);
  p.transient_cycles = f[f.size() / 2].transient_cycles;
  return p;
}

std::vector<CellPrediction> predict_sweep(const SweepCells& sweep, const model::SimConfig& sim, int threads) {
  std::vector<CellPrediction> out(sweep.cells.size());
  parallel_for(sweep.cells.size(), threads,
               [&](std::size_t c) { out[c] = predict_cell_exact(sweep, sim, sweep.cells[c]); });
  return out;
}

}  // namespace idm::analysis
