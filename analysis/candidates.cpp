#include "analysis/candidates.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <limits>
#include <set>

#include <nlopt.hpp>

#include "model/yaml_util.h"

namespace idm::analysis {

const std::vector<CandidateSpec>& candidate_library() {
  // Ranges: what a piezo stage of this kind can plausibly have (wider than any stage we know of).
  static const std::vector<CandidateSpec> lib = {
      {"amplifier", {{"cutoff_hz", 300, 30e3, true}}, {{{"order", 2}}, {{"order", 1}}}, {}},
      {"actuator_compliance",
       {{"stiffness_n_m", 2e5, 2e9, true}, {"damping_n_s_m", 1, 5e3, true}}, {{}}, {}},
      {"hysteresis", {{"ratio", 0.005, 0.45, false}}, {{}}, {}},
      {"creep", {{"per_decade", 0.001, 0.1, true}}, {{}}, {}},
      {"stribeck",
       {{"static_over_kinetic", 1.01, 2.5, false}, {"stribeck_velocity_m_s", 1e-5, 0.1, true}}, {{}}, {}},
      {"friction_spread", {{"relative_sd", 0.005, 0.4, true}, {"mean_shift", -0.3, 0.3, false}}, {{}}, {}},
      {"tilt", {{"angle_deg", -10, 10, false}}, {{}}, {}},
      {"quantization",
       {{"bits", 6, 16, false}, {"update_rate_hz", 1e4, 1e6, true}},
       {{}},
       {{6, 2e4}, {8, 2e4}, {10, 2e4}, {12, 2e4}, {6, 1e5}, {8, 1e5}, {10, 1e5}, {12, 1e5}, {8, 1e6}, {12, 1e6}}},
  };
  return lib;
}

std::string missing_signature(const SweepCells& sweep, const std::string& effect) {
  if (effect == "hysteresis") {
    std::set<double> strokes;
    for (const Cell& c : sweep.cells) strokes.insert(c.key.stroke_m);
    if (strokes.size() < 2) return "a second stroke (hysteresis depends on stroke, not frequency)";
  }
  if (effect == "tilt") {
    bool fwd = false, rev = false;
    for (const Cell& c : sweep.cells) {
      if (c.key.duty < 0.5) fwd = true;
      if (c.key.duty > 0.5) rev = true;
    }
    if (!(fwd && rev))
      return "both directions (duties below and above 0.5): in one direction a tilt is a friction change";
  }
  if (effect == "friction_spread") {
    bool two = false;
    for (const Cell& c : sweep.cells) two = two || (c.train.size() >= 2 && c.test.size() >= 2);
    if (!two) return "at least 4 trials per cell (the spread needs 2 to fit and 2 held out)";
  }
  return "";
}

model::SimConfig config_with(const std::vector<model::EffectSpec>& effects, bool search) {
  model::SimConfig sim;
  sim.plant = model::PlantKind::Rigid;
  sim.effects = effects;
  sim.internal_rate_hz = search ? search_rate_for(sim) : internal_rate_for(sim);
  return sim;
}

GapEvaluation evaluate_config(const SweepCells& sweep, const model::SimConfig& sim, int threads, TrialSet set) {
  const std::vector<CellPrediction> pred = predict_sweep(sweep, sim, threads);
  return evaluate_gap(sweep, pred, fit_step_scale(sweep, pred), set);
}

namespace {

double to_value(const FitParam& p, double u) {
  u = std::clamp(u, 0.0, 1.0);
  const double v = p.log_scale ? std::exp(std::log(p.lo) + u * (std::log(p.hi) - std::log(p.lo))) : p.lo + u * (p.hi - p.lo);
  return std::clamp(v, p.lo, p.hi);
}

struct Trial {
  double train_gap = std::numeric_limits<double>::infinity();
  std::vector<double> u;
  std::map<std::string, double> params;
};

}  // namespace

CandidateResult fit_candidate(const SweepCells& sweep, const std::vector<model::EffectSpec>& base,
                              const CandidateSpec& spec, double gap_before, const FitOptions& opt) {
  const auto t_start = std::chrono::steady_clock::now();
  CandidateResult best;
  best.effect = spec.effect;
  best.train_gap = std::numeric_limits<double>::infinity();
  int evals = 0;
  auto params_of = [&](const std::map<std::string, double>& fixed, const std::vector<double>& u) {
    std::map<std::string, double> p = fixed;
    for (std::size_t i = 0; i < spec.fit.size(); ++i) p[spec.fit[i].name] = to_value(spec.fit[i], u[i]);
    return p;
  };
  // The search (grid and refinement) runs at the cheaper plant rate; the winner is scored at the
  // converged one, so the gap it reports carries no integration error.
  auto config_of = [&](const std::map<std::string, double>& p, bool search) {
    std::vector<model::EffectSpec> effects = base;
    effects.push_back(model::complete_effect({spec.effect, p}, "candidate " + spec.effect));
    return config_with(effects, search);
  };
  auto objective = [&](const std::map<std::string, double>& p) {
    ++evals;
    const GapEvaluation e = evaluate_config(sweep, config_of(p, true), opt.threads, TrialSet::Train);
    return e.gap;
  };

  auto grid_points = [&](std::size_t n) { return n == 1 ? opt.grid_1d : opt.grid_2d; };  // per axis
  // Subplex from `start` (in [0, 1] per parameter), keeping the best point it meets in `local`.
  auto refine = [&](const std::map<std::string, double>& fixed, const std::vector<double>& start,
                    double step, double xtol, Trial& local) {
    if (opt.refine_evals <= 0) return;
    const std::size_t n = start.size();
    nlopt::opt solver(nlopt::LN_SBPLX, static_cast<unsigned>(n));
    solver.set_lower_bounds(std::vector<double>(n, 0.0));
    solver.set_upper_bounds(std::vector<double>(n, 1.0));
    solver.set_initial_step(std::vector<double>(n, step));
    solver.set_maxeval(opt.refine_evals * static_cast<int>(n));
    solver.set_xtol_abs(xtol);
    std::function<double(const std::vector<double>&)> eval = [&](const std::vector<double>& x) {
      const auto p = params_of(fixed, x);
      const double v = objective(p);
      if (v < local.train_gap) local = {v, x, p};
      return v;
    };
    solver.set_min_objective(
        [](const std::vector<double>& x, std::vector<double>&, void* data) {
          return (*static_cast<std::function<double(const std::vector<double>&)>*>(data))(x);
        },
        &eval);
    std::vector<double> x = start;
    double fx = 0;
    try {
      solver.optimize(x, fx);
    } catch (const nlopt::roundoff_limited&) {
    } catch (const nlopt::forced_stop&) {
    }
  };

  Trial winner;
  std::map<std::string, double> winner_fixed;
  if (!spec.grid.empty()) {
    for (const std::vector<double>& g : spec.grid) {
      std::map<std::string, double> p;
      for (std::size_t i = 0; i < spec.fit.size(); ++i) p[spec.fit[i].name] = g[i];
      const double v = objective(p);
      if (v < winner.train_gap) winner = {v, {}, p};
    }
  } else {
    for (const std::map<std::string, double>& fixed : spec.variants) {
      const std::size_t n = spec.fit.size();
      const int pts = grid_points(n);
      Trial local;
      std::vector<double> u(n);
      const int total = n == 1 ? pts : pts * pts;
      std::vector<Trial> grid;
      for (int k = 0; k < total; ++k) {
        u[0] = (k % pts) / double(pts - 1);
        if (n == 2) u[1] = (k / pts) / double(pts - 1);
        const auto p = params_of(fixed, u);
        const double v = objective(p);
        grid.push_back({v, u, p});
        if (v < local.train_gap) local = {v, u, p};
      }
      // Refined from the best grid point and, for two parameters, from the next best ones that
      // are not its grid neighbours (a narrow valley, e.g. the actuator's resonance against its
      // damping, can hide between grid points and trap a single start).
      std::vector<std::vector<double>> starts{local.u};
      if (n == 2) {
        std::sort(grid.begin(), grid.end(), [](const Trial& a, const Trial& b) { return a.train_gap < b.train_gap; });
        const double cell = 1.0 / (pts - 1);
        for (const Trial& g : grid) {
          if (starts.size() >= static_cast<std::size_t>(opt.starts_2d)) break;
          bool near = false;
          for (const std::vector<double>& st : starts)
            near = near || (std::fabs(g.u[0] - st[0]) <= cell * 1.01 && std::fabs(g.u[1] - st[1]) <= cell * 1.01);
          if (!near) starts.push_back(g.u);
        }
      }
      for (const std::vector<double>& start : starts) refine(fixed, start, 0.5 / (pts - 1), 1e-3, local);
      if (local.train_gap < winner.train_gap) {
        winner = local;
        winner_fixed = fixed;
      }
    }
    // The winner is polished with a step a tenth as large: with little noise the gap is a sharp
    // V around the optimum (1 % in a stage's stiffness can be 30 noise units), and a refinement
    // that ran out of evaluations partway down it leaves most of the gap behind.
    if (opt.polish && !winner.u.empty())
      refine(winner_fixed, winner.u, 0.05 / (grid_points(winner.u.size()) - 1), 1e-4, winner);
  }
  best.params = winner.params;
  best.train_gap = winner.train_gap;
  const model::SimConfig sim = config_of(winner.params, false);
  best.eval = evaluate_config(sweep, sim, opt.threads, TrialSet::Test);
  best.gap = best.eval.gap;
  best.step_scale = best.eval.step_scale;
  best.shrink = gap_before > 0 ? 1.0 - best.gap / gap_before : 0.0;
  best.evaluations = evals + 1;
  if (std::getenv("IDM_GAP_VERBOSE"))
    std::fprintf(stderr, "  fit %s (+%zu fixed): %d evaluations, %.2f s, train gap %.3g, held-out %.3g\n",
                 spec.effect.c_str(), base.size(), best.evaluations,
                 std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count(), best.train_gap,
                 best.gap);
  // Plausibility: a fit on the bound of its range, or a step scale no stage has.
  for (std::size_t i = 0; i < spec.fit.size() && spec.grid.empty(); ++i)
    if (!winner.u.empty() && (winner.u[i] < 0.01 || winner.u[i] > 0.99)) {
      best.plausible = false;
      best.note = spec.fit[i].name + " ended on the bound of its plausible range [" +
                  model::format_number(spec.fit[i].lo) + ", " + model::format_number(spec.fit[i].hi) + "]";
    }
  if (!(best.step_scale > 0.05 && best.step_scale <= 2.0)) {
    best.plausible = false;
    best.note = "needs a step scale of " + model::format_number(best.step_scale) + ", outside (0.05, 2]";
  }
  return best;
}

}  // namespace idm::analysis
