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

TrialFeatures trial_features(const TrialInfo& info, const TrialSeries& s, double resolution_m,
                             double noise_m) {
  const double T = 1.0 / info.freq_hz;
  const int n = info.cycles;
  if (s.t_s.empty() || s.t_s.front() > 1e-9 * T || s.t_s.back() < n * T * (1 - 1e-9))
    throw InputError(info.id + ": the trial file does not cover its burst (t from 0 to " +
                     std::to_string(n * T) + " s)");
  TrialFeatures f;
  // Start: the mean of the samples at rest before t = 0 (or the sample at 0).
  double x0 = 0;
  int rest = 0;
  for (std::size_t i = 0; i < s.size() && s.t_s[i] <= 0; ++i) {
    x0 += s.x_m[i];
    ++rest;
  }
  x0 = rest ? x0 / rest : position_at(s, 0.0);
  // Steps are read where the steady cycle rests: just before each fast corner (the end of the slow
  // phase), at t = kT for duty < 0.5 and t = kT + duty T for duty >= 0.5, from the last sample at
  // or before that instant (the next one may already carry the jump of the corner).
  const double anchor0 = info.duty < 0.5 ? 0.0 : info.duty * T;
  const int anchors = info.duty < 0.5 ? n : n - 1;  // anchors after the start, k = 1..anchors
  auto at_or_before = [&](double t) {
    auto it = std::upper_bound(s.t_s.begin(), s.t_s.end(), t + 1e-9 * T);
    if (it == s.t_s.begin()) return s.x_m.front() - x0;
    return s.x_m[static_cast<std::size_t>(it - s.t_s.begin()) - 1] - x0;
  };
  f.cycle_end_m.resize(static_cast<std::size_t>(n));
  for (int k = 1; k <= n; ++k) f.cycle_end_m[k - 1] = at_or_before(k * T);
  std::vector<double> marks;  // positions at 0 (and the first anchor for reverse bursts), then anchors
  marks.push_back(0.0);
  if (anchor0 > 0) marks.push_back(at_or_before(anchor0));
  for (int k = 1; k <= anchors; ++k) marks.push_back(at_or_before(k * T + anchor0));
  std::vector<double> steps;
  for (std::size_t k = 1; k < marks.size(); ++k) steps.push_back(marks[k] - marks[k - 1]);
  const int m = static_cast<int>(steps.size());
  f.first_step_m = steps.front();
  const std::vector<double> tail(steps.begin() + m / 2, steps.end());
  f.steady_step_m = median(tail);
  double ss = 0;
  for (double v : tail) ss += (v - f.steady_step_m) * (v - f.steady_step_m);
  f.steady_sd_m = tail.size() > 1 ? std::sqrt(ss / (tail.size() - 1)) : 0.0;

  // A cycle-end reading carries the sensor's noise and quantization; a step, two of them.
  const double reading_sd = std::sqrt(noise_m * noise_m + resolution_m * resolution_m / 12.0);
  const double step_tol = 4.0 * std::sqrt(2.0) * reading_sd + 0.02 * std::fabs(f.steady_step_m);
  f.transient_cycles = 0;
  for (int k = m - 1; k >= 0; --k)
    if (std::fabs(steps[k] - f.steady_step_m) > step_tol) {
      f.transient_cycles = k + 1;
      break;
    }
  // The net direction: the steady step, or the total displacement when there is none.
  const double net = std::fabs(f.steady_step_m) > step_tol ? f.steady_step_m : f.cycle_end_m.back();
  const double dir = net >= 0 ? 1.0 : -1.0;
  for (std::size_t i = 0; i < s.size(); ++i)
    if (s.t_s[i] >= 0 && s.t_s[i] <= n * T) f.reverse_m = std::max(f.reverse_m, -dir * (s.x_m[i] - x0));
  f.reverse_m = std::max(0.0, f.reverse_m - 2.0 * reading_sd);

  // Region: cut-off when the steady step is within the noise (no net motion after the transient),
  // one-step when every step from the second on is the steady one, multi-step otherwise.
  if (std::fabs(f.steady_step_m) <= step_tol && f.transient_cycles <= 2)
    f.region = model::Region::Cutoff;
  else if (std::fabs(f.steady_step_m) <= step_tol)
    f.region = model::Region::MultiStep;
  else
    f.region = f.transient_cycles <= 1 ? model::Region::OneStep : model::Region::MultiStep;
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
