// The text summary of a diagnosis (selection.h: text_summary).
#include <cmath>
#include <cstdio>
#include <sstream>

#include "analysis/selection.h"
#include "model/yaml_util.h"

namespace idm::analysis {

namespace {

std::string params_text(const std::vector<model::EffectSpec>& effects) {
  std::string out;
  for (const model::EffectSpec& e : effects)
    for (const auto& [k, v] : e.params) {
      if (k == "correlation_m" || k == "mean_shift" || (k == "slew_rate_m_s" && v == 0)) continue;
      out += (out.empty() ? "" : ", ") + k + "=" + model::format_number(v, 4);
    }
  return out;
}

std::string intervals_text(const std::vector<ParameterIntervals>& intervals) {
  std::string out;
  for (const ParameterIntervals& pi : intervals)
    for (const ParameterInterval& p : pi.params) {
      out += (out.empty() ? "" : ", ") + p.param + " " + model::format_number(p.lo, 4) + " to " +
             model::format_number(p.hi, 4) + (p.limited_by_range ? " (range)" : "");
    }
  return out;
}

std::string names_of(const std::vector<std::string>& n) {
  std::string out;
  for (const std::string& s : n) out += (out.empty() ? "" : " + ") + s;
  return out;
}

}  // namespace

std::string left_out_summary(const SweepCells& sweep) {
  if (sweep.damaged.empty()) return "";
  constexpr std::size_t kListed = 8;
  std::ostringstream s;
  s << sweep.damaged.size() << " trial(s) left out (their files could not be used):\n";
  for (std::size_t i = 0; i < sweep.damaged.size() && i < kListed; ++i)
    s << "  " << sweep.damaged[i].why << "\n";
  if (sweep.damaged.size() > kListed)
    s << "  and " << sweep.damaged.size() - kListed << " more (all in the JSON)\n";
  return s.str();
}

std::string text_summary(const SweepCells& sweep, const Diagnosis& d) {
  std::ostringstream s;
  char buf[512];
  int trials = 0;
  for (const Cell& c : sweep.cells) trials += static_cast<int>(c.train.size() + c.test.size());
  std::snprintf(
      buf, sizeof buf, "%s: %zu cells, %d trials; reading noise %.2g m (one count %.4g m)\n",
      sweep.name.c_str(), sweep.cells.size(), trials, sweep.reading_sd_m, sweep.resolution_m);
  s << buf << progress_summary(sweep) << left_out_summary(sweep);
  s << "(gaps and residuals in " << kGapUnit
    << ": standard uncertainties of the measured mean step and spread; about 1 is within the "
       "noise, 3 significant)\n";
  const Calibration& b = d.baseline.calibration;
  std::snprintf(buf, sizeof buf,
                "baseline (impulse model; alpha %.3f and mu %.4g fitted on training trials, "
                "stage.yaml: mu %.4g): "
                "held-out gap %.3g %s\n",
                b.alpha, b.mu, sweep.stage.stage.friction_coefficient, d.gap_before, kGapUnit);
  s << buf << "where: " << d.where.summary << "\n";
  s << "which (each effect alone, fitted on training trials; held-out gap; 95 % intervals from "
       "held-out trials):\n";
  for (std::size_t i = 0; i < d.candidates.size(); ++i) {
    const SetFit& c = d.candidates[i];
    std::snprintf(buf, sizeof buf, "  %-20s gap %8.3g %s  shrink %6.1f %%  ",
                  c.effects.front().name.c_str(), c.gap, kGapUnit, 100 * c.shrink);
    s << buf << params_text(c.effects);
    if (i < d.intervals.size() && !d.intervals[i].empty())
      s << "  [" << intervals_text(d.intervals[i]) << "]";
    if (!c.plausible) s << "  [implausible: " << c.note << "]";
    s << "\n";
  }
  for (const NotIdentifiable& n : d.not_identifiable)
    s << "  " << n.effect << ": not identifiable from this data (needs " << n.needs << ")\n";
  if (!d.steps.empty()) {
    s << "selection:";
    for (const SelectionStep& st : d.steps)
      s << " " << st.action << " -> " << names_of(st.effects) << " (gap "
        << model::format_number(st.gap, 3) << " " << kGapUnit << ");";
    s << "\n";
  }
  if (d.named) {
    std::snprintf(buf, sizeof buf,
                  "diagnosis: %s; held-out gap %.3g %s -> %.3g %s (shrink %.1f %%)\n",
                  names_of(d.best.names()).c_str(), d.gap_before, kGapUnit, d.gap_after, kGapUnit,
                  100 * d.shrink);
    s << buf << "  fitted jointly: " << params_text(d.chosen);
    s << "; alpha " << model::format_number(d.after.calibration.alpha, 3) << ", mu "
      << model::format_number(d.after.calibration.mu, 4) << "\n";
    if (!d.chosen_intervals.empty())
      s << "  95 % intervals (held-out): " << intervals_text(d.chosen_intervals) << "\n";
  } else if (d.unexplained.significant) {
    s << "diagnosis: no effect of the library explains the gap (nothing named)\n";
  } else {
    s << "diagnosis: no significant gap to explain (held-out gap "
      << model::format_number(d.gap_before, 3) << " " << kGapUnit << ", systematic part "
      << model::format_number(systematic_gap(d.baseline), 3) << " " << kGapUnit << ")\n";
  }
  s << "unexplained: " << (d.unexplained.significant ? "SIGNIFICANT. " : "no. ")
    << d.unexplained.summary;
  if (!d.unexplained.closest.empty()) s << " (" << d.unexplained.closest << ")";
  s << "\n";
  for (const Ambiguity& a : d.ambiguous)
    s << "ambiguous: " << names_of(a.chosen) << " or " << names_of(a.alternative) << ": " << a.why
      << " To tell them apart: " << a.next_sweep << "\n";
  if (d.named) s << "after: " << d.where.summary_after << "\n";
  return s.str();
}

}  // namespace idm::analysis
