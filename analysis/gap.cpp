#include "analysis/gap.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <iomanip>
#include <sstream>

namespace idm::analysis {

namespace {
CellPrediction from_features(const TrialFeatures& f) {
  CellPrediction p;
  p.steady_step_m = f.steady_step_m;
  p.first_step_m = f.first_step_m;
  p.reverse_m = f.reverse_m;
  p.transient_cycles = f.transient_cycles;
  p.region = f.region;
  return p;
}
std::vector<CellPrediction> from_features(const std::vector<TrialFeatures>& f) {
  std::vector<CellPrediction> out;
  for (const TrialFeatures& t : f) out.push_back(from_features(t));
  return out;
}
// Mean and sample variance (n - 1) of the steady steps of some trials (0 and 0 for none).
struct StepMoments {
  double mean = 0, var = 0;
};
StepMoments step_moments(const std::vector<TrialFeatures>& trials) {
  StepMoments m;
  const std::size_t n = trials.size();
  if (n == 0) return m;
  for (const TrialFeatures& t : trials) m.mean += t.steady_step_m;
  m.mean /= static_cast<double>(n);
  double ss = 0;
  for (const TrialFeatures& t : trials) ss += (t.steady_step_m - m.mean) * (t.steady_step_m - m.mean);
  m.var = n > 1 ? ss / static_cast<double>(n - 1) : 0.0;
  return m;
}

}  // namespace

LogVarianceMoments log_sample_variance_moments(int dof) {
  // log(chi2_k / k) = log(chi2_k / 2) - log(k / 2): mean psi(k/2) - log(k/2), variance psi'(k/2).
  // psi and psi' at k/2 from psi(1/2) = -gamma - 2 log 2, psi(1) = -gamma, psi'(1/2) = pi^2/2,
  // psi'(1) = pi^2/6 and x -> x + 1: psi += 1/x, psi' -= 1/x^2.
  constexpr double kEulerGamma = 0.57721566490153286061;
  LogVarianceMoments m;
  if (dof < 1) return m;
  double x = dof % 2 == 1 ? 0.5 : 1.0;
  double psi = dof % 2 == 1 ? -kEulerGamma - 2.0 * std::log(2.0) : -kEulerGamma;
  double psi1 = dof % 2 == 1 ? M_PI * M_PI / 2.0 : M_PI * M_PI / 6.0;
  const double half = 0.5 * dof;
  while (x < half - 1e-9) {
    psi += 1.0 / x;
    psi1 -= 1.0 / (x * x);
    x += 1.0;
  }
  m.mean = psi - std::log(half);
  m.sd = std::sqrt(psi1);
  return m;
}

double fit_step_scale(const SweepCells& sweep, const std::vector<CellPrediction>& pred) {
  // Weighted least squares: each cell by the inverse of its measured step variance (never below
  // the reading noise), so that a cell whose steps scatter does not pull the scale off the cells
  // that pin it.
  const double noise_var = 2.0 * sweep.reading_sd_m * sweep.reading_sd_m;
  double num = 0, den = 0;
  for (std::size_t c = 0; c < sweep.cells.size(); ++c) {
    if (pred[c].region == model::Region::Cutoff) continue;
    const std::vector<TrialFeatures>& train = sweep.cells[c].train;
    if (train.empty()) continue;
    const double w = 1.0 / (noise_var + step_moments(train).var + pred[c].step_sd_m * pred[c].step_sd_m);
    for (const TrialFeatures& t : train) {
      num += w * t.steady_step_m * pred[c].steady_step_m;
      den += w * pred[c].steady_step_m * pred[c].steady_step_m;
    }
  }
  return den > 0 ? num / den : 1.0;
}

double fit_step_scale(const SweepCells& sweep, const std::vector<TrialFeatures>& pred) {
  return fit_step_scale(sweep, from_features(pred));
}

GapEvaluation evaluate_gap(const SweepCells& sweep, const std::vector<CellPrediction>& pred, double scale,
                           TrialSet set) {
  GapEvaluation out;
  out.step_scale = scale;
  const double step_sd = std::sqrt(2.0) * sweep.reading_sd_m;
  double sum2 = 0;
  for (std::size_t c = 0; c < sweep.cells.size(); ++c) {
    const Cell& cell = sweep.cells[c];
    const std::vector<TrialFeatures>& trials = set == TrialSet::Test ? cell.test : cell.train;
    CellResidual r;
    r.key = cell.key;
    const int n = static_cast<int>(trials.size());
    r.trials = n;
    const StepMoments moments = step_moments(trials);
    const double mean = moments.mean;
    const double sd = std::sqrt(moments.var);
    r.measured_step_m = mean;
    r.measured_step_sd_m = sd;
    r.model_step_m = scale * pred[c].steady_step_m;
    r.model_step_sd_m = std::fabs(scale) * pred[c].step_sd_m;
    r.measured_region = set == TrialSet::Test ? cell.test_region : cell.train_region;
    r.model_region = pred[c].region;
    const double expected_var = step_sd * step_sd + r.model_step_sd_m * r.model_step_sd_m;
    // The mean's uncertainty from what was measured (never below the noise), so that a model cannot
    // explain a mean it misses by predicting a wide spread; the spread term below scores that.
    double all_mean = 0, all_ss = 0;
    const std::size_t all_n = cell.train.size() + cell.test.size();
    for (const auto* v : {&cell.train, &cell.test})
      for (const TrialFeatures& t : *v) all_mean += t.steady_step_m / all_n;
    for (const auto* v : {&cell.train, &cell.test})
      for (const TrialFeatures& t : *v) all_ss += (t.steady_step_m - all_mean) * (t.steady_step_m - all_mean);
    const double sd_all = all_n > 1 ? std::sqrt(all_ss / (all_n - 1)) : 0.0;
    const double mean_var = std::max({step_sd * step_sd, sd * sd, sd_all * sd_all, r.model_step_sd_m * r.model_step_sd_m});
    const double d = (mean - r.model_step_m) / std::sqrt(mean_var / std::max(1, n));
    // The spread against the one expected: log ratio of the variances (regularized by the noise so
    // that identical quantized readings do not count) in units of the exact sampling error of a
    // log sample variance with n - 1 degrees of freedom (sqrt(psi'((n-1)/2)); 2.2 for two trials,
    // sqrt(2 / (n - 1)) for many).
    double spread = 0;
    if (n > 1) {
      const double q = step_sd * step_sd;
      spread = std::log((sd * sd + q) / (expected_var + q)) / log_sample_variance_moments(n - 1).sd;
    }
    const double label = r.measured_region == r.model_region ? 0.0 : kSignificantResidual;
    r.residual = std::sqrt(d * d + spread * spread + label * label);
    r.significant = r.residual > kSignificantResidual;
    sum2 += r.residual * r.residual;
    out.cells.push_back(r);
  }
  out.gap = out.cells.empty() ? 0.0 : std::sqrt(sum2 / out.cells.size());
  return out;
}

GapEvaluation evaluate_gap(const SweepCells& sweep, const std::vector<TrialFeatures>& pred, double scale) {
  return evaluate_gap(sweep, from_features(pred), scale, TrialSet::Test);
}

std::vector<TrialFeatures> predict_all(const SweepCells& sweep, const model::SimConfig& sim) {
  std::vector<TrialFeatures> pred;
  pred.reserve(sweep.cells.size());
  for (const Cell& c : sweep.cells) pred.push_back(predict_cell(sweep.stage.stage, sim, c));
  return pred;
}

GapEvaluation baseline_gap(const SweepCells& sweep, int threads) {
  model::SimConfig ideal;  // rigid actuator, Coulomb friction: the impulse model's event simulation
  const std::vector<CellPrediction> pred = predict_sweep(sweep, ideal, threads);
  return evaluate_gap(sweep, pred, fit_step_scale(sweep, pred));
}

std::string where_summary(const GapEvaluation& eval) {
  std::vector<const CellResidual*> sig;
  for (const CellResidual& r : eval.cells)
    if (r.significant) sig.push_back(&r);
  std::ostringstream s;
  if (sig.empty()) {
    s << "The model follows the stage within the measurement's noise at all " << eval.cells.size()
      << " cells (gap " << std::setprecision(2) << eval.gap << ").";
    return s.str();
  }
  double f_lo = 1e300, f_hi = 0, d_lo = 1, d_hi = 0;
  std::map<std::string, int> by_region;
  int labels = 0;
  for (const CellResidual* r : sig) {
    f_lo = std::min(f_lo, r->key.freq_hz);
    f_hi = std::max(f_hi, r->key.freq_hz);
    d_lo = std::min(d_lo, r->key.duty);
    d_hi = std::max(d_hi, r->key.duty);
    ++by_region[model::region_name(r->model_region)];
    if (r->measured_region != r->model_region) ++labels;
  }
  std::string regions;
  for (const auto& [name, n] : by_region) regions += (regions.empty() ? "" : ", ") + std::to_string(n) + " " + name;
  s << "The model parts from the stage at " << sig.size() << " of " << eval.cells.size() << " cells, between "
    << f_lo << " and " << f_hi << " Hz and duty " << d_lo << " to " << d_hi << " (model regions: " << regions
    << "; " << labels << " with the wrong region label).";
  return s.str();
}

}  // namespace idm::analysis
