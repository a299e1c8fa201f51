#include "analysis/report_json.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <sstream>
#include <system_error>

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
}  // namespace

std::string gap_report_json(const SweepCells& sweep, const Diagnosis& d, const std::string& dataset) {
  std::ostringstream s;
  s << "{\n  \"dataset\": " << json_string(dataset) << ",\n";
  s << "  \"baseline\": {\"model\": \"impulse\", \"params\": {\"step_correction\": "
    << json_number(d.baseline.step_scale * sweep.stage.stage.step_correction) << ", \"alpha\": "
    << json_number(d.baseline.step_scale) << ", \"friction_coefficient\": "
    << json_number(sweep.stage.stage.friction_coefficient) << "}, \"gap\": " << json_number(d.gap_before) << "},\n";
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
  namespace fs = std::filesystem;
  const fs::path final_path(path);
  const fs::path dir = final_path.has_parent_path() ? final_path.parent_path() : fs::path(".");
  const fs::path tmp = dir / ("." + final_path.filename().string() + ".tmp." + std::to_string(getpid()));
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) throw std::system_error(errno, std::generic_category(), path);
  std::size_t done = 0;
  while (done < content.size()) {
    const ssize_t n = ::write(fd, content.data() + done, content.size() - done);
    if (n < 0) {
      if (errno == EINTR) continue;
      const int err = errno;
      ::close(fd);
      ::unlink(tmp.c_str());
      throw std::system_error(err, std::generic_category(), path);
    }
    done += static_cast<std::size_t>(n);
  }
  if (::fsync(fd) != 0 || ::close(fd) != 0) {
    const int err = errno;
    ::unlink(tmp.c_str());
    throw std::system_error(err, std::generic_category(), path);
  }
  if (::rename(tmp.c_str(), final_path.c_str()) != 0) {
    const int err = errno;
    ::unlink(tmp.c_str());
    throw std::system_error(err, std::generic_category(), path);
  }
  const int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd >= 0) {
    ::fsync(dfd);
    ::close(dfd);
  }
}

}  // namespace idm::analysis
