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
  // a cell short of trials is left out and listed, whether the recorder marked the sweep as cut
  // off or a lab's writer dropped a trial (the format sets no number of trials a cell)
  SweepCells out = collect_cells(ds.stage, ds.trials, series, ds.path, min_trials, true);
  out.progress = ds.progress;
  return out;
}

namespace {

// The spread of the readings of x_m over [from_s, to_s) of one trial; none with fewer than 4.
// Two passes, about the mean: x_m is absolute, and where an interferometer's zero lies 1.2 m away
// the sum of squares loses the nanometres (x^2 carries 16 digits of 1.44 m^2, the noise's variance
// is 1e-18 m^2).
std::optional<double> rest_sd_m(const TrialSeries& s, double from_s, double to_s) {
  std::vector<double> x;
  for (std::size_t k = 0; k < s.size(); ++k)
    if (s.t_s[k] >= from_s && s.t_s[k] < to_s) x.push_back(s.x_m[k]);
  if (x.size() < 4) return std::nullopt;
  const double n = static_cast<double>(x.size());
  double sum = 0;
  for (double v : x) sum += v;
  const double mean = sum / n;
  double ss = 0;
  for (double v : x) ss += (v - mean) * (v - mean);
  return std::sqrt(ss / n);
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

// Without a reading at rest (the format allows a trial without rows before 0 or after its burst):
// the readings' spread from the second differences of successive samples inside the bursts, whose
// spread is sqrt(6) times that of white noise. The slider's own motion adds to the samples where
// it slides (mu g dt^2: 40 nm at 10 kHz), so a trial's robust first estimate (the median absolute
// second difference is 0.6745 sqrt(6) s) picks the samples where it stands: both first
// differences and the second within 3 of their spreads. Their root mean square is the trial's
// estimate (a median of quantized readings moves in whole counts: 3.03 nm for 2.45 nm at 5 nm
// counts). Over the trials, the lower quartile (those that slide least). None when no trial has
// 8 samples to go on.
std::optional<double> burst_noise_sd_m(const std::vector<TrialInfo>& infos,
                                       const std::vector<TrialSeries>& series) {
  constexpr double kMadOfSecondDifference = 0.6745 * 2.449489742783178;  // 0.6745 sqrt(6)
  std::vector<double> per_trial;
  for (std::size_t i = 0; i < infos.size(); ++i) {
    // the burst's samples [a, b) (t increases): first differences d1[j] = x[a+j+1] - x[a+j], second
    // d2[j] about sample a+j+1, between d1[j] and d1[j+1]
    const TrialSeries& s = series[i];
    const double end_s = infos[i].cycles / infos[i].freq_hz;
    std::size_t a = 0;
    while (a < s.size() && s.t_s[a] < 0) ++a;
    std::size_t b = a;
    while (b < s.size() && s.t_s[b] <= end_s) ++b;
    if (b < a + 10) continue;  // 8 second differences
    std::vector<double> d1, d2;
    for (std::size_t k = a; k + 1 < b; ++k) d1.push_back(std::fabs(s.x_m[k + 1] - s.x_m[k]));
    for (std::size_t k = a + 1; k + 1 < b; ++k)
      d2.push_back(std::fabs(s.x_m[k + 1] - 2 * s.x_m[k] + s.x_m[k - 1]));
    const double first = median(d2) / kMadOfSecondDifference;
    const double still = 3 * std::sqrt(2.0) * first, still2 = 3 * std::sqrt(6.0) * first;
    double ss = 0;
    std::size_t n = 0;
    for (std::size_t j = 0; j < d2.size(); ++j)
      if (d1[j] <= still && d1[j + 1] <= still && d2[j] <= still2) {
        ss += d2[j] * d2[j];
        ++n;
      }
    per_trial.push_back(n >= 8 ? std::sqrt(ss / static_cast<double>(n) / 6.0) : first);
  }
  if (per_trial.empty()) return std::nullopt;
  const auto q = per_trial.begin() + static_cast<std::ptrdiff_t>(per_trial.size() / 4);
  std::nth_element(per_trial.begin(), q, per_trial.end());
  return *q;
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
      out.skipped_trials.push_back(members[c].size());
      continue;
    }
    kept.push_back(out.cells[c]);
    kept_members.push_back(members[c]);
  }
  if (kept.empty())
    throw InputError(out.name + ": the sweep is too small to diagnose: no cell has " +
                     std::to_string(min_trials) + " trials, some to fit and some held out (" +
                     std::to_string(trial_count) + " trials in all)");
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
  // noise: the readings' spread at rest (or, with no reading at rest, inside the bursts), at least
  // the quantization's
  const double quant_sd = out.resolution_m / std::sqrt(12.0);
  std::optional<double> sd = median_rest_sd_m(infos, series);
  if (!sd) sd = burst_noise_sd_m(infos, series);
  out.reading_sd_m = std::max(quant_sd, sd.value_or(quant_sd));
  const double noise_m =
      std::sqrt(std::max(0.0, out.reading_sd_m * out.reading_sd_m - quant_sd * quant_sd));
  out.noise_m = noise_m;
  out.name = name;
  out.min_trials = min_trials;

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
  constexpr std::size_t kListed = 8;
  if (!p.marked() && !sweep.skipped.empty()) {  // a sweep from elsewhere with short cells
    std::ostringstream s;
    s << sweep.skipped.size() << " cell(s) left out with fewer than " << sweep.min_trials
      << " trials (some to fit, some held out); diagnosed on the other " << sweep.cells.size()
      << ":";
    for (std::size_t i = 0; i < sweep.skipped.size() && i < kListed; ++i)
      s << (i ? "," : "") << " " << sweep.skipped[i].freq_hz << " Hz duty " << sweep.skipped[i].duty
        << " stroke " << sweep.skipped[i].stroke_m * 1e6 << " um (" << sweep.skipped_trials[i]
        << " trials)";
    if (sweep.skipped.size() > kListed)
      s << " and " << sweep.skipped.size() - kListed << " more (all in the JSON)";
    s << "\n";
    return s.str();
  }
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
