#include "analysis/gap.h"

#include <algorithm>
#include <cmath>

#include "model/stage.h"

namespace idm::analysis {

namespace {

// Mean and sample variance (n - 1) of the steady steps of some trials (0 and 0 for none).
struct StepMoments {
  double mean = 0, var = 0;
};
StepMoments moments_of(const std::vector<double>& v) {
  StepMoments m;
  const std::size_t n = v.size();
  if (n == 0) return m;
  for (double x : v) m.mean += x;
  m.mean /= static_cast<double>(n);
  double ss = 0;
  for (double x : v) ss += (x - m.mean) * (x - m.mean);
  m.var = n > 1 ? ss / static_cast<double>(n - 1) : 0.0;
  return m;
}
StepMoments step_moments(const std::vector<TrialFeatures>& trials) {
  std::vector<double> steps;
  steps.reserve(trials.size());
  for (const TrialFeatures& t : trials) steps.push_back(t.steady_step_m);
  return moments_of(steps);
}

StepMoments all_trials(const Cell& cell) {
  std::vector<TrialFeatures> all = cell.train;
  all.insert(all.end(), cell.test.begin(), cell.test.end());
  return step_moments(all);
}

// log Phi(x), the standard normal's distribution function, exact far into the lower tail.
double log_normal_cdf(double x) {
  if (x > -30) return std::log(0.5 * std::erfc(-x / std::sqrt(2.0)));
  const double x2 = x * x;  // the asymptotic series: Phi(x) = phi(x) / -x (1 - 1/x^2 + 3/x^4 ...)
  return -0.5 * x2 - std::log(-x) - 0.5 * std::log(2 * M_PI) + std::log1p(-1 / x2 + 3 / (x2 * x2));
}

// The x with log Phi(x) = log_p (log_p <= log 1/2), by bisection: log Phi(x) < -x^2 / 2 below -1,
// so x lies above -sqrt(-2 log_p) - 1, however far out.
double normal_quantile_of_log(double log_p) {
  double lo = -std::sqrt(-2.0 * log_p) - 1.0, hi = 0;
  for (int i = 0; i < 64; ++i) {
    const double mid = 0.5 * (lo + hi);
    (log_normal_cdf(mid) < log_p ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

double log_sum_exp(const std::vector<double>& v) {
  const double top = *std::max_element(v.begin(), v.end());
  double sum = 0;
  for (double x : v) sum += std::exp(x - top);
  return top + std::log(sum);
}

// The steady step of one trial as a model with a friction spread predicts it: the quadrature's
// steps (CellPrediction::trial_steps_m) joined linearly in the friction's normal variate (straight
// on beyond the ends, so a step that sets in between two points sets in between them), taken at
// kFinePoints points of a standard normal, each smoothed by a normal of `smoothing_sd_m` (the
// noise on a step and the model's own error). A mixture the quadrature leaves lopsided (one point
// of six breaks loose near the cut-off) is scored as the distribution it is, not by its mean.
class TrialStepDistribution {
 public:
  TrialStepDistribution(const std::vector<double>& quadrature_steps_m, double smoothing_sd_m)
      : h_(smoothing_sd_m) {
    static const std::vector<double> fine = normal_points(kFinePoints);
    const std::vector<double>& z = spread_quadrature();
    for (double u : fine) {
      std::size_t k = 1;
      while (k + 1 < z.size() && u > z[k]) ++k;
      const double w = (u - z[k - 1]) / (z[k] - z[k - 1]);
      steps_m_.push_back(quadrature_steps_m[k - 1] +
                         w * (quadrature_steps_m[k] - quadrature_steps_m[k - 1]));
    }
  }

  // Phi^-1(F(y)): a standard normal variate when y is drawn from the distribution (computed from
  // the smaller tail, so a step far outside gets its full distance), and dz/dy there.
  struct Score {
    double z = 0, dz_dy_per_m = 0;
  };
  Score score(double step_m) const {
    const double log_w = -std::log(static_cast<double>(steps_m_.size()));
    std::vector<double> lower, upper, density;
    for (double s : steps_m_) {
      const double x = (step_m - s) / h_;
      lower.push_back(log_w + log_normal_cdf(x));
      upper.push_back(log_w + log_normal_cdf(-x));
      density.push_back(log_w - 0.5 * x * x);
    }
    const double log_lower = log_sum_exp(lower), log_upper = log_sum_exp(upper);
    Score out;
    out.z = log_lower < log_upper ? normal_quantile_of_log(log_lower)
                                  : -normal_quantile_of_log(log_upper);
    // p(y) / phi(z), both with their 1 / sqrt(2 pi)
    out.dz_dy_per_m = std::exp(log_sum_exp(density) + 0.5 * out.z * out.z) / h_;
    return out;
  }

 private:
  static constexpr int kFinePoints = 64;
  double h_;
  std::vector<double> steps_m_;
};

// A cell's weight in the calibration: the inverse of its steps' variance, measured or, when the
// model predicts a wider spread of the trials (a friction spread), predicted: a few training trials
// that happened to agree (all stuck in a cell where one trial in six breaks loose) do not pull
// alpha off every other cell.
double calibration_weight(double noise_var, const std::vector<TrialFeatures>& train,
                          const CellPrediction& p) {
  return 1.0 / (noise_var + std::max(step_moments(train).var, p.step_sd_m * p.step_sd_m));
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

Calibration fit_calibration(const SweepCells& sweep, const std::vector<CellPrediction>& pred,
                            double mu_sim, bool fit_mu) {
  // step = a s + b q with a = alpha, b = alpha (mu - mu_sim): weighted normal equations.
  const double noise_var = 2.0 * sweep.reading_sd_m * sweep.reading_sd_m;
  double ss = 0, sq = 0, qq = 0, ys = 0, yq = 0;
  for (std::size_t c = 0; c < sweep.cells.size(); ++c) {
    const std::vector<TrialFeatures>& train = sweep.cells[c].train;
    if (train.empty()) continue;
    const double w = calibration_weight(noise_var, train, pred[c]);
    const double s = pred[c].steady_step_m, q = pred[c].mu_slope_m;
    for (const TrialFeatures& t : train) {
      ss += w * s * s;
      sq += w * s * q;
      qq += w * q * q;
      ys += w * t.steady_step_m * s;
      yq += w * t.steady_step_m * q;
    }
  }
  Calibration c;
  c.mu_sim = c.mu = mu_sim;
  c.alpha = ss > 0 ? ys / ss : 1.0;
  const double det = ss * qq - sq * sq;
  if (!fit_mu || !(det > 1e-6 * ss * qq)) return c;  // mu and alpha indistinguishable: mu stays
  const double a = (ys * qq - yq * sq) / det, b = (yq * ss - ys * sq) / det;
  if (!(a > 0)) return c;
  // a step of at most 30 %, and never past the largest mu a stage may have (the model is not
  // defined there)
  const double dmu = std::clamp(b / a, -0.3 * mu_sim,
                                std::min(0.3 * mu_sim, model::kMaxFrictionCoefficient - mu_sim));
  c.mu = mu_sim + dmu;
  // alpha again for the (possibly clamped) mu
  double num = 0, den = 0;
  for (std::size_t k = 0; k < sweep.cells.size(); ++k) {
    const std::vector<TrialFeatures>& train = sweep.cells[k].train;
    if (train.empty()) continue;
    const double w = calibration_weight(noise_var, train, pred[k]);
    const double p = pred[k].steady_step_m + dmu * pred[k].mu_slope_m;
    for (const TrialFeatures& t : train) {
      num += w * t.steady_step_m * p;
      den += w * p * p;
    }
  }
  c.alpha = den > 0 ? num / den : a;
  return c;
}

GapEvaluation evaluate_gap(const SweepCells& sweep, const std::vector<CellPrediction>& pred,
                           const Calibration& calib, TrialSet set) {
  GapEvaluation out;
  out.calibration = calib;
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
    const double sd = std::sqrt(moments.var);
    r.measured_step_m = moments.mean;
    r.measured_step_sd_m = sd;
    r.model_step_m = calib.step(pred[c]);
    r.model_step_sd_m = std::fabs(calib.alpha) * pred[c].step_sd_m;
    r.measured_region = set == TrialSet::Test ? cell.test_region : cell.train_region;
    r.model_region = pred[c].region;
    const double expected_var = step_sd * step_sd + r.model_step_sd_m * r.model_step_sd_m;
    // The mean's uncertainty from what was measured (never below the noise), never from what the
    // model predicts: a model cannot explain a mean it misses by predicting a wide spread; the
    // spread term scores the spread.
    const double sd_all = std::sqrt(all_trials(cell).var);
    const double mean_var = std::max({step_sd * step_sd, sd * sd, sd_all * sd_all});
    const double model_var =
        kModelErrorM * kModelErrorM + std::pow(kModelErrorRel * r.model_step_m, 2);
    r.se_m = std::sqrt(mean_var / std::max(1, n) + model_var);
    if (!pred[c].trial_steps_m.empty() && n > 0) {
      // A friction spread: every trial scored against the predicted distribution (its normal
      // score); the mean of the scores against 1 / sqrt(n) (or the scores' own spread when they
      // scatter wider), their spread against 1.
      std::vector<double> quadrature;
      for (double step : pred[c].trial_steps_m)
        quadrature.push_back(calib.step_at(step, pred[c].mu_slope_m));
      const TrialStepDistribution dist(quadrature, std::sqrt(step_sd * step_sd + model_var));
      std::vector<double> z, z_all;
      double q = 0;
      for (const auto* set_of : {&cell.train, &cell.test})
        for (const TrialFeatures& t : *set_of) {
          const TrialStepDistribution::Score sc = dist.score(t.steady_step_m);
          z_all.push_back(sc.z);
          if (set_of != &trials) continue;
          z.push_back(sc.z);
          q += std::pow(step_sd * sc.dz_dy_per_m, 2) / n;  // the noise on a step, in scores
        }
      const StepMoments scores = moments_of(z);
      const double var_z = scores.var;
      r.mean_z = scores.mean * std::sqrt(n / std::max({1.0, var_z, moments_of(z_all).var}));
      q = std::max(q, 1e-12);  // (far out the density can underflow)
      if (n > 1)
        r.spread_z = std::log((var_z + q) / (1 + q)) / log_sample_variance_moments(n - 1).sd;
      r.se_m = std::sqrt(std::max(mean_var, r.model_step_sd_m * r.model_step_sd_m) / n + model_var);
    } else {
      r.mean_z = n > 0 ? (moments.mean - r.model_step_m) / r.se_m : 0.0;
      // The spread against the one expected: log ratio of the variances (regularized by the noise
      // so that identical quantized readings do not count) in units of the exact sampling error of
      // a log sample variance with n - 1 degrees of freedom.
      if (n > 1) {
        const double q = step_sd * step_sd;
        r.spread_z =
            std::log((sd * sd + q) / (expected_var + q)) / log_sample_variance_moments(n - 1).sd;
      }
    }
    r.label = r.measured_region == r.model_region ? 0.0 : kSignificantResidual;
    r.residual = std::sqrt(r.mean_z * r.mean_z + r.spread_z * r.spread_z + r.label * r.label);
    r.significant = r.residual > kSignificantResidual;
    sum2 += r.residual * r.residual;
    out.cells.push_back(r);
  }
  out.gap = out.cells.empty() ? 0.0 : std::sqrt(sum2 / static_cast<double>(out.cells.size()));
  return out;
}

GapParts gap_parts(const GapEvaluation& evaluation) {
  GapParts p;
  if (evaluation.cells.empty()) return p;
  for (const CellResidual& r : evaluation.cells) {
    p.mean += r.mean_z * r.mean_z;
    p.spread += r.spread_z * r.spread_z;
    p.label += r.label * r.label;
  }
  const double n = static_cast<double>(evaluation.cells.size());
  p.mean = std::sqrt(p.mean / n);
  p.spread = std::sqrt(p.spread / n);
  p.label = std::sqrt(p.label / n);
  return p;
}

FittedModel fit_model(const SweepCells& sweep, ModelConfig model, int threads, int rounds) {
  // mu by proposals checked exactly: the linearized fit (the ideal model's slope) proposes a mu,
  // the model is simulated there and alpha fitted alone; a proposal that does not lower the
  // training gap is halved once, then the search ends. The reported calibration has no
  // linearization left in it.
  auto exact = [&](double mu) {
    FittedModel f;
    f.model = model;
    f.model.stage.friction_coefficient = mu;
    f.predictions = predict_sweep(sweep, f.model, threads);
    f.calibration = fit_calibration(sweep, f.predictions, mu, false);
    f.train = evaluate_gap(sweep, f.predictions, f.calibration, TrialSet::Train);
    return f;
  };
  FittedModel best = exact(model.stage.friction_coefficient);
  // With effects, the ideal model's slope can be far from the model's own (a compliant actuator
  // with Stribeck friction): once the model has been simulated at a second mu, each cell's slope
  // is the secant through the two.
  FittedModel other;
  for (int round = 0; round < rounds; ++round) {
    const double mu = best.model.stage.friction_coefficient;
    std::vector<CellPrediction> linear = best.predictions;
    const double dmu = mu - other.model.stage.friction_coefficient;
    if (!model.effects.empty() && !other.predictions.empty() && std::fabs(dmu) > 1e-6 * mu)
      for (std::size_t c = 0; c < linear.size(); ++c)
        linear[c].mu_slope_m =
            (best.predictions[c].steady_step_m - other.predictions[c].steady_step_m) / dmu;
    const double proposal = fit_calibration(sweep, linear, mu).mu;
    if (std::fabs(proposal - mu) < 1e-4 * mu) break;
    FittedModel next = exact(proposal);
    if (!(next.train.gap < best.train.gap)) {
      other = std::move(next);
      next = exact(0.5 * (proposal + mu));
    }
    if (!(next.train.gap < best.train.gap)) {
      if (model.effects.empty()) break;
      other = std::move(next);  // the secant through it may propose better
      continue;
    }
    other = std::move(best);
    best = std::move(next);
  }
  best.test = evaluate_gap(sweep, best.predictions, best.calibration, TrialSet::Test);
  return best;
}

ModelConfig nominal_model(const SweepCells& sweep) {
  ModelConfig m;
  m.stage = sweep.stage.stage;
  m.chain_rate_hz = 0;  // score_rate_hz of the effects
  return m;
}

FittedModel fit_baseline(const SweepCells& sweep, int threads) {
  return fit_model(sweep, nominal_model(sweep), threads, 4);
}

double systematic_gap(const FittedModel& m) {
  if (m.test.cells.empty()) return 0;
  double s = 0;
  for (std::size_t c = 0; c < m.test.cells.size(); ++c) {
    const CellResidual& a = m.train.cells[c];
    const CellResidual& b = m.test.cells[c];
    s += a.mean_z * b.mean_z + a.spread_z * b.spread_z + a.label * b.label;
  }
  return std::sqrt(std::max(0.0, s / static_cast<double>(m.test.cells.size())));
}

}  // namespace idm::analysis
