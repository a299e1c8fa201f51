// Running and scoring validate (validate.h): generate, diagnose, compare with the truth.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <sstream>

#include "analysis/report_json.h"
#include "analysis/unknown_effects.h"
#include "analysis/validate.h"

namespace idm::analysis {

namespace {

struct Generated {
  std::vector<TrialInfo> infos;
  std::vector<TrialSeries> series;
};

Generated generate(const Scenario& sc, const model::SimConfig& sim, const SweepPlan& plan) {
  Generated g;
  std::map<std::string, double> unused;
  std::unique_ptr<HiddenDistortion> distortion;
  SweepPlan p = plan;
  if (!sc.unknown.empty()) {
    distortion = make_unknown_effect(sc.unknown, sc.unknown_strength, sc.stage.stage.stroke_m,
                                     plan.freqs_hz.back(), unused);
    p.distortion = distortion.get();
  }
  simulate_sweep(sc.stage, sim, p, [&](const TrialInfo& info, TrialSeries&& s) {
    g.infos.push_back(info);
    g.series.push_back(std::move(s));
  });
  return g;
}

}  // namespace

std::vector<double> true_footprint(const Scenario& sc, const SweepCells& cells,
                                   const GapEvaluation& units) {
  std::vector<double> out(cells.cells.size(), 0.0);
  if (sc.sim.effects.empty() && sc.unknown.empty()) return out;
  if (sc.unknown.empty()) {
    ModelConfig with, bare;
    with.stage = bare.stage = sc.stage.stage;
    with.effects = sc.sim.effects;
    const std::vector<CellPrediction> a = predict_sweep(cells, with, 1),
                                      b = predict_sweep(cells, bare, 1);
    for (std::size_t c = 0; c < out.size(); ++c)
      out[c] =
          prediction_change(units.cells[c], a[c].steady_step_m, a[c].step_sd_m, a[c].region,
                            b[c].steady_step_m, b[c].step_sd_m, b[c].region, cells.reading_sd_m);
    return out;
  }
  model::SimConfig quiet = sc.sim;
  quiet.noise_m = 0;
  SweepPlan one = sc.plan;
  one.trials = 1;
  model::StageFile exact = sc.stage;
  exact.interferometer.resolution_m = 1e-12;
  Scenario with = sc;
  with.stage = exact;
  Scenario without = with;
  without.unknown.clear();
  const Generated a = generate(with, quiet, one), b = generate(without, quiet, one);
  for (std::size_t i = 0; i < a.infos.size(); ++i) {
    const TrialFeatures fa = trial_features(a.infos[i], a.series[i], 1e-12, 0);
    const TrialFeatures fb = trial_features(b.infos[i], b.series[i], 1e-12, 0);
    for (std::size_t c = 0; c < cells.cells.size(); ++c) {
      const CellKey& k = cells.cells[c].key;
      if (k.freq_hz == a.infos[i].freq_hz && k.duty == a.infos[i].duty &&
          k.stroke_m == a.infos[i].stroke_m)
        out[c] = prediction_change(units.cells[c], fa.steady_step_m, 0, fa.region, fb.steady_step_m,
                                   0, fb.region, cells.reading_sd_m);
    }
  }
  return out;
}

SweepCells scenario_sweep(const Scenario& sc) {
  const Generated g = generate(sc, sc.sim, sc.plan);
  return collect_cells(sc.stage, g.infos, g.series,
                       "validate:" + sc.name + ":seed" + std::to_string(sc.seed));
}

namespace {

// The hidden pair at its true parameters against each member's partner fitted alone (the
// diagnosis's candidates): ValidateRun::truth_cannot_show.
void score_truth(const Scenario& sc, const SweepCells& cells, const Diagnosis& d, int threads,
                 ValidateRun& run) {
  ModelConfig m;
  m.stage = cells.stage.stage;
  m.effects = sc.sim.effects;
  m.chain_rate_hz = score_rate_hz(m.effects);
  SetFit truth;
  truth.fitted = fit_model(cells, m, threads, 4);
  truth.gap = truth.fitted.test.gap;
  run.truth_gap = truth.gap;
  run.truth_scored = true;
  for (const std::string& member : sc.expected)
    for (const SetFit& alone : d.candidates) {
      const std::vector<std::string> n = alone.names();
      if (n.size() != 1 || n[0] == member ||
          std::find(sc.expected.begin(), sc.expected.end(), n[0]) == sc.expected.end())
        continue;
      if (!earns_place(truth, alone) && !into_noise(truth, alone))
        run.truth_cannot_show.push_back(member);
    }
  std::vector<std::string> shown;
  for (const std::string& member : sc.expected)
    if (std::find(run.truth_cannot_show.begin(), run.truth_cannot_show.end(), member) ==
        run.truth_cannot_show.end())
      shown.push_back(member);
  run.missed_beyond_sweep = !run.correct && !run.truth_cannot_show.empty() && run.named == shown;
  run.fit_short = run.named == sc.expected && run.unexplained && truth.gap <= kExplainedGap;
}

// The diagnosis of a run's sweep and how it compares with what was hidden.
void diagnose_run(const Scenario& sc, int threads, ValidateRun& run, Diagnosis* out) {
  const SweepCells cells = scenario_sweep(sc);
  DiagnoseOptions opt;
  opt.fit.threads = threads;
  const Diagnosis d = diagnose(cells, opt);
  for (const model::EffectSpec& e : d.chosen) run.named.push_back(e.name);
  std::sort(run.named.begin(), run.named.end());
  for (const Ambiguity& a : d.ambiguous)
    for (const std::string& n : a.alternative) run.ambiguous_with.push_back(n);
  for (const NotIdentifiable& n : d.not_identifiable) run.not_identifiable.push_back(n.effect);
  run.correct = run.named == run.expected;
  if (sc.cls == "not_identifiable")
    run.correct = run.correct && std::find(run.not_identifiable.begin(), run.not_identifiable.end(),
                                           sc.name.substr(17)) != run.not_identifiable.end();
  run.unexplained = d.unexplained.significant;
  // an effect the library does not have: right only when nothing is named and the report says so
  if (sc.expect_unexplained) run.correct = run.correct && run.unexplained;
  run.gap_before = d.gap_before;
  run.gap_after = d.gap_after;
  run.shrink = d.named ? d.shrink : (d.candidates.empty() ? 0.0 : d.candidates.front().shrink);
  // where: what the report locates against where the hidden effects act (the named effects'
  // footprint; with nothing named, the departure from the stage as stage.yaml describes it)
  if (sc.cls != "none" && sc.cls != "not_identifiable") {
    const std::vector<double> truth = true_footprint(sc, cells, d.after.test);
    std::vector<double> located;
    for (std::size_t c = 0; c < cells.cells.size(); ++c)
      located.push_back(d.named ? d.where.cells[c].effect_gap : d.where.cells[c].departure);
    run.where_rank = spearman(located, truth);
    run.where_scored = true;
  }
  if (sc.cls == "pair") score_truth(sc, cells, d, threads, run);
  if (out) *out = d;
}

}  // namespace

ValidateRun validate_one(const Scenario& sc, int threads, Diagnosis* out) {
  const auto t0 = std::chrono::steady_clock::now();
  ValidateRun run;
  run.hidden = sc.name;
  run.cls = sc.cls;
  run.setup = sc.describe();
  run.params = sc.params;
  run.seed = sc.seed;
  run.expected = sc.expected;
  run.expect_unexplained = sc.expect_unexplained;
  try {
    diagnose_run(sc, threads, run, out);
  } catch (const std::exception& e) {
    run.correct = false;
    run.error = e.what();
  }
  run.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return run;
}

ValidateResult run_validate(const ValidateOptions& options, void (*progress)(const ValidateRun&)) {
  ValidateResult r;
  const std::vector<std::string> cases =
      options.cases.empty() ? validate_cases(options.quick) : options.cases;
  for (const std::string& c : cases) case_class(c);  // every name checked before the first run
  int correct = 0;
  for (int k = 0; k < options.seeds; ++k)
    for (const std::string& c : cases) {
      const Scenario sc =
          make_scenario(c, options.first_seed + static_cast<std::uint64_t>(k), options.quick);
      ValidateRun run = validate_one(sc, options.threads);
      auto& tally = r.by_effect[c];
      ++tally.first;
      ClassScore& cs = r.by_class[run.cls];
      ++cs.runs;
      cs.shrink_sum += run.shrink;
      if (run.unexplained) ++cs.unexplained_said;
      if (run.where_scored) {
        cs.where_sum += run.where_rank;
        ++cs.where_runs;
      }
      if (run.correct) {
        ++tally.second;
        ++cs.correct;
        ++correct;
      } else if (run.missed_beyond_sweep) {
        ++cs.missed_beyond_sweep;
      }
      if (run.fit_short) ++cs.fit_short;
      if (progress) progress(run);
      r.runs.push_back(std::move(run));
    }
  r.accuracy =
      r.runs.empty() ? 0.0 : static_cast<double>(correct) / static_cast<double>(r.runs.size());
  return r;
}

namespace {
std::string names(const std::vector<std::string>& v) {
  std::string out = "[";
  for (std::size_t i = 0; i < v.size(); ++i) out += (i ? ", " : "") + json_string(v[i]);
  return out + "]";
}
}  // namespace

std::string validate_json(const ValidateResult& r) {
  std::ostringstream s;
  s << "{\"runs\": [\n";
  for (std::size_t i = 0; i < r.runs.size(); ++i) {
    const ValidateRun& run = r.runs[i];
    s << "  {\"hidden\": " << json_string(run.hidden) << ", \"class\": " << json_string(run.cls)
      << ", \"params\": {";
    bool first = true;
    for (const auto& [k, v] : run.params) {
      s << (first ? "" : ", ") << json_string(k) << ": " << json_number(v);
      first = false;
    }
    s << "}, \"seed\": " << run.seed << ", \"setup\": " << json_string(run.setup)
      << ", \"named\": " << names(run.named) << ", \"expected\": " << names(run.expected)
      << ", \"correct\": " << (run.correct ? "true" : "false")
      << ", \"unexplained\": " << (run.unexplained ? "true" : "false")
      << ", \"expect_unexplained\": " << (run.expect_unexplained ? "true" : "false")
      << ", \"ambiguous_with\": " << names(run.ambiguous_with)
      << ", \"shrink\": " << json_number(run.shrink)
      << ", \"gap_before\": " << json_number(run.gap_before)
      << ", \"gap_after\": " << json_number(run.gap_after)
      << ", \"where_rank\": " << (run.where_scored ? json_number(run.where_rank) : "null")
      << ", \"truth_gap\": " << (run.truth_scored ? json_number(run.truth_gap) : "null")
      << ", \"truth_cannot_show\": " << names(run.truth_cannot_show)
      << ", \"missed_beyond_sweep\": " << (run.missed_beyond_sweep ? "true" : "false")
      << ", \"fit_short\": " << (run.fit_short ? "true" : "false")
      << ", \"seconds\": " << json_number(run.seconds)
      << ", \"error\": " << (run.error.empty() ? "null" : json_string(run.error)) << "}"
      << (i + 1 < r.runs.size() ? "," : "") << "\n";
  }
  s << "],\n\"accuracy\": " << json_number(r.accuracy) << ",\n\"by_effect\": {";
  bool first = true;
  for (const auto& [e, t] : r.by_effect) {
    s << (first ? "" : ", ") << json_string(e) << ": {\"runs\": " << t.first
      << ", \"correct\": " << t.second << "}";
    first = false;
  }
  s << "},\n\"by_class\": {";
  first = true;
  for (const auto& [c, t] : r.by_class) {
    s << (first ? "" : ", ") << json_string(c) << ": {\"runs\": " << t.runs
      << ", \"correct\": " << t.correct << ", \"missed_beyond_sweep\": " << t.missed_beyond_sweep
      << ", \"fit_short\": " << t.fit_short << ", \"unexplained_said\": " << t.unexplained_said
      << ", \"mean_shrink\": " << json_number(t.shrink_sum / t.runs) << ", \"mean_where_rank\": "
      << (t.where_runs ? json_number(t.where_sum / t.where_runs) : "null") << "}";
    first = false;
  }
  s << "}}\n";
  return s.str();
}

std::string validate_table(const ValidateResult& r) {
  std::ostringstream s;
  char buf[200];
  std::snprintf(buf, sizeof buf, "accuracy %.3f (%zu runs)\n", r.accuracy, r.runs.size());
  s << buf;
  const auto errors = std::count_if(r.runs.begin(), r.runs.end(),
                                    [](const ValidateRun& run) { return !run.error.empty(); });
  if (errors > 0) s << "  " << errors << " run(s) stopped with an error (counted as wrong)\n";
  s << "  class              correct   says unexplained   mean shrink   where (rank correlation)\n";
  for (const auto& [c, t] : r.by_class) {
    std::snprintf(
        buf, sizeof buf, "  %-18s %3d / %-3d %6d / %-3d       %6.1f %%     %s\n", c.c_str(),
        t.correct, t.runs, t.unexplained_said, t.runs, 100 * t.shrink_sum / t.runs,
        t.where_runs ? std::to_string(t.where_sum / t.where_runs).substr(0, 5).c_str() : "-");
    s << buf;
  }
  for (const auto& [c, t] : r.by_class)
    if (t.missed_beyond_sweep > 0) {
      std::snprintf(
          buf, sizeof buf,
          "  %s: %d of the %d misses name the hidden set but for a member that the true set "
          "itself does not earn a place for in that sweep\n",
          c.c_str(), t.missed_beyond_sweep, t.runs - t.correct);
      s << buf;
    }
  for (const auto& [c, t] : r.by_class)
    if (t.fit_short > 0) {
      std::snprintf(buf, sizeof buf,
                    "  %s: %d named the hidden set and said a remainder unexplained that the true "
                    "set leaves within the noise (the fit stopped short)\n",
                    c.c_str(), t.fit_short);
      s << buf;
    }
  for (const auto& [e, t] : r.by_effect) {
    std::snprintf(buf, sizeof buf, "  %-40s %d / %d\n", e.c_str(), t.second, t.first);
    s << buf;
  }
  return s.str();
}

}  // namespace idm::analysis
