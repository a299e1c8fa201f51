#include "analysis/trial_features.h"

#include <algorithm>
#include <cmath>

namespace idm::analysis {

double position_at(const TrialSeries& s, double t) {
  const auto it = std::lower_bound(s.t_s.begin(), s.t_s.end(), t);
  if (it == s.t_s.begin()) return s.x_m.front();
  if (it == s.t_s.end()) return s.x_m.back();
  const std::size_t i = static_cast<std::size_t>(it - s.t_s.begin());
  const double t0 = s.t_s[i - 1], t1 = s.t_s[i];
  const double w = (t - t0) / (t1 - t0);
  return s.x_m[i - 1] + w * (s.x_m[i] - s.x_m[i - 1]);
}

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  const std::size_t n = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + n, v.end());
  if (v.size() % 2) return v[n];
  const double hi = v[n];
  std::nth_element(v.begin(), v.begin() + n - 1, v.end());
  return 0.5 * (hi + v[n - 1]);
}

std::vector<double> rest_instants(double freq_hz, double duty, int cycles) {
  const double T = 1.0 / freq_hz;
  const double anchor0 = duty < 0.5 ? 0.0 : duty * T;
  const int anchors = duty < 0.5 ? cycles : cycles - 1;  // anchors after the start, k = 1..anchors
  std::vector<double> out{0.0};
  if (anchor0 > 0) out.push_back(anchor0);
  for (int k = 1; k <= anchors; ++k) out.push_back(k * T + anchor0);
  return out;
}

double step_tolerance_m(double step_m, double resolution_m, double noise_m) {
  // A rest reading carries the sensor's noise and quantization; a step, two of them.
  const double reading_sd = std::sqrt(noise_m * noise_m + resolution_m * resolution_m / 12.0);
  return 4.0 * std::sqrt(2.0) * reading_sd + 0.02 * std::fabs(step_m);
}

TrialFeatures features_from_marks(const std::vector<double>& marks, double resolution_m,
                                  double noise_m) {
  TrialFeatures f;
  std::vector<double> steps;
  for (std::size_t k = 1; k < marks.size(); ++k) steps.push_back(marks[k] - marks[k - 1]);
  const int m = static_cast<int>(steps.size());
  if (m == 0) return f;
  f.first_step_m = steps.front();
  const std::vector<double> tail(steps.begin() + m / 2, steps.end());
  f.steady_step_m = median(tail);
  double ss = 0;
  for (double v : tail) ss += (v - f.steady_step_m) * (v - f.steady_step_m);
  f.steady_sd_m = tail.size() > 1 ? std::sqrt(ss / static_cast<double>(tail.size() - 1)) : 0.0;
  const double tol = step_tolerance_m(f.steady_step_m, resolution_m, noise_m);
  f.transient_cycles = 0;
  for (int k = m - 1; k >= 0; --k)
    if (std::fabs(steps[static_cast<std::size_t>(k)] - f.steady_step_m) > tol) {
      f.transient_cycles = k + 1;
      break;
    }
  // Region: cut-off when the steady step is within the noise (no net motion after the
  // transient), one-step when every step from the second on is the steady one, multi-step
  // otherwise.
  if (std::fabs(f.steady_step_m) <= tol && f.transient_cycles <= 2)
    f.region = model::Region::Cutoff;
  else if (std::fabs(f.steady_step_m) <= tol)
    f.region = model::Region::MultiStep;
  else
    f.region = f.transient_cycles <= 1 ? model::Region::OneStep : model::Region::MultiStep;
  return f;
}

namespace {

void check_covers(const TrialInfo& info, const TrialSeries& s) {
  const double T = 1.0 / info.freq_hz;
  const int n = info.cycles;
  if (s.t_s.empty() || s.t_s.front() > 1e-9 * T || s.t_s.back() < n * T * (1 - 1e-9))
    throw InputError(info.id + ": the trial file does not cover its burst (t from 0 to " +
                     std::to_string(n * T) + " s)");
}

// Index of the last sample at or before t (t within a billionth of a period counts as at).
std::size_t last_at_or_before(const TrialSeries& s, double t, double period_s) {
  const auto it = std::upper_bound(s.t_s.begin(), s.t_s.end(), t + 1e-9 * period_s);
  return it == s.t_s.begin() ? 0 : static_cast<std::size_t>(it - s.t_s.begin()) - 1;
}

}  // namespace

std::vector<double> read_instants(const TrialInfo& info, const TrialSeries& s) {
  check_covers(info, s);
  const double T = 1.0 / info.freq_hz;
  std::vector<double> out;
  for (double t : rest_instants(info.freq_hz, info.duty, info.cycles))
    out.push_back(t == 0.0 ? 0.0 : s.t_s[last_at_or_before(s, t, T)]);
  return out;
}

TrialFeatures trial_features(const TrialInfo& info, const TrialSeries& s, double resolution_m,
                             double noise_m) {
  check_covers(info, s);
  const double T = 1.0 / info.freq_hz;
  const int n = info.cycles;
  // Start: the mean of the samples at rest before t = 0 (or the sample at 0).
  double x0 = 0;
  int rest = 0;
  for (std::size_t i = 0; i < s.size() && s.t_s[i] <= 0; ++i) {
    x0 += s.x_m[i];
    ++rest;
  }
  x0 = rest ? x0 / rest : position_at(s, 0.0);
  auto at_or_before = [&](double t) { return s.x_m[last_at_or_before(s, t, T)] - x0; };
  std::vector<double> marks;
  for (double t : rest_instants(info.freq_hz, info.duty, n))
    marks.push_back(t == 0.0 ? 0.0 : at_or_before(t));
  TrialFeatures f = features_from_marks(marks, resolution_m, noise_m);
  f.cycle_end_m.resize(static_cast<std::size_t>(n));
  for (int k = 1; k <= n; ++k) f.cycle_end_m[static_cast<std::size_t>(k - 1)] = at_or_before(k * T);
  // The net direction: the steady step, or the total displacement when there is none.
  const double tol = step_tolerance_m(f.steady_step_m, resolution_m, noise_m);
  const double net = std::fabs(f.steady_step_m) > tol ? f.steady_step_m : f.cycle_end_m.back();
  const double dir = net >= 0 ? 1.0 : -1.0;
  for (std::size_t i = 0; i < s.size(); ++i)
    if (s.t_s[i] >= 0 && s.t_s[i] <= n * T)
      f.reverse_m = std::max(f.reverse_m, -dir * (s.x_m[i] - x0));
  const double reading_sd = std::sqrt(noise_m * noise_m + resolution_m * resolution_m / 12.0);
  f.reverse_m = std::max(0.0, f.reverse_m - 2.0 * reading_sd);
  return f;
}

model::Region majority_region(const std::vector<model::Region>& regions) {
  int votes[3] = {0, 0, 0};
  for (model::Region r : regions) ++votes[static_cast<int>(r)];
  int best = 0;
  for (int i = 1; i < 3; ++i)
    if (votes[i] >= votes[best]) best = i;
  return static_cast<model::Region>(best);
}

}  // namespace idm::analysis
