#include "recording/sweep_plan.h"

#include <charconv>
#include <cmath>

#include "model/range.h"
#include "model/yaml_util.h"
#include "recording/dataset.h"
#include "recording/dataset_format.h"
#include "recording/dataset_limits.h"

namespace idm::recording {

namespace {

constexpr SweepStatus kWrittenStatuses[] = {SweepStatus::InProgress, SweepStatus::Complete,
                                            SweepStatus::Stopped, SweepStatus::Failed};

void append_exact(std::string& out, double value) {
  char buf[32];
  const auto [end, ec] = std::to_chars(buf, buf + sizeof buf, value);
  out.append(buf, ec == std::errc() ? end : buf);
}

// A note on one line, quoted for YAML (double quotes, backslash escapes).
std::string quoted(const std::string& text) {
  std::string out = "\"";
  for (const char c : text) {
    if (c == '"' || c == '\\') out.push_back('\\');
    if (c == '\n' || c == '\r')
      out.push_back(' ');
    else
      out.push_back(c);
  }
  return out + "\"";
}

bool close(double a, double b) {
  return std::fabs(a - b) <= 1e-9 * std::max(std::fabs(a), std::fabs(b));
}

std::string cell_text(const PlannedCell& c) {
  return "(" + model::format_number(c.freq_hz) + " Hz, duty " + model::format_number(c.duty) +
         ", stroke " + model::format_number(c.stroke_m) + " m)";
}

}  // namespace

const char* status_name(SweepStatus status) {
  switch (status) {
    case SweepStatus::Unmarked:
      return "unmarked";
    case SweepStatus::InProgress:
      return "in_progress";
    case SweepStatus::Complete:
      return "complete";
    case SweepStatus::Stopped:
      return "stopped";
    case SweepStatus::Failed:
      return "failed";
  }
  return "?";
}

std::string plan_yaml(const SweepPlanFile& plan) {
  std::string out =
      "# The sweep as planned and how its recording ended (recording/README.md).\n"
      "# in_progress: the recorder did not finish (crash, kill, power loss, still running).\n";
  out += "status: " + std::string(status_name(plan.status)) + "\n";
  if (!plan.note.empty()) out += "note: " + quoted(plan.note) + "\n";
  if (!plan.axis.empty()) out += "axis: " + quoted(plan.axis) + "\n";
  out += "cells:\n";
  for (const PlannedCell& c : plan.cells) {
    out += "  - {freq_hz: ";
    append_exact(out, c.freq_hz);
    out += ", duty: ";
    append_exact(out, c.duty);
    out += ", stroke_m: ";
    append_exact(out, c.stroke_m);
    out += ", trials: " + std::to_string(c.trials) + "}\n";
  }
  return out;
}

void validate_plan(const std::vector<PlannedCell>& cells, const std::string& where) {
  for (std::size_t i = 0; i < cells.size(); ++i) {
    const PlannedCell& c = cells[i];
    const std::string at = where + ": planned cell " + std::to_string(i + 1) + " ";
    auto check = [&](const char* key, double v, const model::Range& range) {
      if (!range.contains(v))
        throw InputError(at + key + ": " + model::format_number(v) + " is out of range, allowed " +
                         range.text());
    };
    check("freq_hz", c.freq_hz, kFreqRangeHz);
    check("duty", c.duty, model::Range{0.0, 1.0, true, true});
    check("stroke_m", c.stroke_m, model::stage_key_range("stroke_m"));
    if (c.trials < 1 || c.trials > kMaxTrialsPerCell)
      throw InputError(at + "trials: " + std::to_string(c.trials) +
                       " is out of range, allowed [1, " + std::to_string(kMaxTrialsPerCell) + "]");
    for (std::size_t k = 0; k < i; ++k)
      if (same_cell(cells[k], c.freq_hz, c.duty, c.stroke_m))
        throw InputError(at + cell_text(c) + " repeats planned cell " + std::to_string(k + 1));
  }
}

SweepPlanFile read_plan_file(const std::string& path) {
  // A line per planned cell: up to recording.sweep_max_trials cells, each a map of a few keys.
  const YAML::Node root = model::load_yaml_file(path, {kMaxYamlFileBytes, 4000000});
  if (!root.IsMap()) throw InputError(path + ":1: expected a map with status and cells");
  SweepPlanFile plan;
  const YAML::Node status = root["status"];
  if (!status) throw InputError(path + ": status: missing (required)");
  const std::string name = model::read_string(status, path, "status");
  bool known = false;
  for (const SweepStatus s : kWrittenStatuses)
    if (name == status_name(s)) {
      plan.status = s;
      known = true;
    }
  if (!known)
    throw InputError(model::located(path, status, "status",
                                    "'" + name +
                                        "' is not allowed, allowed in_progress, complete, "
                                        "stopped"));
  if (const YAML::Node note = root["note"]) plan.note = model::read_string(note, path, "note");
  if (const YAML::Node axis = root["axis"]) plan.axis = model::read_string(axis, path, "axis");
  const YAML::Node cells = root["cells"];
  if (!cells) throw InputError(path + ": cells: missing (required)");
  if (!cells.IsSequence() && !cells.IsNull())
    throw InputError(model::located(path, cells, "cells", "expected a list of cells"));
  for (std::size_t i = 0; cells.IsSequence() && i < cells.size(); ++i) {
    const YAML::Node c = cells[i];
    const std::string key = "cells[" + std::to_string(i) + "]";
    if (!c.IsMap())
      throw InputError(model::located(path, c, key, "expected {freq_hz, duty, stroke_m, trials}"));
    auto field = [&](const char* name) {
      const YAML::Node v = c[name];
      if (!v) throw InputError(model::located(path, c, key + "." + name, "missing (required)"));
      return v;
    };
    PlannedCell p;
    p.freq_hz = model::read_double(field("freq_hz"), path, key + ".freq_hz", kFreqRangeHz.lo,
                                   kFreqRangeHz.hi, kFreqRangeHz.lo_open);
    p.duty = model::read_double(field("duty"), path, key + ".duty", -1e300, 1e300);
    if (!(p.duty > 0 && p.duty < 1))
      throw InputError(
          model::located(path, c["duty"], key + ".duty",
                         model::format_number(p.duty) + " is out of range, allowed (0, 1)"));
    const model::Range& stroke = model::stage_key_range("stroke_m");
    p.stroke_m = model::read_double(field("stroke_m"), path, key + ".stroke_m", stroke.lo,
                                    stroke.hi, stroke.lo_open);
    p.trials = static_cast<int>(
        model::read_integer(field("trials"), path, key + ".trials", 1, kMaxTrialsPerCell));
    for (std::size_t k = 0; k < plan.cells.size(); ++k)
      if (same_cell(plan.cells[k], p.freq_hz, p.duty, p.stroke_m))
        throw InputError(model::located(
            path, c, key, cell_text(p) + " repeats cells[" + std::to_string(k) + "]"));
    plan.cells.push_back(p);
  }
  return plan;
}

bool same_cell(const PlannedCell& cell, double freq_hz, double duty, double stroke_m) {
  return close(cell.freq_hz, freq_hz) && close(cell.duty, duty) && close(cell.stroke_m, stroke_m);
}

std::vector<MissingCell> missing_cells(const std::vector<PlannedCell>& planned,
                                       const std::vector<TrialInfo>& trials) {
  std::vector<int> count(planned.size(), 0);
  for (const TrialInfo& t : trials)
    for (std::size_t c = 0; c < planned.size(); ++c)
      if (same_cell(planned[c], t.freq_hz, t.duty, t.stroke_m)) {
        ++count[c];
        break;
      }
  std::vector<MissingCell> out;
  for (std::size_t c = 0; c < planned.size(); ++c)
    if (count[c] < planned[c].trials) out.push_back({planned[c], count[c]});
  return out;
}

}  // namespace idm::recording
