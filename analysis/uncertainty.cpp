#include "analysis/uncertainty.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <limits>
#include <set>

namespace idm::analysis {

namespace {

// The held-out chi-square of a fitted set at other coordinates (alpha and mu refitted on training).
class HeldOut {
 public:
  HeldOut(const SweepCells& sweep, const std::vector<CandidateSpec>& library, const SetFit& fit,
          int threads, bool scoring)
      : sweep_(sweep), library_(library), fit_(fit), threads_(threads), scoring_(scoring) {}

  double chi2(const std::vector<MemberFit>& members) const {
    ModelConfig m = fit_.fitted.model;
    m.effects = effects_of(library_, members);
    m.chain_rate_hz = scoring_ ? score_rate_hz(m.effects) : search_rate_hz(m.effects);
    m.search = !scoring_;
    const std::vector<CellPrediction> pred = predict_sweep(sweep_, m, threads_);
    const Calibration calib = fit_calibration(sweep_, pred, m.stage.friction_coefficient);
    const double g = evaluate_gap(sweep_, pred, calib, TrialSet::Test).gap;
    return static_cast<double>(sweep_.cells.size()) * g * g;
  }

 private:
  const SweepCells& sweep_;
  const std::vector<CandidateSpec>& library_;
  const SetFit& fit_;
  int threads_;
  bool scoring_;
};

// The reported (fitted) parameters of a member at its coordinates.
Params fitted_params(const CandidateSpec& spec, const MemberFit& m) {
  if (!spec.grid.empty()) return m.grid_point;
  std::vector<double> x;
  for (std::size_t i = 0; i < spec.axes.size(); ++i) x.push_back(spec.axes[i].value(m.u[i]));
  return spec.params(x);
}

struct Quadratic {
  Eigen::VectorXd g;  // gradient at the fit
  Eigen::MatrixXd h;  // Hessian
  std::vector<double> step;
  std::vector<bool> constrained;
  double f0 = 0;
};

// The quadratic of the held-out chi-square around the flat coordinate vector u0, with steps chosen
// per coordinate so that the rise is between delta and 30 delta.
Quadratic probe(const std::function<double(const std::vector<double>&)>& f,
                const std::vector<double>& u0, double delta) {
  const std::size_t n = u0.size();
  Quadratic q;
  q.g = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(n));
  q.h = Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(n), static_cast<Eigen::Index>(n));
  q.step.assign(n, 0.01);
  q.constrained.assign(n, false);
  q.f0 = f(u0);
  std::vector<double> f_plus(n, 0.0);
  for (std::size_t i = 0; i < n; ++i) {
    double h = 0.01;
    for (int attempt = 0; attempt < 6; ++attempt) {
      // a step that would leave [0, 1] is taken on the other side twice (one-sided differences)
      const double a = u0[i] + h <= 1.0 ? h : -h, b = u0[i] - h >= 0.0 ? -h : 2 * a;
      std::vector<double> ua = u0, ub = u0;
      ua[i] += a;
      ub[i] += b;
      const double fa = f(ua), fb = f(ub);
      const double rise = std::max(fa, fb) - q.f0;
      const bool last = attempt == 5;
      if (rise < delta && h < 0.25 && !last) {
        h *= 3;
        continue;
      }
      if (rise > 30 * delta && h > 3e-4 && !last) {
        h /= 3;
        continue;
      }
      // parabola through (0, f0), (a, fa), (b, fb)
      double d2 = 2 * ((fa - q.f0) / a - (fb - q.f0) / b) / (a - b);
      double d1 = (fa - q.f0) / a - 0.5 * d2 * a;
      // a rise beyond delta on both sides bounds the interval within the steps, whatever the
      // parabola's shape (an objective with kinks, a chain rate's rounding, can bend it the
      // other way): the flattest parabola through the lower rise, centered on the fit
      const double low_rise = std::min(fa, fb) - q.f0;
      if (d2 <= 0 && low_rise >= delta) {
        d2 = 2 * low_rise / (h * h);
        d1 = 0;
      }
      q.g(static_cast<Eigen::Index>(i)) = d1;
      q.h(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(i)) = d2;
      q.step[i] = a;
      q.constrained[i] = d2 > 0 && rise >= 0.5 * delta;
      f_plus[i] = fa;
      break;
    }
  }
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t j = i + 1; j < n; ++j) {
      if (!q.constrained[i] || !q.constrained[j]) continue;
      std::vector<double> u = u0;
      u[i] += q.step[i];
      u[j] += q.step[j];
      const double fij = f(u);
      // f(a e_i + b e_j) = f0 + g_i a + g_j b + (h_ii a^2 + h_jj b^2) / 2 + h_ij a b
      const Eigen::Index I = static_cast<Eigen::Index>(i), J = static_cast<Eigen::Index>(j);
      const double a = q.step[i], b = q.step[j];
      const double hij =
          (fij - q.f0 - q.g(I) * a - q.g(J) * b - 0.5 * (q.h(I, I) * a * a + q.h(J, J) * b * b)) /
          (a * b);
      q.h(I, J) = q.h(J, I) = hij;
    }
  // A Hessian that is not positive definite keeps its diagonal only.
  Eigen::LLT<Eigen::MatrixXd> llt(q.h + 1e-12 * Eigen::MatrixXd::Identity(q.h.rows(), q.h.cols()));
  if (llt.info() != Eigen::Success) q.h = Eigen::MatrixXd(q.h.diagonal().asDiagonal());
  return q;
}

// Explicit-grid members: the grid values whose held-out chi-square is within delta of the best.
std::vector<ParameterIntervals> grid_intervals(const HeldOut& held,
                                               const std::vector<CandidateSpec>& library,
                                               const SetFit& fit, double delta) {
  std::vector<ParameterIntervals> out;
  for (std::size_t k = 0; k < fit.members.size(); ++k) {
    const CandidateSpec& spec = spec_of(library, fit.members[k].effect);
    if (spec.grid.empty()) continue;
    std::vector<std::pair<double, Params>> values;
    for (const Params& g : spec.grid) {
      std::vector<MemberFit> m = fit.members;
      m[k].grid_point = g;
      values.push_back({held.chi2(m), g});
    }
    double best = std::numeric_limits<double>::infinity();
    for (const auto& v : values) best = std::min(best, v.first);
    ParameterIntervals pi{spec.effect, {}};
    for (const auto& [name, value] : fit.members[k].grid_point) {
      ParameterInterval iv{name, value, value, value, false};
      for (const auto& [chi2, g] : values)
        if (chi2 <= best + delta) {
          iv.lo = std::min(iv.lo, g.at(name));
          iv.hi = std::max(iv.hi, g.at(name));
        }
      pi.params.push_back(iv);
    }
    out.push_back(pi);
  }
  return out;
}

// The delta-ellipsoid of a quadratic over the constrained coordinates (offsets from the fit):
// its center, the held-out minimum (at most two steps from the training optimum), and the points
// that reach furthest along each coordinate, plus a ring for two coordinates.
struct Ellipsoid {
  Eigen::VectorXd center;
  std::vector<Eigen::VectorXd> boundary;
};

Ellipsoid delta_ellipsoid(const Quadratic& q, std::size_t n, double delta) {
  Ellipsoid e;
  Eigen::VectorXd& center = e.center;
  std::vector<Eigen::VectorXd>& boundary = e.boundary;
  center = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(n));
  Eigen::MatrixXd cov = Eigen::MatrixXd::Zero(q.h.rows(), q.h.cols());
  std::vector<Eigen::Index> free_axes;
  for (std::size_t i = 0; i < n; ++i)
    if (q.constrained[i]) free_axes.push_back(static_cast<Eigen::Index>(i));
  if (!free_axes.empty()) {
    const Eigen::Index m = static_cast<Eigen::Index>(free_axes.size());
    Eigen::MatrixXd hs(m, m);
    Eigen::VectorXd gs(m);
    for (Eigen::Index a = 0; a < m; ++a) {
      gs(a) = q.g(free_axes[a]);
      for (Eigen::Index b = 0; b < m; ++b) hs(a, b) = q.h(free_axes[a], free_axes[b]);
    }
    const Eigen::MatrixXd inv = hs.inverse();
    const Eigen::VectorXd vertex = -inv * gs;
    for (Eigen::Index a = 0; a < m; ++a) {
      const double lim = 2 * std::fabs(q.step[static_cast<std::size_t>(free_axes[a])]);
      center(free_axes[a]) = std::clamp(vertex(a), -lim, lim);
      for (Eigen::Index b = 0; b < m; ++b) cov(free_axes[a], free_axes[b]) = inv(a, b);
    }
    for (Eigen::Index a = 0; a < m; ++a) {
      const Eigen::Index i = free_axes[a];
      const Eigen::VectorXd col = cov.col(i);
      const double reach = std::sqrt(2 * delta / std::max(1e-300, cov(i, i)));
      boundary.push_back(center + reach * col);
      boundary.push_back(center - reach * col);
    }
    if (m == 2) {
      const Eigen::LLT<Eigen::MatrixXd> llt(inv);
      const Eigen::MatrixXd l = llt.matrixL();
      for (int k = 0; k < 24; ++k) {
        Eigen::VectorXd d2(2);
        d2 << std::cos(2 * M_PI * k / 24), std::sin(2 * M_PI * k / 24);
        const Eigen::VectorXd d = std::sqrt(2 * delta) * (l * d2);
        Eigen::VectorXd full = center;
        full(free_axes[0]) += d(0);
        full(free_axes[1]) += d(1);
        boundary.push_back(full);
      }
    }
  }
  return e;
}

// The flat coordinate vectors to evaluate: u0 moved to the ellipsoid's center and boundary; an
// unconstrained coordinate spans its range (each point at both ends, clamped later).
std::vector<std::vector<double>> interval_points(const std::vector<double>& u0, const Quadratic& q,
                                                 const Ellipsoid& e) {
  const std::size_t n = u0.size();
  std::vector<std::vector<double>> points;
  auto add_point = [&](const Eigen::VectorXd& d) {
    std::vector<double> u = u0;
    for (std::size_t i = 0; i < n; ++i) u[i] += d(static_cast<Eigen::Index>(i));
    points.push_back(u);
  };
  add_point(e.center);
  for (const Eigen::VectorXd& d : e.boundary) add_point(d);
  for (std::size_t i = 0; i < n; ++i)
    if (!q.constrained[i]) {
      const std::size_t count = points.size();
      for (std::size_t p = 0; p < count; ++p)
        for (double end : {-1e9, 1e9}) {
          std::vector<double> u = points[p];
          u[i] = end;
          points.push_back(u);
        }
    }
  return points;
}

// Members with axes: each parameter's range over the points (flat coordinates, the members in
// order), appended to out.
void add_axis_intervals(const std::vector<CandidateSpec>& library, const SetFit& fit,
                        const std::vector<std::vector<double>>& points,
                        std::vector<ParameterIntervals>& out) {
  std::size_t offset = 0;
  for (std::size_t k = 0; k < fit.members.size(); ++k) {
    const MemberFit& member = fit.members[k];
    const CandidateSpec& spec = spec_of(library, member.effect);
    if (!spec.grid.empty()) continue;
    ParameterIntervals pi{member.effect, {}};
    const Params at_fit = fitted_params(spec, member);
    for (const auto& [name, value] : at_fit) {
      ParameterInterval iv{name, value, value, value, false};
      for (const std::vector<double>& u : points) {
        MemberFit mm = member;
        bool clamped = false;
        for (std::size_t i = 0; i < mm.u.size(); ++i) {
          const double v = u[offset + i];
          clamped = clamped || v < 0.0 || v > 1.0;
          mm.u[i] = std::clamp(v, 0.0, 1.0);
        }
        const double p = fitted_params(spec, mm).at(name);
        if (p < iv.lo || p > iv.hi) iv.limited_by_range = iv.limited_by_range || clamped;
        iv.lo = std::min(iv.lo, p);
        iv.hi = std::max(iv.hi, p);
      }
      pi.params.push_back(iv);
    }
    offset += member.u.size();
    out.push_back(pi);
  }
}

}  // namespace

std::vector<ParameterIntervals> parameter_intervals(const SweepCells& sweep,
                                                    const std::vector<CandidateSpec>& library,
                                                    const SetFit& fit, const FittedModel& baseline,
                                                    int threads, bool scoring) {
  (void)baseline;
  const HeldOut held(sweep, library, fit, threads, scoring);
  const double reduced = fit.gap * fit.gap;
  const double delta = 3.84 * std::max(1.0, reduced);
  std::vector<ParameterIntervals> out = grid_intervals(held, library, fit, delta);
  // coordinates: one flat vector over the members with axes
  std::vector<double> u0;
  for (const MemberFit& m : fit.members) u0.insert(u0.end(), m.u.begin(), m.u.end());
  auto members_at = [&](const std::vector<double>& u) {
    std::vector<MemberFit> m = fit.members;
    std::size_t k = 0;
    for (MemberFit& x : m)
      for (double& v : x.u) v = std::clamp(u[k++], 0.0, 1.0);
    return m;
  };
  if (u0.empty()) return out;
  const Quadratic q =
      probe([&](const std::vector<double>& u) { return held.chi2(members_at(u)); }, u0, delta);
  const Ellipsoid e = delta_ellipsoid(q, u0.size(), delta);
  add_axis_intervals(library, fit, interval_points(u0, q, e), out);
  return out;
}

std::string separating_sweep(const SweepCells& sweep, const SetFit& a, const SetFit& b,
                             int threads) {
  std::set<double> freqs, strokes;
  bool forward = false, reverse = false;
  int cycles = 0, trials = 0;
  double f_max = 0;
  for (const Cell& c : sweep.cells) {
    freqs.insert(c.key.freq_hz);
    strokes.insert(c.key.stroke_m);
    forward = forward || c.key.duty < 0.5;
    reverse = reverse || c.key.duty > 0.5;
    cycles = std::max(cycles, c.cycles);
    trials = std::max(trials, static_cast<int>(c.train.size() + c.test.size()));
    f_max = std::max(f_max, c.key.freq_hz);
  }
  SweepCells wide = sweep;
  wide.cells.clear();
  std::vector<double> fr(freqs.begin(), freqs.end());
  for (double k : {1.25, 1.5, 2.0, 3.0}) fr.push_back(std::round(k * f_max));
  for (double s : strokes)
    for (double f : fr)
      for (double d : {0.02, 0.05, 0.1, 0.2, 0.3, 0.4, 0.45})
        for (int dir = 0; dir < 2; ++dir) {
          if ((dir == 0 && !forward) || (dir == 1 && !reverse)) continue;
          Cell c;
          c.key = {f, dir == 0 ? d : 1.0 - d, s};
          c.cycles = cycles;
          c.read_t_s = rest_instants(f, c.key.duty, cycles);
          wide.cells.push_back(c);
        }
  auto predict = [&](const SetFit& s) {
    ModelConfig m = s.fitted.model;
    m.chain_rate_hz = search_rate_hz(m.effects);
    m.search = true;
    const std::vector<CellPrediction> p = predict_sweep(wide, m, threads);
    std::vector<double> steps;
    steps.reserve(p.size());
    for (const CellPrediction& c : p) steps.push_back(s.fitted.calibration.step(c));
    return steps;
  };
  const std::vector<double> pa = predict(a), pb = predict(b);
  const double unit = std::sqrt(2.0) * sweep.reading_sd_m / std::sqrt(std::max(1, trials));
  double best = 0, here = 0;
  std::vector<double> sep(wide.cells.size());
  for (std::size_t c = 0; c < wide.cells.size(); ++c) {
    sep[c] = std::fabs(pa[c] - pb[c]) / unit;
    best = std::max(best, sep[c]);
    if (freqs.count(wide.cells[c].key.freq_hz)) here = std::max(here, sep[c]);
  }
  double f_lo = 1e300, f_hi = 0, d_lo = 1, d_hi = 0;
  std::set<double> used_strokes;
  for (std::size_t c = 0; c < wide.cells.size(); ++c)
    if (sep[c] >= 0.5 * best) {
      const CellKey& k = wide.cells[c].key;
      f_lo = std::min(f_lo, k.freq_hz);
      f_hi = std::max(f_hi, k.freq_hz);
      const double dd = std::min(k.duty, 1 - k.duty);
      d_lo = std::min(d_lo, dd);
      d_hi = std::max(d_hi, dd);
      used_strokes.insert(k.stroke_m);
    }
  char buf[400];
  std::snprintf(
      buf, sizeof buf,
      "frequencies %.0f-%.0f Hz at duty %.2f-%.2f (or 1 - duty)%s: the two fits part by up to %.1f "
      "times the step noise of %d trials there, %.1f in this sweep's cells",
      f_lo, f_hi, d_lo, d_hi, used_strokes.size() < strokes.size() ? " at the larger stroke" : "",
      best, trials, here);
  std::string out = buf;
  if (best < 5) {
    const int needed = static_cast<int>(std::ceil(trials * std::pow(5.0 / std::max(best, 0.1), 2)));
    out += "; about " + std::to_string(needed) + " trials a cell would make it 5";
  }
  return out;
}

}  // namespace idm::analysis
