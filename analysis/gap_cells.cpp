#include "analysis/gap_cells.h"

#include <algorithm>
#include <cmath>
#include <optional>
#include <sstream>
#include <stdexcept>

namespace idm::analysis {

SweepCells collect_cells(const Dataset& ds, int min_trials) {
  std::vector<TrialSeries> series(ds.trials.size());
  for (std::size_t i = 0; i < ds.trials.size(); ++i) series[i] = read_trial(ds, i);
  SweepCells out =
      collect_cells(ds.stage, ds.trials, series, ds.path, min_trials, ds.progress.marked());
  out.progress = ds.progress;
  return out;
}

namespace {

// The spread of the readings of x_m over [from_s, to_s) of one trial; none with fewer than 4.
std::optional<double> rest_sd_m(const TrialSeries& s, double from_s, double to_s) {
  double sum = 0, sum2 = 0;
  int n = 0;
  for (std::size_t k = 0; k < s.size(); ++k)
    if (s.t_s[k] >= from_s && s.t_s[k] < to_s) {
      sum += s.x_m[k];
      sum2 += s.x_m[k] * s.x_m[k];
      ++n;
    }
  if (n < 4) return std::nullopt;
  return std::sqrt(std::max(0.0, sum2 / n - (sum / n) * (sum / n)));
}

// The median spread of the readings while the slider rests before each burst, and after it once
// the slider has settled (a period after the last cycle, the command at rest); none when no
// trial has enough samples at rest.
std::optional<double> median_rest_sd_m(const std::vector<TrialInfo>& infos,
                                       const std::vector<TrialSeries>& series) {
  std::vector<double> rest_sd;
  auto add_rest = [&](const TrialSeries& s, double from_s, double to_s) {
    if (const std::optional<double> sd = rest_sd_m(s, from_s, to_s)) rest_sd.push_back(*sd);
  };
  for (std::size_t i = 0; i < infos.size(); ++i) {
    if (series[i].size() == 0) continue;
    add_rest(series[i], -1e300, 0.0);
    add_rest(series[i], (infos[i].cycles + 1) / infos[i].freq_hz, 1e300);
  }
  if (rest_sd.empty()) return std::nullopt;
  return median(rest_sd);
}

// Appends one cell per distinct (f, duty, stroke) to out.cells in the order of first appearance;
// returns, for each cell, the indices of its trials.
std::vector<std::vector<std::size_t>> group_into_cells(const std::vector<TrialInfo>& infos,
                                                       SweepCells& out) {
  std::vector<std::vector<std::size_t>> members;
  for (std::size_t i = 0; i < infos.size(); ++i) {
    const TrialInfo& t = infos[i];
    const CellKey key{t.freq_hz, t.duty, t.stroke_m};
    std::size_t c = 0;
    while (c < out.cells.size() && !(out.cells[c].key == key)) ++c;
    if (c == out.cells.size()) {
      Cell cell;
      cell.key = key;
      cell.cycles = t.cycles;
      cell.sample_rate_hz = t.sample_rate_hz;
      out.cells.push_back(std::move(cell));
      members.emplace_back();
    }
    members[c].push_back(i);
  }
  return members;
}

// Moves the cells with fewer than min_trials trials to out.skipped; InputError when none is left.
void skip_small_cells(SweepCells& out, std::vector<std::vector<std::size_t>>& members,
                      int min_trials, std::size_t trial_count) {
  std::vector<Cell> kept;
  std::vector<std::vector<std::size_t>> kept_members;
  for (std::size_t c = 0; c < out.cells.size(); ++c) {
    if (static_cast<int>(members[c].size()) < min_trials) {
      out.skipped.push_back(out.cells[c].key);
      continue;
    }
    kept.push_back(out.cells[c]);
    kept_members.push_back(members[c]);
  }
  if (kept.empty())
    throw InputError(out.name + ": the sweep is too small to diagnose: no cell has " +
                     std::to_string(min_trials) + " trials (the recording was cut off after " +
                     std::to_string(trial_count) + " trials)");
  out.cells = std::move(kept);
  members = std::move(kept_members);
}

// A cell's trial features, split alternately into train and test, and its majority regions.
void fill_cell(Cell& cell, const std::vector<std::size_t>& members,
               const std::vector<TrialInfo>& infos, const std::vector<TrialSeries>& series,
               double resolution_m, double noise_m) {
  std::vector<model::Region> votes, train_votes, test_votes;
  for (std::size_t j = 0; j < members.size(); ++j) {
    const std::size_t i = members[j];
    TrialFeatures f = trial_features(infos[i], series[i], resolution_m, noise_m);
    votes.push_back(f.region);
    (j % 2 == 0 ? train_votes : test_votes).push_back(f.region);
    (j % 2 == 0 ? cell.train : cell.test).push_back(std::move(f));
  }
  cell.read_t_s = read_instants(infos[members.front()], series[members.front()]);
  cell.measured_region = majority_region(votes);
  cell.train_region = majority_region(train_votes);
  cell.test_region = majority_region(test_votes);
}

}  // namespace

SweepCells collect_cells(const model::StageFile& stage, const std::vector<TrialInfo>& infos,
                         const std::vector<TrialSeries>& series, const std::string& name,
                         int min_trials, bool skip_small) {
  if (infos.size() != series.size())
    throw std::invalid_argument("collect_cells: infos and trials differ in size");
  if (infos.empty())
    throw InputError(name + ": the sweep is too small to diagnose: it holds no trials");
  SweepCells out;
  out.stage = stage;
  out.resolution_m = stage.interferometer.resolution_m;
  // noise: the readings' spread at rest, at least the quantization's
  const double quant_sd = out.resolution_m / std::sqrt(12.0);
  out.reading_sd_m = std::max(quant_sd, median_rest_sd_m(infos, series).value_or(quant_sd));
  const double noise_m =
      std::sqrt(std::max(0.0, out.reading_sd_m * out.reading_sd_m - quant_sd * quant_sd));
  out.noise_m = noise_m;
  out.name = name;

  std::vector<std::vector<std::size_t>> members = group_into_cells(infos, out);
  if (skip_small) skip_small_cells(out, members, min_trials, infos.size());
  for (std::size_t c = 0; c < out.cells.size(); ++c) {
    Cell& cell = out.cells[c];
    if (static_cast<int>(members[c].size()) < min_trials) {
      std::ostringstream m;
      m << name << ": the sweep is too small to diagnose: cell (" << cell.key.freq_hz
        << " Hz, duty " << cell.key.duty << ", stroke " << cell.key.stroke_m << " m) has "
        << members[c].size() << " trials, at least " << min_trials
        << " needed (some to fit, some held out)";
      throw InputError(m.str());
    }
    fill_cell(cell, members[c], infos, series, out.resolution_m, noise_m);
  }
  return out;
}

std::string progress_summary(const SweepCells& sweep) {
  const recording::SweepProgress& p = sweep.progress;
  if (!p.marked() || (!p.interrupted() && p.missing.empty())) return "";
  std::ostringstream s;
  int empty = 0;
  for (const recording::MissingCell& m : p.missing) empty += m.recorded == 0 ? 1 : 0;
  s << (p.interrupted() ? "interrupted sweep" : "sweep")
    << " (plan.yaml: " << recording::status_name(p.status) << (p.note.empty() ? "" : ", " + p.note)
    << "): " << p.planned.size() - p.missing.size() << " of " << p.planned.size()
    << " planned cells complete, " << empty << " missing, " << p.missing.size() - empty
    << " short of trials; diagnosed on the " << sweep.cells.size() << " cells with enough trials";
  if (!sweep.skipped.empty()) s << " (" << sweep.skipped.size() << " left out with too few)";
  s << "\n";
  constexpr std::size_t kListed = 8;
  s << "missing or short:";
  for (std::size_t i = 0; i < p.missing.size() && i < kListed; ++i) {
    const recording::MissingCell& m = p.missing[i];
    s << (i ? "," : "") << " " << m.planned.freq_hz << " Hz duty " << m.planned.duty << " stroke "
      << m.planned.stroke_m * 1e6 << " um (" << m.recorded << "/" << m.planned.trials << ")";
  }
  if (p.missing.size() > kListed)
    s << " and " << p.missing.size() - kListed << " more (all in the JSON)";
  s << "\n";
  return s.str();
}

}  // namespace idm::analysis
