#include "analysis/where.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numeric>
#include <set>

#include "model/range.h"

namespace idm::analysis {

namespace {

std::vector<double> ranks(const std::vector<double>& v) {
  std::vector<std::size_t> order(v.size());
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return v[a] < v[b]; });
  std::vector<double> r(v.size());
  for (std::size_t i = 0; i < order.size();) {
    std::size_t j = i;
    while (j + 1 < order.size() && v[order[j + 1]] == v[order[i]]) ++j;
    for (std::size_t k = i; k <= j; ++k) r[order[k]] = 0.5 * (static_cast<double>(i + j));
    i = j + 1;
  }
  return r;
}

std::string fmt(const char* f, double v) {
  char b[64];
  std::snprintf(b, sizeof b, f, v);
  return b;
}

// How close a cell is to the nearest region boundary of the impulse model: minus the distance in
// log impulse ratio (0 on a boundary).
double boundary_closeness(const model::StageParams& stage, const CellKey& k) {
  const double beta = model::impulse_ratio(stage, k.freq_hz, k.stroke_m);
  const model::RegionBoundaries b = model::region_boundaries(std::min(k.duty, 1.0 - k.duty));
  double d = 1e300;
  for (double v : {b.cutoff, b.first_rest_a, b.first_rest_b})
    if (v > 0) d = std::min(d, std::fabs(std::log(beta / v)));
  return -d;
}

double mean_where(const SweepCells& sweep, const std::vector<double>& v,
                  bool (*pick)(const CellKey&, double), double arg) {
  double s = 0;
  int n = 0;
  for (std::size_t c = 0; c < v.size(); ++c)
    if (pick(sweep.cells[c].key, arg)) {
      s += v[c];
      ++n;
    }
  return n ? s / n : 0.0;
}

}  // namespace

double spearman(const std::vector<double>& a, const std::vector<double>& b) {
  if (a.size() != b.size() || a.size() < 3) return 0;
  const std::vector<double> ra = ranks(a), rb = ranks(b);
  const double n = static_cast<double>(a.size());
  const double ma = std::accumulate(ra.begin(), ra.end(), 0.0) / n,
               mb = std::accumulate(rb.begin(), rb.end(), 0.0) / n;
  double sab = 0, saa = 0, sbb = 0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    sab += (ra[i] - ma) * (rb[i] - mb);
    saa += (ra[i] - ma) * (ra[i] - ma);
    sbb += (rb[i] - mb) * (rb[i] - mb);
  }
  return saa > 0 && sbb > 0 ? sab / std::sqrt(saa * sbb) : 0.0;
}

double prediction_change(const CellResidual& cell, double step_a, double sd_a,
                         model::Region region_a, double step_b, double sd_b, model::Region region_b,
                         double reading_sd_m) {
  const double d = cell.se_m > 0 ? (step_a - step_b) / cell.se_m : 0.0;
  double s = 0;
  if (cell.trials > 1) {
    const double q = 2.0 * reading_sd_m * reading_sd_m;
    s = std::log((sd_a * sd_a + q) / (sd_b * sd_b + q)) /
        log_sample_variance_moments(cell.trials - 1).sd;
  }
  const double l = region_a == region_b ? 0.0 : kSignificantResidual;
  return std::sqrt(d * d + s * s + l * l);
}

WhereReport where_of(const SweepCells& sweep, const FittedModel& baseline, const FittedModel& after,
                     const std::vector<CellPrediction>* without,
                     const std::vector<CellPrediction>& described) {
  WhereReport w;
  const Calibration& cal = after.calibration;
  Calibration as_described;  // alpha 1, stage.yaml's mu
  as_described.mu = as_described.mu_sim = sweep.stage.stage.friction_coefficient;
  const GapEvaluation departure = evaluate_gap(sweep, described, as_described, TrialSet::Test);
  const double q = 2.0 * sweep.reading_sd_m * sweep.reading_sd_m;
  std::vector<double> gap, rest, away;
  for (std::size_t c = 0; c < sweep.cells.size(); ++c) {
    const Cell& cell = sweep.cells[c];
    const CellResidual& r = after.test.cells[c];
    CellWhere cw;
    const CellPrediction& p = after.predictions[c];
    if (without) {
      const CellPrediction& o = (*without)[c];
      cw.effect_gap = prediction_change(r, cal.step(p), std::fabs(cal.alpha) * p.step_sd_m,
                                        p.region, cal.step(o), std::fabs(cal.alpha) * o.step_sd_m,
                                        o.region, sweep.reading_sd_m);
    }
    std::vector<double> steps;
    for (const auto* v : {&cell.train, &cell.test})
      for (const TrialFeatures& t : *v) steps.push_back(t.steady_step_m);
    if (steps.size() > 1) {
      double mean = 0, ss = 0;
      for (double s : steps) mean += s / static_cast<double>(steps.size());
      for (double s : steps) ss += (s - mean) * (s - mean);
      const double var = ss / static_cast<double>(steps.size() - 1);
      const double expected = q + std::pow(cal.alpha * p.step_sd_m, 2);
      const double z = std::log((var + q) / (expected + q)) /
                       log_sample_variance_moments(static_cast<int>(steps.size()) - 1).sd;
      cw.spread_excess = std::max(0.0, z);
    }
    cw.remainder = r.residual;
    cw.departure = departure.cells[c].residual;
    w.cells.push_back(cw);
    gap.push_back(cw.effect_gap);
    rest.push_back(cw.remainder);
    away.push_back(cw.departure);
  }
  for (const CellResidual& r : baseline.test.cells)
    if (r.significant) w.significant_cells.push_back(r.key);
  if (without) {
    w.summary = pattern_summary(sweep, gap, "The named effects' footprint (effect_gap)");
  } else {
    std::vector<double> base;
    for (const CellResidual& r : baseline.test.cells) base.push_back(r.residual);
    w.summary = pattern_summary(sweep, base, "The gap of the impulse model");
  }
  w.summary_after = pattern_summary(sweep, rest, "What is left after the named effects");
  w.summary_departure =
      pattern_summary(sweep, away,
                      "Against the stage as stage.yaml describes it (mu " +
                          model::format_number(sweep.stage.stage.friction_coefficient) +
                          ", alpha 1, no effect), the departure (a calibration cannot hide it)");
  return w;
}

namespace {

// How many cells, the largest first, carry 80 % of v's sum of squares, and the span of their
// frequencies and duties: "K of N cells carry 80 % of it (...)."
std::string carrying_part(const SweepCells& sweep, const std::vector<double>& v) {
  const std::size_t n = v.size();
  double total = 0;
  for (double x : v) total += x * x;
  std::vector<double> sorted = v;
  std::sort(sorted.rbegin(), sorted.rend());
  double part = 0;
  std::size_t carrying = 0;
  while (carrying < n && part < 0.8 * total) {
    part += sorted[carrying] * sorted[carrying];
    ++carrying;
  }
  double f_lo = 1e300, f_hi = 0, d_lo = 1, d_hi = 0;
  for (std::size_t c = 0; c < n; ++c)
    if (v[c] >= sorted[carrying - 1]) {
      f_lo = std::min(f_lo, sweep.cells[c].key.freq_hz);
      f_hi = std::max(f_hi, sweep.cells[c].key.freq_hz);
      d_lo = std::min(d_lo, sweep.cells[c].key.duty);
      d_hi = std::max(d_hi, sweep.cells[c].key.duty);
    }
  return std::to_string(carrying) + " of " + std::to_string(n) + " cells carry 80 % of it (" +
         fmt("%g", f_lo) + "-" + fmt("%g", f_hi) + " Hz, duty " + fmt("%g", d_lo) + "-" +
         fmt("%g", d_hi) + ").";
}

// How v follows the sweep's axes: frequency, the fast phase, stroke, direction and closeness to
// the impulse model's region boundaries (only the clear trends).
std::vector<std::string> trends_of(const SweepCells& sweep, const std::vector<double>& v,
                                   const std::set<double>& strokes, bool fwd, bool rev) {
  std::vector<std::string> trends;
  std::vector<double> f, fast, close;
  for (const Cell& c : sweep.cells) {
    f.push_back(c.key.freq_hz);
    fast.push_back(std::min(c.key.duty, 1.0 - c.key.duty));
    close.push_back(boundary_closeness(sweep.stage.stage, c.key));
  }
  const double rf = spearman(v, f), rd = spearman(v, fast), rb = spearman(v, close);
  if (std::fabs(rf) >= 0.4)
    trends.push_back(std::string(rf > 0 ? "grows" : "falls") +
                     " with frequency (rank correlation " + fmt("%.2f", rf) + ")");
  if (std::fabs(rd) >= 0.4)
    trends.push_back(std::string(rd < 0
                                     ? "grows as the fast phase gets shorter (duty towards 0 or 1)"
                                     : "grows towards duty 0.5") +
                     " (rank correlation " + fmt("%.2f", -rd) + ")");
  if (strokes.size() > 1) {
    const double big = mean_where(
        sweep, v, [](const CellKey& c, double s) { return c.stroke_m == s; }, *strokes.rbegin());
    const double small = mean_where(
        sweep, v, [](const CellKey& c, double s) { return c.stroke_m == s; }, *strokes.begin());
    if (big > 1.5 * small || small > 1.5 * big)
      trends.push_back(
          std::string("is larger at the ") + (big > small ? "larger" : "smaller") + " stroke (" +
          fmt("%.2g", std::max(big, small) / std::max(1e-12, std::min(big, small))) + " times)");
  }
  if (fwd && rev) {
    const double a = mean_where(
        sweep, v, [](const CellKey& c, double) { return c.duty < 0.5; }, 0);
    const double b = mean_where(
        sweep, v, [](const CellKey& c, double) { return c.duty > 0.5; }, 0);
    if (a > 2 * b || b > 2 * a)
      trends.push_back(std::string("acts mostly in one direction: duty ") +
                       (a > b ? "< 0.5" : "> 0.5") + " carries " +
                       fmt("%.2g", std::max(a, b) / std::max(1e-12, std::min(a, b))) +
                       " times the other's");
    else
      trends.push_back("is about the same in both directions");
  }
  if (rb >= 0.4)
    trends.push_back("sits near the region boundaries of the impulse model (rank correlation " +
                     fmt("%.2f", rb) + " with closeness to the nearest)");
  return trends;
}

}  // namespace

std::string pattern_summary(const SweepCells& sweep, const std::vector<double>& v,
                            const std::string& what) {
  const std::size_t n = v.size();
  if (n == 0) return what + ": no cells.";
  std::size_t top = 0;
  for (std::size_t c = 1; c < n; ++c)
    if (v[c] > v[top]) top = c;
  const CellKey& k = sweep.cells[top].key;
  std::set<double> strokes;
  bool fwd = false, rev = false;
  for (const Cell& c : sweep.cells) {
    strokes.insert(c.key.stroke_m);
    fwd = fwd || c.key.duty < 0.5;
    rev = rev || c.key.duty > 0.5;
  }
  std::string s = what;
  const std::string at =
      fmt("%g Hz", k.freq_hz) + ", duty " + fmt("%g", k.duty) +
      (strokes.size() > 1 ? ", stroke " + fmt("%.4g", k.stroke_m * 1e6) + " um" : "");
  if (v[top] < kSignificantResidual)
    return s + " is within the noise at all " + std::to_string(n) + " cells (largest " +
           fmt("%.2g", v[top]) + " " + kGapUnit + " at " + at + ").";
  s += " is largest at " + at + " (" + fmt("%.3g", v[top]) + " " + kGapUnit + "); " +
       carrying_part(sweep, v);
  const std::vector<std::string> trends = trends_of(sweep, v, strokes, fwd, rev);
  if (!trends.empty()) {
    s += " It ";
    for (std::size_t i = 0; i < trends.size(); ++i)
      s += (i == 0 ? "" : (i + 1 == trends.size() ? " and " : ", ")) + trends[i];
    s += ".";
  }
  return s;
}

}  // namespace idm::analysis
