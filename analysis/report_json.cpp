#include "analysis/report_json.h"

#include <cmath>
#include <cstdio>
#include <map>
#include <sstream>

#include "recording/durable_file.h"

namespace idm::analysis {

std::string json_string(const std::string& s) {
  std::string out = "\"";
  for (char c : s) {
    switch (c) {
      case '"':
        out += "\\\"";
        break;
      case '\\':
        out += "\\\\";
        break;
      case '\n':
        out += "\\n";
        break;
      case '\t':
        out += "\\t";
        break;
      default:
        if (static_cast<unsigned char>(c) < 0x20) {
          char b[8];
          std::snprintf(b, sizeof b, "\\u%04x", c);
          out += b;
        } else {
          out += c;
        }
    }
  }
  return out + "\"";
}

std::string json_number(double v) {
  if (!std::isfinite(v)) return "null";
  char b[32];
  std::snprintf(b, sizeof b, "%.6g", v);
  return b;
}

namespace {
std::string params_json(const std::map<std::string, double>& p) {
  std::string out = "{";
  for (const auto& [k, v] : p)
    out += (out.size() > 1 ? ", " : "") + json_string(k) + ": " + json_number(v);
  return out + "}";
}
std::string region(model::Region r) {
  return json_string(model::region_name(r));
}

// The recorder's mark: status, whether the sweep was cut off, the planned cells short of trials,
// the cells the diagnosis left out and the trials it left out (files it could not use, and why).
std::string dataset_status_json(const SweepCells& sweep) {
  const recording::SweepProgress& p = sweep.progress;
  std::ostringstream s;
  s << "{\"status\": " << json_string(recording::status_name(p.status))
    << ", \"interrupted\": " << (p.interrupted() ? "true" : "false");
  if (!p.note.empty()) s << ", \"note\": " << json_string(p.note);
  if (p.marked()) {
    s << ", \"planned_cells\": " << p.planned.size() << ", \"missing_cells\": [";
    for (std::size_t i = 0; i < p.missing.size(); ++i) {
      const recording::MissingCell& m = p.missing[i];
      s << (i ? ", " : "") << "{\"freq_hz\": " << json_number(m.planned.freq_hz)
        << ", \"duty\": " << json_number(m.planned.duty)
        << ", \"stroke_m\": " << json_number(m.planned.stroke_m) << ", \"trials\": " << m.recorded
        << ", \"planned_trials\": " << m.planned.trials << "}";
    }
    s << "]";
  }
  s << ", \"cells_used\": " << sweep.cells.size() << ", \"cells_left_out\": [";
  for (std::size_t i = 0; i < sweep.skipped.size(); ++i)
    s << (i ? ", " : "") << "[" << json_number(sweep.skipped[i].freq_hz) << ", "
      << json_number(sweep.skipped[i].duty) << ", " << json_number(sweep.skipped[i].stroke_m)
      << "]";
  s << "], \"trials_left_out\": [";
  for (std::size_t i = 0; i < sweep.damaged.size(); ++i)
    s << (i ? ", " : "") << "{\"file\": " << json_string(sweep.damaged[i].file)
      << ", \"why\": " << json_string(sweep.damaged[i].why) << "}";
  s << "]}";
  return s.str();
}
}  // namespace

namespace {

std::string cell_pairs(const std::vector<CellKey>& cells, bool with_stroke) {
  std::string out = "[";
  for (std::size_t i = 0; i < cells.size(); ++i) {
    out += (i ? ", [" : "[") + json_number(cells[i].freq_hz) + ", " + json_number(cells[i].duty);
    if (with_stroke) out += ", " + json_number(cells[i].stroke_m);
    out += "]";
  }
  return out + "]";
}

std::string names_json(const std::vector<std::string>& names) {
  std::string out = "[";
  for (std::size_t i = 0; i < names.size(); ++i) out += (i ? ", " : "") + json_string(names[i]);
  return out + "]";
}

// The fitted parameters as reported: the effect's own, without the library's fixed extras.
std::string effect_params_json(const model::EffectSpec& e) {
  std::map<std::string, double> p;
  for (const auto& [k, v] : e.params)
    if (k != "correlation_m" && k != "mean_shift" && !(k == "slew_rate_m_s" && v == 0)) p[k] = v;
  return params_json(p);
}

std::string intervals_json(const ParameterIntervals& pi) {
  std::string out = "{";
  for (std::size_t i = 0; i < pi.params.size(); ++i)
    out += (i ? ", " : "") + json_string(pi.params[i].param) + ": [" +
           json_number(pi.params[i].lo) + ", " + json_number(pi.params[i].hi) + "]";
  return out + "}";
}

std::string cells_json(const SweepCells& sweep, const Diagnosis& d) {
  std::ostringstream s;
  s << "  \"cells\": [\n";
  for (std::size_t c = 0; c < sweep.cells.size(); ++c) {
    const Cell& cell = sweep.cells[c];
    const CellResidual& r = d.baseline.test.cells[c];
    const CellResidual& a = d.after.test.cells[c];
    const CellWhere& w = d.where.cells[c];
    std::vector<const TrialFeatures*> all;
    for (const TrialFeatures& t : cell.train) all.push_back(&t);
    for (const TrialFeatures& t : cell.test) all.push_back(&t);
    const double n = static_cast<double>(all.size());
    double mean = 0, first = 0, reverse = 0, transient = 0;
    for (const TrialFeatures* t : all) {
      mean += t->steady_step_m / n;
      first += t->first_step_m / n;
      reverse += t->reverse_m / n;
      transient += static_cast<double>(t->transient_cycles) / n;
    }
    double ss = 0;
    for (const TrialFeatures* t : all) ss += (t->steady_step_m - mean) * (t->steady_step_m - mean);
    const double sd = all.size() > 1 ? std::sqrt(ss / (n - 1)) : 0.0;
    s << "    {\"freq_hz\": " << json_number(cell.key.freq_hz)
      << ", \"duty\": " << json_number(cell.key.duty)
      << ", \"stroke_m\": " << json_number(cell.key.stroke_m) << ", \"trials\": " << all.size()
      << ", \"held_out_trials\": " << cell.test.size()
      << ", \"measured_step_m\": " << json_number(mean)
      << ", \"measured_step_sd_m\": " << json_number(sd)
      << ", \"model_step_m\": " << json_number(r.model_step_m)
      << ", \"first_step_m\": " << json_number(first)
      << ", \"transient_cycles\": " << json_number(transient)
      << ", \"reverse_m\": " << json_number(reverse)
      << ", \"measured_region\": " << region(cell.measured_region)
      << ", \"model_region\": " << region(r.model_region)
      << ", \"residual\": " << json_number(r.residual)
      << ", \"significant\": " << (r.significant ? "true" : "false")
      << ", \"effect_gap\": " << json_number(w.effect_gap)
      << ", \"spread_excess\": " << json_number(w.spread_excess)
      << ", \"departure\": " << json_number(w.departure)
      << ", \"model_step_after_m\": " << json_number(a.model_step_m)
      << ", \"model_region_after\": " << region(a.model_region)
      << ", \"residual_after\": " << json_number(a.residual) << "}"
      << (c + 1 < sweep.cells.size() ? "," : "") << "\n";
  }
  s << "  ],\n";
  return s.str();
}

std::string diagnosis_json(const Diagnosis& d) {
  std::ostringstream s;
  s << "  \"diagnosis\": {\"effects\": [";
  for (std::size_t i = 0; i < d.chosen.size(); ++i)
    s << (i ? ", " : "") << json_string(d.chosen[i].name);
  s << "], \"params\": {";
  for (std::size_t i = 0; i < d.chosen.size(); ++i)
    s << (i ? ", " : "") << json_string(d.chosen[i].name) << ": "
      << effect_params_json(d.chosen[i]);
  s << "}, \"intervals\": {";
  for (std::size_t i = 0; i < d.chosen_intervals.size(); ++i)
    s << (i ? ", " : "") << json_string(d.chosen_intervals[i].effect) << ": "
      << intervals_json(d.chosen_intervals[i]);
  s << "}, \"step_correction\": " << json_number(d.after.calibration.alpha)
    << ", \"friction_coefficient\": " << json_number(d.after.calibration.mu)
    << ",\n                \"gap_before\": " << json_number(d.gap_before)
    << ", \"gap_after\": " << json_number(d.gap_after) << ", \"shrink\": " << json_number(d.shrink)
    << ",\n";
  const Unexplained& u = d.unexplained;
  s << "                \"unexplained\": {\"significant\": " << (u.significant ? "true" : "false")
    << ", \"gap\": " << json_number(u.gap)
    << ", \"systematic_gap\": " << json_number(u.systematic_gap)
    << ", \"cells\": " << cell_pairs(u.cells, false)
    << ", \"cells_with_stroke\": " << cell_pairs(u.cells, true)
    << ", \"summary\": " << json_string(u.summary);
  if (!u.closest.empty()) s << ", \"closest\": " << json_string(u.closest);
  s << "},\n                \"ambiguous\": [";
  for (std::size_t i = 0; i < d.ambiguous.size(); ++i) {
    const Ambiguity& a = d.ambiguous[i];
    s << (i ? ",\n                  " : "") << "{\"effects\": " << names_json(a.effects)
      << ", \"chosen\": " << names_json(a.chosen)
      << ", \"alternative\": " << names_json(a.alternative)
      << ", \"gap_chosen\": " << json_number(a.gap_chosen)
      << ", \"gap_alternative\": " << json_number(a.gap_alternative)
      << ", \"why\": " << json_string(a.why) << ", \"next_sweep\": " << json_string(a.next_sweep)
      << "}";
  }
  s << "],\n                \"not_identifiable\": [";
  for (std::size_t i = 0; i < d.not_identifiable.size(); ++i)
    s << (i ? ", " : "") << "{\"effect\": " << json_string(d.not_identifiable[i].effect)
      << ", \"why\": " << json_string("needs " + d.not_identifiable[i].needs) << "}";
  s << "]}\n";
  return s.str();
}

}  // namespace

std::string gap_report_json(const SweepCells& sweep, const Diagnosis& d,
                            const std::string& dataset) {
  std::ostringstream s;
  s << "{\n  \"dataset\": " << json_string(dataset) << ",\n";
  s << "  \"dataset_status\": " << dataset_status_json(sweep) << ",\n";
  s << "  \"baseline\": {\"model\": \"impulse\", \"params\": {\"step_correction\": "
    << json_number(d.baseline.calibration.alpha)
    << ", \"friction_coefficient\": " << json_number(d.baseline.calibration.mu)
    << "}, \"gap\": " << json_number(d.gap_before)
    << ", \"systematic_gap\": " << json_number(systematic_gap(d.baseline)) << "},\n";
  s << cells_json(sweep, d);
  s << "  \"where\": {\"significant_cells\": " << cell_pairs(d.where.significant_cells, false)
    << ",\n            \"significant_cells_with_stroke\": "
    << cell_pairs(d.where.significant_cells, true)
    << ",\n            \"summary\": " << json_string(d.where.summary)
    << ",\n            \"summary_after\": " << json_string(d.where.summary_after)
    << ",\n            \"summary_departure\": " << json_string(d.where.summary_departure) << "},\n";
  s << "  \"candidates\": [\n";
  for (std::size_t i = 0; i < d.candidates.size(); ++i) {
    const SetFit& c = d.candidates[i];
    s << "    {\"effect\": " << json_string(c.effects.front().name)
      << ", \"params\": " << effect_params_json(c.effects.front()) << ", \"intervals\": "
      << (i < d.intervals.size() && !d.intervals[i].empty() ? intervals_json(d.intervals[i].front())
                                                            : "{}")
      << ", \"gap\": " << json_number(c.gap) << ", \"shrink\": " << json_number(c.shrink)
      << ", \"plausible\": " << (c.plausible ? "true" : "false")
      << ", \"train_gap\": " << json_number(c.train_gap);
    if (!c.plausible) s << ", \"why\": " << json_string(c.note);
    s << "}" << (i + 1 < d.candidates.size() ? "," : "") << "\n";
  }
  s << "  ],\n  \"not_identifiable\": [";
  for (std::size_t i = 0; i < d.not_identifiable.size(); ++i)
    s << (i ? ", " : "") << "{\"effect\": " << json_string(d.not_identifiable[i].effect)
      << ", \"needs\": " << json_string(d.not_identifiable[i].needs) << "}";
  s << "],\n  \"selection\": [";
  for (std::size_t i = 0; i < d.steps.size(); ++i)
    s << (i ? ", " : "") << "{\"action\": " << json_string(d.steps[i].action)
      << ", \"effects\": " << names_json(d.steps[i].effects)
      << ", \"gap\": " << json_number(d.steps[i].gap) << "}";
  s << "],\n";
  s << diagnosis_json(d) << "}\n";
  return s.str();
}

void write_file_atomic(const std::string& path, const std::string& content) {
  recording::write_file_durably(path, content);
}

}  // namespace idm::analysis
