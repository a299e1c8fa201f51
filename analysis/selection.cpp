#include "analysis/selection.h"

#include <algorithm>
#include <cstdio>
#include <sstream>

#include "model/yaml_util.h"

namespace idm::analysis {

namespace {
std::vector<std::string> names_of(const std::vector<model::EffectSpec>& e) {
  std::vector<std::string> out;
  for (const model::EffectSpec& s : e) out.push_back(s.name);
  return out;
}
bool wanted(const DiagnoseOptions& o, const std::string& effect) {
  return o.effects.empty() || std::find(o.effects.begin(), o.effects.end(), effect) != o.effects.end();
}
}  // namespace

Diagnosis diagnose(const SweepCells& sweep, const DiagnoseOptions& options) {
  Diagnosis d;
  d.baseline = baseline_gap(sweep, options.fit.threads);
  d.gap_before = d.baseline.gap;
  d.where = where_summary(d.baseline);
  std::vector<const CandidateSpec*> specs;
  for (const CandidateSpec& spec : candidate_library()) {
    if (!wanted(options, spec.effect)) continue;
    const std::string needs = missing_signature(sweep, spec.effect);
    if (!needs.empty()) {
      d.not_identifiable.push_back({spec.effect, needs});
      continue;
    }
    specs.push_back(&spec);
  }
  for (const CandidateSpec* spec : specs) d.candidates.push_back(fit_candidate(sweep, {}, *spec, d.gap_before, options.fit));
  std::stable_sort(d.candidates.begin(), d.candidates.end(),
                   [](const CandidateResult& a, const CandidateResult& b) { return a.shrink > b.shrink; });

  d.after = d.baseline;
  double gap = d.gap_before;
  if (gap > kExplainedGap) {
    // Round 1: the best plausible candidate alone.
    const CandidateResult* first = nullptr;
    for (const CandidateResult& c : d.candidates)
      if (c.plausible && c.shrink >= kMinShrink) {
        first = &c;
        break;
      }
    if (first) {
      d.chosen.push_back(model::complete_effect({first->effect, first->params}, "diagnosis"));
      d.after = first->eval;
      gap = first->gap;
      d.steps.push_back({names_of(d.chosen), gap});
    }
    // Further rounds: each remaining effect on top of the chosen set. These fits refine from the
    // best grid point only, without the polish: each model run carries the chosen effects too (a
    // friction spread on top of an amplifier is 6 runs through the actuator chain a cell), and a
    // second effect is a correction on a fitted model, not a search for a hidden resonance.
    FitOptions further = options.fit;
    further.starts_2d = 1;
    further.polish = false;
    while (!d.chosen.empty() && gap > kExplainedGap) {
      CandidateResult best;
      bool found = false;
      for (const CandidateSpec* spec : specs) {
        // Only effects that explained part of the gap on their own are tried on top of the set.
        const auto alone = std::find_if(d.candidates.begin(), d.candidates.end(),
                                        [&](const CandidateResult& c) { return c.effect == spec->effect; });
        if (alone == d.candidates.end() || !alone->plausible || alone->shrink < kMinShrink) continue;
        if (std::find_if(d.chosen.begin(), d.chosen.end(),
                         [&](const model::EffectSpec& e) { return e.name == spec->effect; }) != d.chosen.end())
          continue;
        CandidateResult r = fit_candidate(sweep, d.chosen, *spec, gap, further);
        if (r.plausible && r.shrink >= kMinFurtherShrink && (!found || r.gap < best.gap)) {
          best = std::move(r);
          found = true;
        }
      }
      if (!found) break;
      d.chosen.push_back(model::complete_effect({best.effect, best.params}, "diagnosis"));
      d.after = best.eval;
      gap = best.gap;
      d.steps.push_back({names_of(d.chosen), gap});
    }
  }
  d.gap_after = d.after.gap;
  d.shrink = d.gap_before > 0 ? 1.0 - d.gap_after / d.gap_before : 0.0;
  return d;
}

std::string text_summary(const SweepCells& sweep, const Diagnosis& d) {
  std::ostringstream s;
  char buf[256];
  int trials = 0;
  for (const Cell& c : sweep.cells) trials += static_cast<int>(c.train.size() + c.test.size());
  std::snprintf(buf, sizeof buf, "%s: %zu cells, %d trials; reading noise %.2g m (one count %.4g m)\n",
                sweep.name.c_str(), sweep.cells.size(), trials, sweep.reading_sd_m, sweep.resolution_m);
  s << buf << progress_summary(sweep);
  std::snprintf(buf, sizeof buf, "baseline (impulse model, alpha %.3f fitted on training trials): held-out gap %.3g\n",
                d.baseline.step_scale, d.gap_before);
  s << buf << "where: " << d.where << "\n";
  s << "which (each effect alone, fitted on training trials, held-out gap):\n";
  for (const CandidateResult& c : d.candidates) {
    std::string params;
    for (const auto& [k, v] : c.params) params += (params.empty() ? "" : ", ") + k + "=" + model::format_number(v);
    std::snprintf(buf, sizeof buf, "  %-20s gap %8.3g  shrink %6.1f %%  %s%s%s\n", c.effect.c_str(), c.gap,
                  100 * c.shrink, params.c_str(), c.plausible ? "" : "  [implausible: ", c.plausible ? "" : (c.note + "]").c_str());
    s << buf;
  }
  for (const NotIdentifiable& n : d.not_identifiable)
    s << "  " << n.effect << ": not identifiable from this data (needs " << n.needs << ")\n";
  if (d.chosen.empty()) {
    s << (d.gap_before <= kExplainedGap ? "diagnosis: no significant gap to explain\n"
                                        : "diagnosis: no effect of the library explains the gap\n");
  } else {
    std::string names;
    for (const model::EffectSpec& e : d.chosen) names += (names.empty() ? "" : " + ") + e.name;
    std::snprintf(buf, sizeof buf, "diagnosis: %s; held-out gap %.3g -> %.3g (shrink %.1f %%)\n", names.c_str(),
                  d.gap_before, d.gap_after, 100 * d.shrink);
    s << buf << "after: " << where_summary(d.after) << "\n";
  }
  return s.str();
}

}  // namespace idm::analysis
