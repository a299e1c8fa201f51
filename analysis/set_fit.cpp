// Fitting one effect or a set of effects (candidates.h): grid, Subplex refinement at the search
// rate, polish and score at the scoring rate.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <limits>
#include <map>
#include <nlopt.hpp>
#include <numeric>
#include <optional>

#include "analysis/candidates.h"
#include "model/yaml_util.h"

namespace idm::analysis {

std::vector<model::EffectSpec> effects_of(const std::vector<CandidateSpec>& library,
                                          const std::vector<MemberFit>& members) {
  std::vector<model::EffectSpec> out;
  for (const MemberFit& m : members) {
    const CandidateSpec& spec = spec_of(library, m.effect);
    Params p = m.fixed;
    if (!spec.grid.empty()) {
      for (const auto& [k, v] : m.grid_point) p[k] = v;
    } else {
      std::vector<double> x;
      for (std::size_t i = 0; i < spec.axes.size(); ++i) x.push_back(spec.axes[i].value(m.u[i]));
      for (const auto& [k, v] : spec.params(x)) p[k] = v;
    }
    out.push_back(model::complete_effect({m.effect, p}, "candidate " + m.effect));
  }
  return out;
}

namespace {

// The training gap of a set of effects (alpha and mu refitted around the baseline's mu).
class Objective {
 public:
  Objective(const SweepCells& sweep, const std::vector<CandidateSpec>& library,
            const FittedModel& baseline, int threads)
      : sweep_(sweep),
        library_(library),
        baseline_(baseline),
        model_(baseline.model),
        threads_(threads) {
    model_.stage.friction_coefficient = sweep.stage.stage.friction_coefficient;
  }

  double train_gap(const std::vector<MemberFit>& members, bool search) {
    ++evaluations;
    ModelConfig model = model_;
    model.effects = effects_of(library_, members);
    model.chain_rate_hz = search ? search_rate_hz(model.effects) : score_rate_hz(model.effects);
    model.search = search;
    const std::vector<CellPrediction> pred = predict_sweep(sweep_, model, threads_);
    const Calibration calib =
        fit_calibration(sweep_, pred, model.stage.friction_coefficient, false);
    last_mu_ = fit_calibration(sweep_, pred, model.stage.friction_coefficient).mu;  // a proposal
    const double gap = evaluate_gap(sweep_, pred, calib, TrialSet::Train).gap;
    return std::isnan(gap) ? std::numeric_limits<double>::infinity() : gap;  // never a best point
  }

  // The search keeps mu at stage.yaml's (alpha alone is fitted: a free mu would let every
  // candidate trade its own parameters against the friction). Before the polish, mu moves to the
  // linearized fit's proposal at the best point when that lowers the training gap there.
  void recenter(const std::vector<MemberFit>& members) {
    const double here = train_gap(members, true);
    const double mu = model_.stage.friction_coefficient, proposal = last_mu_;
    model_.stage.friction_coefficient = proposal;
    if (!(train_gap(members, true) < here)) model_.stage.friction_coefficient = mu;
  }

  // The set scored at the scoring rate, mu re-simulated at its fitted value.
  SetFit score(const std::vector<MemberFit>& members, double train_gap) {
    SetFit f;
    f.members = members;
    f.effects = effects_of(library_, members);
    ModelConfig model = model_;
    model.effects = f.effects;
    model.chain_rate_hz = score_rate_hz(model.effects);
    f.fitted = fit_model(sweep_, model, threads_, 4);
    f.train_gap = train_gap;
    f.gap = f.fitted.test.gap;
    f.shrink = baseline_.test.gap > 0 ? 1.0 - f.gap / baseline_.test.gap : 0.0;
    f.evaluations = evaluations + 1 + 1;
    return f;
  }

  int evaluations = 0;

 private:
  const SweepCells& sweep_;
  const std::vector<CandidateSpec>& library_;
  const FittedModel& baseline_;
  ModelConfig model_;  // the model searched: stage.yaml's, at the mu of the current search
  int threads_;
  double last_mu_ = 0;
};

// The objective of the coarse searches and the screens: on the cells of spread_subset (owned
// here, since the objective refers to them).
struct CoarseObjective {
  CoarseObjective(const SweepCells& sweep, const std::vector<CandidateSpec>& library,
                  const FittedModel& baseline, int threads)
      : cells(spread_subset(sweep, kCoarseCells)), objective(cells, library, baseline, threads) {}
  CoarseObjective(const CoarseObjective&) = delete;
  CoarseObjective& operator=(const CoarseObjective&) = delete;
  CoarseObjective(CoarseObjective&&) = delete;
  CoarseObjective& operator=(CoarseObjective&&) = delete;
  ~CoarseObjective() = default;
  const SweepCells cells;
  Objective objective;
};

// Bounded Subplex on [0, 1]^n from `start`, first steps `steps` (one a coordinate); returns the
// best point met (and its value in `best`).
std::vector<double> subplex(const std::function<double(const std::vector<double>&)>& f,
                            std::vector<double> start, const std::vector<double>& steps,
                            int max_evals, double xtol, double& best) {
  const std::size_t n = start.size();
  std::vector<double> best_x = start;
  best = std::numeric_limits<double>::infinity();
  if (n == 0 || max_evals <= 0) return best_x;
  nlopt::opt solver(nlopt::LN_SBPLX, static_cast<unsigned>(n));
  solver.set_lower_bounds(std::vector<double>(n, 0.0));
  solver.set_upper_bounds(std::vector<double>(n, 1.0));
  solver.set_initial_step(steps);
  solver.set_maxeval(max_evals);
  solver.set_xtol_abs(xtol);
  std::function<double(const std::vector<double>&)> eval = [&](const std::vector<double>& x) {
    const double v = f(x);
    if (v < best) {
      best = v;
      best_x = x;
    }
    return v;
  };
  solver.set_min_objective(
      [](const std::vector<double>& x, std::vector<double>&, void* data) {
        return (*static_cast<std::function<double(const std::vector<double>&)>*>(data))(x);
      },
      &eval);
  double fx = 0;
  try {
    solver.optimize(start, fx);
  } catch (const nlopt::roundoff_limited&) {
  } catch (const nlopt::forced_stop&) {
  }
  return best_x;
}

std::vector<double> subplex(const std::function<double(const std::vector<double>&)>& f,
                            std::vector<double> start, double step, int max_evals, double xtol,
                            double& best) {
  const std::vector<double> steps(start.size(), step);
  return subplex(f, std::move(start), steps, max_evals, xtol, best);
}

// Plausibility of a fitted set: no coordinate on a bound, a step scale some stage has, and a
// spread of the trials (a friction spread) only where the trials show one: a set that predicts a
// spread must not miss the measured spreads by more than the baseline does (the spread part of
// its held-out gap, kSpreadPartAllowance at least). Else its spread merely widens what a mean it
// misses is measured against (an effect the library lacks, the stroke lost to heat).
void judge(const std::vector<CandidateSpec>& library, const FittedModel& baseline, SetFit& f) {
  auto implausible = [&f](const std::string& why) {
    f.plausible = false;
    f.note += (f.note.empty() ? "" : "; ") + why;
  };
  for (const MemberFit& m : f.members) {
    const CandidateSpec& spec = spec_of(library, m.effect);
    for (std::size_t i = 0; i < m.u.size(); ++i)
      if (m.u[i] < 0.01 || m.u[i] > 0.99) {
        f.on_bound = true;
        implausible(m.effect + " " + spec.axes[i].name +
                    " ended on the bound of its plausible range [" +
                    model::format_number(spec.axes[i].lo) + ", " +
                    model::format_number(spec.axes[i].hi) + "]");
      }
  }
  const double alpha = f.fitted.calibration.alpha;
  if (!(alpha > 0.05 && alpha <= 2.0))
    implausible("needs a step scale of " + model::format_number(alpha, 3) + ", outside (0.05, 2]");
  const bool spreads =
      std::any_of(f.fitted.predictions.begin(), f.fitted.predictions.end(),
                  [](const CellPrediction& p) { return !p.trial_steps_m.empty(); });
  const double spread_part = gap_parts(f.fitted.test).spread;
  const double allowed = std::max(kSpreadPartAllowance, gap_parts(baseline.test).spread);
  if (spreads && spread_part > allowed)
    implausible(
        "predicts a spread of the trials the sweep does not show: the spread part of the "
        "held-out gap is " +
        model::format_number(spread_part, 3) + ", above " + model::format_number(allowed, 3) +
        " (the baseline's, or " + model::format_number(kSpreadPartAllowance) + ")");
}

void log_fit(const char* what, const SetFit& f, std::chrono::steady_clock::time_point t0,
             const FitOptions& opt) {
  if (!opt.explain) return;
  std::string names;
  for (const std::string& n : f.names()) names += (names.empty() ? "" : "+") + n;
  const GapParts held_out = gap_parts(f.fitted.test);
  std::string params;
  for (const model::EffectSpec& e : f.effects)
    for (const auto& [k, v] : e.params)
      params += " " + e.name + "." + k + "=" + model::format_number(v);
  char line[640];
  std::snprintf(line, sizeof line,
                "%s %s: %d evaluations, %.2f s, train gap %.3g, held-out %.3g (mean %.3g, spread "
                "%.3g, label %.3g, systematic %.3g)%s%s; mu %.4g alpha %.4g",
                what, names.c_str(), f.evaluations,
                std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(),
                f.train_gap, f.gap, held_out.mean, held_out.spread, held_out.label,
                systematic_gap(f.fitted),
                f.plausible ? "" : ", implausible: ", f.plausible ? "" : f.note.c_str(),
                f.fitted.model.stage.friction_coefficient, f.fitted.calibration.alpha);
  opt.explain(line + params);
}

}  // namespace

SweepCells spread_subset(const SweepCells& sweep, std::size_t count) {
  if (sweep.cells.size() <= 2 * count) return sweep;
  SweepCells out = sweep;
  out.cells.clear();
  const double stride = static_cast<double>(sweep.cells.size()) / static_cast<double>(count);
  for (std::size_t k = 0; k < count; ++k)
    out.cells.push_back(
        sweep.cells[static_cast<std::size_t>((static_cast<double>(k) + 0.5) * stride)]);
  return out;
}

std::vector<std::vector<double>> starts_from(
    std::vector<std::pair<double, std::vector<double>>> grid, const std::vector<double>& step,
    const std::vector<double>& cell, int max_starts) {
  for (auto& point : grid)  // a point that could not be scored ranks last
    if (!std::isfinite(point.first)) point.first = std::numeric_limits<double>::infinity();
  std::sort(grid.begin(), grid.end(),
            [](const auto& a, const auto& b) { return a.first < b.first; });
  auto within = [](const std::vector<double>& u, const std::vector<double>& v,
                   const std::vector<double>& d) {
    for (std::size_t i = 0; i < u.size(); ++i)
      if (std::fabs(u[i] - v[i]) > d[i] * 1.01) return false;
    return true;
  };
  std::vector<std::vector<double>> starts;
  auto take = [&](const std::vector<double>& u) {
    for (const std::vector<double>& s : starts)
      if (within(u, s, cell)) return;
    starts.push_back(u);
  };
  for (std::size_t k = 0; k < grid.size(); ++k) {
    if (starts.size() >= static_cast<std::size_t>(max_starts)) break;
    if (!std::isfinite(grid[k].first)) break;
    bool minimum = true;
    for (std::size_t j = 0; j < k && minimum; ++j)  // the better points
      minimum = grid[j].first == grid[k].first || !within(grid[j].second, grid[k].second, step);
    if (minimum) take(grid[k].second);
  }
  for (const auto& [value, u] : grid) {
    if (starts.size() >= static_cast<std::size_t>(max_starts)) break;
    take(u);
  }
  return starts;
}

namespace {

// The coordinates of a set's members in one vector (member by member), and back: `u` fills the
// members in order until it runs out (a set's leading members alone may be given).
std::vector<double> coordinates_of(const std::vector<MemberFit>& members) {
  std::vector<double> u;
  for (const MemberFit& m : members) u.insert(u.end(), m.u.begin(), m.u.end());
  return u;
}

void set_coordinates(std::vector<MemberFit>& members, const std::vector<double>& u) {
  std::size_t k = 0;
  for (MemberFit& m : members)
    for (double& v : m.u)
      if (k < u.size()) v = u[k++];
}

// A spec's grid, or with `scan` its scan (axis 0 in steps of scan_ratio, `coarsen` of them a step,
// at each of scan_other), then stage.yaml's start when there is one.
struct GridLayout {
  std::vector<std::vector<double>> points;
  int spacing = 0;           // grid points per unit of u (the refinement's first step)
  std::vector<double> step;  // per coordinate, one grid step (a scan's: du, the rows' largest gap)
  std::vector<double> cell;  // per coordinate, how far apart starts must lie (a scan: two steps)
};

GridLayout grid_points(const CandidateSpec& spec, const FitOptions& opt, bool scan,
                       int coarsen = 1) {
  const std::size_t n = spec.axes.size();
  const int pts = n == 1 ? opt.grid_1d : opt.grid_2d;
  GridLayout g;
  g.spacing = pts;
  g.step.assign(n, 1.0 / (pts - 1));
  g.cell = g.step;
  if (scan && spec.scan_ratio > 1 && n == 2) {
    const FitAxis& a = spec.axes[0];
    const double du = coarsen * std::log(spec.scan_ratio) / std::log(a.hi / a.lo);
    g.spacing = static_cast<int>(std::ceil(0.5 / du));  // neighbours: within two scan steps
    double rows = 0;
    for (std::size_t k = 1; k < spec.scan_other.size(); ++k)
      rows = std::max(rows, std::fabs(spec.axes[1].coordinate(spec.scan_other[k]) -
                                      spec.axes[1].coordinate(spec.scan_other[k - 1])));
    g.step = {du, rows};
    g.cell = {1.0 / (g.spacing - 1), rows};
    for (double other : spec.scan_other)
      for (double u0 = 0; u0 <= 1 + 1e-9; u0 += du)
        g.points.push_back({std::min(u0, 1.0), spec.axes[1].coordinate(other)});
  } else {
    const int total = n == 1 ? pts : pts * pts;
    for (int k = 0; k < total; ++k) {
      // Point k of a pts x pts grid: column k % pts, row k / pts (integer division on purpose).
      const int column = k % pts, row = k / pts;
      std::vector<double> u(n);
      u[0] = column / double(pts - 1);
      if (n == 2) u[1] = row / double(pts - 1);
      g.points.push_back(u);
    }
  }
  if (!spec.start.empty()) {
    std::vector<double> u;
    for (std::size_t i = 0; i < n; ++i) u.push_back(spec.axes[i].coordinate(spec.start[i]));
    g.points.push_back(u);
  }
  return g;
}

// The objective of a newcomer on top of a set of fitted members. Held: the set stays where its
// own fit left it. Profiled: at every point the set's coordinates are refitted by a short Subplex
// from there, the newcomer held (the profile of the objective over the newcomer's coordinates):
// fitted without the newcomer, the set has absorbed part of its signature and sits beside the
// narrow valley the two share, where the newcomer alone shows no basin. A refinement then moves
// the set and the newcomer together.
class OnTop {
 public:
  OnTop(Objective& obj, const std::vector<MemberFit>& set, bool profile, const FitOptions& opt)
      : obj_(obj),
        set_(set),
        u0_(coordinates_of(set)),
        evals_(profile && !u0_.empty() ? kProfileEvals * static_cast<int>(u0_.size()) + 2 : 0),
        step_(0.1 / (opt.grid_1d - 1)) {}

  bool alone() const { return set_.empty(); }

  // The objective with `m` added, and the set's coordinates it was reached at.
  double value(const MemberFit& m, std::vector<double>& set_u) {
    std::vector<MemberFit> all = set_;
    all.push_back(m);
    set_u = u0_;
    if (evals_ == 0) return obj_.train_gap(all, true);
    double best = 0;
    set_u = subplex(
        [&](const std::vector<double>& u) {
          set_coordinates(all, u);
          return obj_.train_gap(all, true);
        },
        u0_, step_, evals_, 1e-4, best);
    return best;
  }

  // A Subplex from (set_u, m.u), `evals` per coordinate it moves: the newcomer's coordinates
  // (first step `step`) when the set is held, the set's too (the profile's step) when it is
  // profiled; both updated, the value returned.
  double refine(MemberFit& m, std::vector<double>& set_u, double step, int evals) {
    std::vector<MemberFit> all = with(m, set_u);
    const bool joint = evals_ > 0;
    std::vector<double> steps(joint ? set_u.size() : 0, step_);
    steps.resize(steps.size() + m.u.size(), step);
    double best = 0;
    const std::vector<double> u = subplex(
        [&](const std::vector<double>& x) {
          if (joint) set_coordinates(all, x);
          if (!joint) all.back().u = x;
          return obj_.train_gap(all, true);
        },
        joint ? coordinates_of(all) : m.u, steps, evals * static_cast<int>(steps.size()), 1e-3,
        best);
    if (joint) set_coordinates(all, u);
    if (!joint) all.back().u = u;
    m.u = all.back().u;
    all.pop_back();
    set_u = coordinates_of(all);
    return best;
  }

  // The set at `set_u` with `m` added.
  std::vector<MemberFit> with(const MemberFit& m, const std::vector<double>& set_u) const {
    std::vector<MemberFit> all = set_;
    set_coordinates(all, set_u);
    all.push_back(m);
    return all;
  }

 private:
  static constexpr int kProfileEvals = 4;  // Subplex evaluations per coordinate of the set
  Objective& obj_;
  std::vector<MemberFit> set_;
  std::vector<double> u0_;
  int evals_;
  double step_;
};

// The coarse search for one effect on top of a set (`on_top`; alone when it is empty): its grid
// or with `scan` its scan, then Subplex from the best points that are not neighbours. Returns the
// set with the effect added (the effect last); `value`: the objective there; `per_variant`, when
// given, receives the best of each variant.
std::vector<MemberFit> coarse_search(OnTop& on_top, const CandidateSpec& spec,
                                     const FitOptions& opt, bool scan, double& value,
                                     std::vector<MemberFit>* per_variant = nullptr) {
  // (the middle of the ranges until a point scores: none may when every prediction fails)
  std::vector<MemberFit> best = on_top.with(
      {spec.effect, spec.variants.front(), std::vector<double>(spec.axes.size(), 0.5), {}}, {});
  value = std::numeric_limits<double>::infinity();
  std::vector<double> set_u;
  if (!spec.grid.empty()) {
    for (const Params& g : spec.grid) {
      const MemberFit m{spec.effect, spec.variants.front(), {}, g};
      const double v = on_top.value(m, set_u);
      if (v < value) {
        value = v;
        best = on_top.with(m, set_u);
      }
    }
    return best;
  }
  const std::size_t n = spec.axes.size();
  const GridLayout layout = grid_points(spec, opt, scan);
  for (const Params& fixed : spec.variants) {
    MemberFit m{spec.effect, fixed, std::vector<double>(n, 0.0), {}};
    std::vector<std::pair<double, std::vector<double>>> grid;
    std::map<std::vector<double>, std::vector<double>> set_at;  // the set's coordinates at a point
    for (const std::vector<double>& u : layout.points) {
      m.u = u;
      grid.push_back({on_top.value(m, set_u), u});
      set_at[u] = set_u;
    }
    std::vector<MemberFit> variant_best = on_top.with(m, {});
    double variant_value = std::numeric_limits<double>::infinity();
    for (const std::vector<double>& start :
         starts_from(grid, layout.step, layout.cell, n == 1 ? 1 : (scan ? 2 : 1) * opt.starts_2d)) {
      m.u = start;
      set_u = set_at.at(start);
      const double v = on_top.refine(m, set_u, 0.5 / (layout.spacing - 1), opt.refine_evals);
      if (v < variant_value) {
        variant_value = v;
        variant_best = on_top.with(m, set_u);
      }
    }
    if (per_variant) per_variant->push_back(variant_best.back());
    if (variant_value < value) {
      value = variant_value;
      best = variant_best;
    }
  }
  return best;
}

// A pair of a scanned effect (`narrow`: a valley across its grid, Stribeck's, or a resonance's
// when the selection asks) and an effect on one coordinate (`wide`: an amplifier, a tilt, creep,
// hysteresis): the scan, at twice its step,
// with `wide` held at every point of its grid. Fitted alone, either can absorb part of the other
// and sit where the pair's valley is not (an amplifier fitted to nothing beside a Stribeck valley
// at a 6 times higher velocity): the profile refits the set only near its own optimum, and the
// scan with the set held looks only there. Returns, for each of `wide`'s variants, `wide` at the
// two grid points where the pair scored best (the pair's optimum lies between grid points, and
// the valley's place moves with `wide`: beside a 3 kHz amplifier 2.4 kHz and 5.7 kHz both
// scored 66; searched from 5.7 kHz the pair stopped at 40, from 2.4 kHz it reached 6).
std::vector<MemberFit> scan_across(Objective& obj, const CandidateSpec& narrow,
                                   const CandidateSpec& wide, const FitOptions& opt) {
  const GridLayout across = grid_points(wide, opt, false);
  const GridLayout scan = grid_points(narrow, opt, true, 2);
  std::vector<MemberFit> best;
  for (const Params& fixed : wide.variants) {
    std::vector<double> at;  // the pair's best value at each grid point
    for (const std::vector<double>& uw : across.points) {
      const MemberFit w{wide.effect, fixed, uw, {}};
      double value = std::numeric_limits<double>::infinity();
      for (const std::vector<double>& un : scan.points) {
        const double v = obj.train_gap({w, {narrow.effect, narrow.variants.front(), un, {}}}, true);
        if (std::isfinite(v)) value = std::min(value, v);
      }
      at.push_back(value);
    }
    std::vector<std::size_t> order(at.size());
    std::iota(order.begin(), order.end(), 0);
    const std::size_t kept = std::min<std::size_t>(2, order.size());
    std::partial_sort(order.begin(), order.begin() + static_cast<std::ptrdiff_t>(kept), order.end(),
                      [&](std::size_t x, std::size_t y) { return at[x] < at[y]; });
    for (std::size_t k = 0; k < kept; ++k)
      best.push_back({wide.effect, fixed, across.points[order[k]], {}});
  }
  return best;
}

// The best of `u` and the points on rings around it, a quarter, half, one and two `step`s away
// in the first of two coordinates and 4 times as far in the second (8 points a ring); `value`
// holds f(u) on entry and the best value on return.
std::vector<double> best_on_rings(const std::function<double(const std::vector<double>&)>& f,
                                  const std::vector<double>& u, double step, double& value) {
  std::vector<double> best = u;
  for (double r : {0.25 * step, 0.5 * step, step, 2 * step})
    for (int d0 = -1; d0 <= 1; ++d0)
      for (int d1 = -1; d1 <= 1; ++d1) {
        if (d0 == 0 && d1 == 0) continue;
        const std::vector<double> p = {std::clamp(u[0] + d0 * r, 0.0, 1.0),
                                       std::clamp(u[1] + d1 * 4 * r, 0.0, 1.0)};
        const double v = f(p);
        if (v < value) {
          value = v;
          best = p;
        }
      }
  return best;
}

}  // namespace

SetFit fit_single(const SweepCells& sweep, const std::vector<CandidateSpec>& library,
                  const CandidateSpec& spec, const FittedModel& baseline, const FitOptions& opt) {
  const auto t0 = std::chrono::steady_clock::now();
  Objective obj(sweep, library, baseline, opt.threads);
  // The grid or scan looks for basins on a subset of the cells spread over the map (cheaper on a
  // large sweep); the refinement runs on every cell.
  CoarseObjective coarse_set(sweep, library, baseline, opt.threads);
  const SweepCells& coarse_cells = coarse_set.cells;
  Objective& coarse = coarse_set.objective;
  double best_value = 0;
  std::vector<MemberFit> variants;
  OnTop alone(coarse, {}, false, opt);
  MemberFit best = coarse_search(alone, spec, opt, spec.scans(true), best_value, &variants).back();
  if (spec.grid.empty()) {
    const int n = static_cast<int>(spec.axes.size());
    const int pts = n == 1 ? opt.grid_1d : opt.grid_2d;
    auto on_all = [&](bool search) {
      return [&, search](const std::vector<double>& u) {
        MemberFit m = best;
        m.u = u;
        return obj.train_gap({m}, search);
      };
    };
    // On a large sweep each variant's coarse optimum is refined on every cell (a short Subplex
    // from there) and the variants are compared there.
    if (coarse_cells.cells.size() < sweep.cells.size()) {
      best_value = std::numeric_limits<double>::infinity();
      for (const MemberFit& v : variants) {
        MemberFit keep = best;
        best = v;
        double value = 0;
        best.u = subplex(on_all(true), v.u, 0.1 / (pts - 1), opt.refine_evals * n / 2, 1e-3, value);
        if (value < best_value) {
          best_value = value;
          keep = best;
        }
        best = keep;
      }
    }
    // The winner polished at the scoring rate, simulated at its own mu: with little noise the gap
    // is a sharp V around the optimum, and the search rate's error and the linearized mu move it.
    obj.recenter({best});
    const double step = spec.scans(true) ? 0.005 : 0.05 / (pts - 1);
    best.u = subplex(on_all(false), best.u, step, opt.polish_evals * n, 1e-4, best_value);
    // A narrow valley's V is rough where region labels change, and the short polish can stop on
    // its edge (validate's stribeck seed 12: train 9.49, held-out 8.11 where a point a polish step
    // away leaves 1.36 and 1.12, and creep joined to make up for it; the valley is 1-2 % wide in
    // Stribeck's impulse, a polish step 6 %): rings of 8 points a quarter, half, one and two polish
    // steps away (4 times as far in the second coordinate), the polish again from the best of them
    // while they find a better point (at most kRingRounds times).
    constexpr int kRingRounds = 3;
    for (int round = 0; spec.scans(true) && n == 2 && round < kRingRounds; ++round) {
      double ring_value = best_value;
      const std::vector<double> ring_best = best_on_rings(on_all(false), best.u, step, ring_value);
      if (!(ring_value < best_value)) break;
      best_value = ring_value;
      best.u = subplex(on_all(false), ring_best, step, opt.polish_evals * n, 1e-4, best_value);
    }
  }
  SetFit out = obj.score({best}, best_value);
  out.evaluations += coarse.evaluations;
  judge(library, baseline, out);
  log_fit("fit", out, t0, opt);
  return out;
}

double screening_gap(const SweepCells& sweep, const std::vector<CandidateSpec>& library,
                     const std::vector<MemberFit>& members, const FittedModel& baseline,
                     int threads) {
  CoarseObjective coarse(sweep, library, baseline, threads);
  return coarse.objective.train_gap(members, true);
}

namespace {

// The scanned one of a pair (first) and the one on one coordinate, or none when the pair is not
// searched across (searched_across).
std::optional<std::pair<const CandidateSpec*, const CandidateSpec*>> across_roles(
    const CandidateSpec& set_spec, const CandidateSpec& spec, bool resonance) {
  const bool narrow_first = set_spec.scans(true) && !spec.scans(true);
  const CandidateSpec& narrow = narrow_first ? set_spec : spec;
  const CandidateSpec& wide = narrow_first ? spec : set_spec;
  if (!narrow.scans(true) || (!narrow.scan_alone_only && !resonance) || wide.scans(true) ||
      wide.axes.size() != 1 || !wide.grid.empty() || !wide.scanned_across)
    return std::nullopt;
  return std::make_pair(&narrow, &wide);
}

// The pair of `base`'s one member and `spec` searched across (scan_across) when one of them is
// scanned alone only (or, with opt.resonance_across, scanned on top of a set as well) and the
// other is on one coordinate: at each point scan_across returns, the narrow effect searched on
// top of the wide one (profiled and scanned held) and both jointly; the members in the order
// (base, spec). None for other sets, or with opt.scan_across off.
std::vector<SetFit> fits_across(const SweepCells& sweep, const std::vector<CandidateSpec>& library,
                                const std::vector<MemberFit>& base, const CandidateSpec& spec,
                                const FittedModel& baseline, const FitOptions& opt,
                                Objective& coarse) {
  if (!opt.scan_across || base.size() != 1) return {};
  const CandidateSpec& set_spec = spec_of(library, base[0].effect);
  const auto roles = across_roles(set_spec, spec, opt.resonance_across);
  if (!roles) return {};
  const CandidateSpec& narrow = *roles->first;
  const CandidateSpec& wide = *roles->second;
  const bool narrow_first = &narrow == &set_spec;
  FitOptions once = opt;
  once.scan_across = false;
  once.resonance_across = false;
  std::vector<SetFit> fits;
  for (const MemberFit& w : scan_across(coarse, narrow, wide, opt)) {
    fits.push_back(fit_on_top(sweep, library, {w}, narrow, baseline, once));
    if (narrow_first) {
      std::swap(fits.back().members[0], fits.back().members[1]);
      fits.back().effects = effects_of(library, fits.back().members);
    }
  }
  return fits;
}

}  // namespace

bool searched_across(const std::vector<CandidateSpec>& library, const std::vector<MemberFit>& base,
                     const CandidateSpec& spec, bool resonance) {
  return base.size() == 1 &&
         across_roles(spec_of(library, base[0].effect), spec, resonance).has_value();
}

SetFit fit_on_top(const SweepCells& sweep, const std::vector<CandidateSpec>& library,
                  const std::vector<MemberFit>& base, const CandidateSpec& spec,
                  const FittedModel& baseline, const FitOptions& opt) {
  const auto t0 = std::chrono::steady_clock::now();
  // the new effect searched on top of the set, on the coarse cells, a set of one profiled at
  // every grid point (held under a scan, hundreds of points, and when larger: the profile costs
  // evaluations in proportion to its coordinates at every point); then all of them jointly. An
  // effect scanned alone only (a valley the grid steps over) is also scanned with the set held,
  // the better start kept; beside a one-coordinate effect also across its grid (fits_across).
  CoarseObjective coarse_set(sweep, library, baseline, opt.threads);
  const SweepCells& coarse_cells = coarse_set.cells;
  Objective& coarse = coarse_set.objective;
  // With opt.resonance_across the selection has screened the pair already: only across.
  SetFit out;
  out.train_gap = std::numeric_limits<double>::infinity();
  out.gap = out.train_gap;
  if (!opt.resonance_across) {
    const bool scan = spec.scans(base.empty());
    OnTop on_top(coarse, base, base.size() == 1 && !scan, opt);
    double value = 0;
    std::vector<MemberFit> start = coarse_search(on_top, spec, opt, scan, value);
    if (!scan && spec.scans(true)) {
      OnTop held(coarse, base, false, opt);
      double scanned = 0;
      std::vector<MemberFit> across = coarse_search(held, spec, opt, true, scanned);
      if (scanned < value) start = std::move(across);
    }
    out = fit_joint(coarse_cells, library, start, baseline, opt, JointStage::Search);
  }
  int evaluations = out.evaluations;
  for (SetFit& other : fits_across(sweep, library, base, spec, baseline, opt, coarse)) {
    evaluations += other.evaluations;
    if (other.train_gap < out.train_gap) out = std::move(other);
  }
  out.evaluations = evaluations + coarse.evaluations;
  log_fit("on top", out, t0, opt);
  return out;
}

SetFit fit_joint(const SweepCells& sweep, const std::vector<CandidateSpec>& library,
                 const std::vector<MemberFit>& start, const FittedModel& baseline,
                 const FitOptions& opt, JointStage stage) {
  const auto t0 = std::chrono::steady_clock::now();
  Objective obj(sweep, library, baseline, opt.threads);
  std::vector<MemberFit> members = start;
  std::vector<double> u0;
  for (const MemberFit& m : members) u0.insert(u0.end(), m.u.begin(), m.u.end());
  auto unpack = [&](const std::vector<double>& u) {
    std::size_t k = 0;
    for (MemberFit& m : members)
      for (double& v : m.u) v = u[k++];
  };
  const int n = static_cast<int>(u0.size());
  double value = std::numeric_limits<double>::infinity();
  auto f = [&](bool search) {
    return [&, search](const std::vector<double>& u) {
      unpack(u);
      return obj.train_gap(members, search);
    };
  };
  // the search (screening runs it on a subset of the cells), then on every cell: a short search
  // when the set was screened, mu recentered, the polish at the scoring rate
  if (stage != JointStage::Finish)
    u0 = subplex(f(true), u0, 0.02, opt.refine_evals * n + 8, 1e-3, value);
  if (stage == JointStage::Finish)
    u0 = subplex(f(true), u0, 0.01, opt.refine_evals * n / 2, 1e-3, value);
  if (stage != JointStage::Search) {
    unpack(u0);
    obj.recenter(members);
    u0 = subplex(f(false), u0, 0.005, opt.joint_polish_evals * n, 1e-4, value);
  }
  if (n == 0) value = obj.train_gap(members, stage == JointStage::Search);
  unpack(u0);
  if (stage == JointStage::Search) {
    SetFit out;
    out.members = members;
    out.effects = effects_of(library, members);
    out.train_gap = value;
    out.gap = std::numeric_limits<double>::infinity();
    out.evaluations = obj.evaluations;
    return out;
  }
  SetFit out = obj.score(members, value);
  judge(library, baseline, out);
  log_fit("joint", out, t0, opt);
  return out;
}

}  // namespace idm::analysis
