#include "analysis/report_json.h"

#include <cmath>
#include <cstdio>
#include <sstream>

#include "recording/durable_file.h"

namespace idm::analysis {

std::string json_string(const std::string& s) {
  std::string out = "\"";
  for (char c : s) {
    switch (c) {
      case '"': out += "\\\""; break;
      case '\\': out += "\\\\"; break;
      case '\n': out += "\\n"; break;
      case '\t': out += "\\t"; break;
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
  for (const auto& [k, v] : p) out += (out.size() > 1 ? ", " : "") + json_string(k) + ": " + json_number(v);
  return out + "}";
}
std::string region(model::Region r) { return json_string(model::region_name(r)); }

// The recorder's mark: status, whether the sweep was cut off, the planned cells short of trials
// and the cells the diagnosis left out.
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
        << ", \"duty\": " << json_number(m.planned.duty) << ", \"stroke_m\": " << json_number(m.planned.stroke_m)
        << ", \"trials\": " << m.recorded << ", \"planned_trials\": " << m.planned.trials << "}";
    }
    s << "]";
  }
  s << ", \"cells_used\": " << sweep.cells.size() << ", \"cells_left_out\": [";
  for (std::size_t i = 0; i < sweep.skipped.size(); ++i)
    s << (i ? ", " : "") << "[" << json_number(sweep.skipped[i].freq_hz) << ", " << json_number(sweep.skipped[i].duty)
      << ", " << json_number(sweep.skipped[i].stroke_m) << "]";
  s << "]}";
  return s.str();
}
}  // namespace

std::string gap_report_json(const SweepCells& sweep, const Diagnosis& d, const std::string& dataset) {
  std::ostringstream s;
  s << "{\n  \"dataset\": " << json_string(dataset) << ",\n";
  s << "  \"baseline\": {\"model\": \"impulse\", \"params\": {\"step_correction\": "
    << json_number(d.baseline.step_scale * sweep.stage.stage.step_correction) << ", \"alpha\": "
    << json_number(d.baseline.step_scale) << ", \"friction_coefficient\": "
    << json_number(sweep.stage.stage.friction_coefficient) << "}, \"gap\": " << json_number(d.gap_before) << "},\n";
  s << "  \"dataset_status\": " << dataset_status_json(sweep) << ",\n";
  s << "  \"cells\": [\n";
  for (std::size_t c = 0; c < sweep.cells.size(); ++c) {
    const Cell& cell = sweep.cells[c];
    const CellResidual& r = d.baseline.cells[c];
    const CellResidual& a = d.after.cells[c];
    std::vector<const TrialFeatures*> all;
    for (const TrialFeatures& t : cell.train) all.push_back(&t);
    for (const TrialFeatures& t : cell.test) all.push_back(&t);
    double mean = 0, first = 0, reverse = 0, transient = 0;
    for (const TrialFeatures* t : all) {
      mean += t->steady_step_m / all.size();
      first += t->first_step_m / all.size();
      reverse += t->reverse_m / all.size();
      transient += static_cast<double>(t->transient_cycles) / all.size();
    }
    double ss = 0;
    for (const TrialFeatures* t : all) ss += (t->steady_step_m - mean) * (t->steady_step_m - mean);
    const double sd = all.size() > 1 ? std::sqrt(ss / (all.size() - 1)) : 0.0;
    s << "    {\"freq_hz\": " << json_number(cell.key.freq_hz) << ", \"duty\": " << json_number(cell.key.duty)
      << ", \"stroke_m\": " << json_number(cell.key.stroke_m) << ", \"trials\": " << all.size()
      << ", \"held_out_trials\": " << cell.test.size() << ", \"measured_step_m\": " << json_number(mean)
      << ", \"measured_step_sd_m\": " << json_number(sd) << ", \"model_step_m\": " << json_number(r.model_step_m)
      << ", \"first_step_m\": " << json_number(first) << ", \"transient_cycles\": " << json_number(transient)
      << ", \"reverse_m\": " << json_number(reverse) << ", \"measured_region\": " << region(cell.measured_region)
      << ", \"model_region\": " << region(r.model_region) << ", \"residual\": " << json_number(r.residual)
      << ", \"significant\": " << (r.significant ? "true" : "false")
      << ", \"model_region_after\": " << region(a.model_region) << ", \"residual_after\": " << json_number(a.residual)
      << "}" << (c + 1 < sweep.cells.size() ? "," : "") << "\n";
  }
  s << "  ],\n";
  s << "  \"where\": {\"significant_cells\": [";
  bool first_cell = true;
  for (const CellResidual& r : d.baseline.cells)
    if (r.significant) {
      s << (first_cell ? "" : ", ") << "[" << json_number(r.key.freq_hz) << ", " << json_number(r.key.duty) << "]";
      first_cell = false;
    }
  s << "],\n            \"summary\": " << json_string(d.where)
    << ",\n            \"summary_after\": " << json_string(where_summary(d.after)) << "},\n";
  s << "  \"candidates\": [\n";
  for (std::size_t i = 0; i < d.candidates.size(); ++i) {
    const CandidateResult& c = d.candidates[i];
    s << "    {\"effect\": " << json_string(c.effect) << ", \"params\": " << params_json(c.params)
      << ", \"gap\": " << json_number(c.gap) << ", \"shrink\": " << json_number(c.shrink)
      << ", \"plausible\": " << (c.plausible ? "true" : "false") << ", \"train_gap\": " << json_number(c.train_gap);
    if (!c.plausible) s << ", \"why\": " << json_string(c.note);
    s << "}" << (i + 1 < d.candidates.size() ? "," : "") << "\n";
  }
  s << "  ],\n  \"not_identifiable\": [";
  for (std::size_t i = 0; i < d.not_identifiable.size(); ++i)
    s << (i ? ", " : "") << "{\"effect\": " << json_string(d.not_identifiable[i].effect)
      << ", \"needs\": " << json_string(d.not_identifiable[i].needs) << "}";
  s << "],\n  \"selection\": [";
  for (std::size_t i = 0; i < d.steps.size(); ++i) {
    s << (i ? ", " : "") << "{\"effects\": [";
    for (std::size_t k = 0; k < d.steps[i].effects.size(); ++k) s << (k ? ", " : "") << json_string(d.steps[i].effects[k]);
    s << "], \"gap\": " << json_number(d.steps[i].gap) << "}";
  }
  s << "],\n  \"diagnosis\": {\"effects\": [";
  for (std::size_t i = 0; i < d.chosen.size(); ++i) s << (i ? ", " : "") << json_string(d.chosen[i].name);
  s << "], \"params\": {";
  for (std::size_t i = 0; i < d.chosen.size(); ++i)
    s << (i ? ", " : "") << json_string(d.chosen[i].name) << ": " << params_json(d.chosen[i].params);
  s << "}, \"gap_before\": " << json_number(d.gap_before) << ", \"gap_after\": " << json_number(d.gap_after)
    << ", \"shrink\": " << json_number(d.shrink) << "}\n}\n";
  return s.str();
}

void write_file_atomic(const std::string& path, const std::string& content) {
  recording::write_file_durably(path, content);
}

}  // namespace idm::analysis
