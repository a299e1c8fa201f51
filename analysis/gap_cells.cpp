#include "analysis/gap_cells.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <optional>
#include <sstream>
#include <stdexcept>

#include "recording/dataset_limits.h"

namespace idm::analysis {

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

// The spread of the readings while the slider rests before the burst, and after it once the
// slider has settled (a period after the last cycle, the command at rest): one value for each
// stretch with enough samples at rest. The sweep's is their median.
void add_rest_sd_m(const TrialInfo& info, const TrialSeries& s, std::vector<double>& rest_sd) {
  if (s.size() == 0) return;
  if (const std::optional<double> sd = rest_sd_m(s, -1e300, 0.0)) rest_sd.push_back(*sd);
  if (const std::optional<double> sd = rest_sd_m(s, (info.cycles + 1) / info.freq_hz, 1e300))
    rest_sd.push_back(*sd);
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
std::optional<double> trial_burst_noise_sd_m(const TrialInfo& info, const TrialSeries& s) {
  constexpr double kMadOfSecondDifference = 0.6745 * 2.449489742783178;  // 0.6745 sqrt(6)
  // the burst's samples [a, b) (t increases): first differences d1[j] = x[a+j+1] - x[a+j], second
  // d2[j] about sample a+j+1, between d1[j] and d1[j+1]
  const double end_s = info.cycles / info.freq_hz;
  std::size_t a = 0;
  while (a < s.size() && s.t_s[a] < 0) ++a;
  std::size_t b = a;
  while (b < s.size() && s.t_s[b] <= end_s) ++b;
  if (b < a + 10) return std::nullopt;  // 8 second differences
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
  return n >= 8 ? std::sqrt(ss / static_cast<double>(n) / 6.0) : first;
}

// Over the trials, the lower quartile of their burst estimates (those that slide least).
std::optional<double> lower_quartile(std::vector<double> per_trial) {
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

// Moves the cells with fewer than min_trials trials to out.skipped; InputError when none is left
// (naming the trials left out as damaged, if any: they may be why).
void skip_small_cells(SweepCells& out, std::vector<std::vector<std::size_t>>& members,
                      std::vector<std::vector<double>>& read_t, int min_trials,
                      std::size_t trial_count) {
  std::vector<Cell> kept;
  std::vector<std::vector<std::size_t>> kept_members;
  std::vector<std::vector<double>> kept_read_t;
  for (std::size_t c = 0; c < out.cells.size(); ++c) {
    if (static_cast<int>(members[c].size()) < min_trials) {
      out.skipped.push_back(out.cells[c].key);
      out.skipped_trials.push_back(members[c].size());
      continue;
    }
    kept.push_back(out.cells[c]);
    kept_members.push_back(members[c]);
    kept_read_t.push_back(std::move(read_t[c]));
  }
  if (kept.empty()) {
    std::string damaged;
    if (!out.damaged.empty())
      damaged = "; " + std::to_string(out.damaged.size()) +
                " trial(s) left out as damaged, the first: " + out.damaged.front().why;
    throw InputError(out.name + ": the sweep is too small to diagnose: no cell has " +
                     std::to_string(min_trials) + " trials, some to fit and some held out (" +
                     std::to_string(trial_count) + " trials in all" + damaged + ")");
  }
  out.cells = std::move(kept);
  members = std::move(kept_members);
  read_t = std::move(kept_read_t);
}

// A cell's trial features (in file order), split alternately into train and test, and its
// majority regions.
void fill_cell(Cell& cell, const std::vector<std::size_t>& members,
               std::vector<std::optional<TrialFeatures>>& features, std::vector<double> read_t) {
  std::vector<model::Region> votes, train_votes, test_votes;
  for (std::size_t j = 0; j < members.size(); ++j) {
    TrialFeatures f = std::move(*features[members[j]]);
    votes.push_back(f.region);
    (j % 2 == 0 ? train_votes : test_votes).push_back(f.region);
    (j % 2 == 0 ? cell.train : cell.test).push_back(std::move(f));
  }
  cell.read_t_s = std::move(read_t);
  cell.measured_region = majority_region(votes);
  cell.train_region = majority_region(train_votes);
  cell.test_region = majority_region(test_votes);
}

// Calls `use` with trial i's time series (read from its file, or held in memory). A trial that
// cannot be read throws InputError naming its file.
using TrialSource =
    std::function<void(std::size_t, const std::function<void(const TrialSeries&)>&)>;

// The readings' spread and noise (SweepCells::reading_sd_m, noise_m) from every trial, one at a
// time: at rest, or (no reading at rest anywhere) inside the bursts; at least the quantization's.
// A trial that cannot be read is marked in `why` (left out) or, without leave_out, rethrown.
void read_noise(SweepCells& out, const std::vector<TrialInfo>& infos, const TrialSource& source,
                bool leave_out, std::vector<std::string>& why) {
  std::vector<double> rest_sd, burst_sd;
  for (std::size_t i = 0; i < infos.size(); ++i) {
    try {
      source(i, [&](const TrialSeries& s) {
        add_rest_sd_m(infos[i], s, rest_sd);
        if (const std::optional<double> b = trial_burst_noise_sd_m(infos[i], s))
          burst_sd.push_back(*b);
      });
    } catch (const InputError& e) {
      if (!leave_out) throw;
      why[i] = e.what();
    }
  }
  const double quant_sd = out.resolution_m / std::sqrt(12.0);
  std::optional<double> sd;
  if (!rest_sd.empty()) sd = median(rest_sd);
  if (!sd) sd = lower_quartile(std::move(burst_sd));
  out.reading_sd_m = std::max(quant_sd, sd.value_or(quant_sd));
  out.noise_m = std::sqrt(std::max(0.0, out.reading_sd_m * out.reading_sd_m - quant_sd * quant_sd));
}

// The features of every trial not yet left out, one at a time, and the read instants of each
// cell's first trial that has them; a trial whose features cannot be read is left out like one
// that cannot be read at all.
std::vector<std::optional<TrialFeatures>> read_features(const SweepCells& out,
                                                        const std::vector<TrialInfo>& infos,
                                                        const std::vector<std::size_t>& cell_of,
                                                        const TrialSource& source, bool leave_out,
                                                        std::vector<std::string>& why,
                                                        std::vector<std::vector<double>>& read_t) {
  std::vector<std::optional<TrialFeatures>> features(infos.size());
  for (std::size_t i = 0; i < infos.size(); ++i) {
    if (!why[i].empty()) continue;
    try {
      source(i, [&](const TrialSeries& s) {
        features[i] = trial_features(infos[i], s, out.resolution_m, out.noise_m);
        if (read_t[cell_of[i]].empty()) read_t[cell_of[i]] = read_instants(infos[i], s);
      });
    } catch (const InputError& e) {
      if (!leave_out) throw;
      why[i] = e.what();
    }
  }
  return features;
}

// Both overloads of collect_cells: the trials streamed from `source` twice (noise, then
// features), never held all at once.
SweepCells collect(const model::StageFile& stage, const std::vector<TrialInfo>& infos,
                   const TrialSource& source, const std::string& name, int min_trials,
                   bool skip_small, const std::function<std::string(std::size_t)>& file_of) {
  if (infos.empty())
    throw InputError(name + ": the sweep is too small to diagnose: it holds no trials");
  const bool leave_out = static_cast<bool>(file_of);
  SweepCells out;
  out.stage = stage;
  out.resolution_m = stage.interferometer.resolution_m;
  out.name = name;
  out.min_trials = min_trials;
  std::vector<std::string> why(infos.size());
  read_noise(out, infos, source, leave_out, why);

  std::vector<std::vector<std::size_t>> members = group_into_cells(infos, out);
  std::vector<std::size_t> cell_of(infos.size());
  for (std::size_t c = 0; c < members.size(); ++c)
    for (std::size_t i : members[c]) cell_of[i] = c;
  std::vector<std::vector<double>> read_t(members.size());
  std::vector<std::optional<TrialFeatures>> features =
      read_features(out, infos, cell_of, source, leave_out, why, read_t);
  for (std::size_t i = 0; i < infos.size(); ++i) {
    if (why[i].empty()) continue;
    const std::string file = file_of(i);  // the message names the file, or gets it in front
    out.damaged.push_back({file, why[i].rfind(file, 0) == 0 ? why[i] : file + ": " + why[i]});
  }
  for (std::vector<std::size_t>& m : members)
    std::erase_if(m, [&](std::size_t i) { return !why[i].empty(); });

  if (skip_small) skip_small_cells(out, members, read_t, min_trials, infos.size());
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
    fill_cell(cell, members[c], features, std::move(read_t[c]));
  }
  return out;
}

std::string bytes_text(std::uintmax_t bytes) {
  return std::to_string(bytes) + " bytes (" + std::to_string(bytes >> 20) + " MiB)";
}

// What a diagnosis holds and reads, from sweep.csv alone, before a trial file is read: its cells,
// the rest readings its trials' features hold, the bytes of its trial files.
void check_budget(const Dataset& ds) {
  const std::string sweep_csv = (std::filesystem::path(ds.path) / "sweep.csv").string();
  SweepCells shell;
  group_into_cells(ds.trials, shell);
  if (shell.cells.size() > kMaxDiagnosedCells)
    throw InputError(sweep_csv + ": " + std::to_string(shell.cells.size()) +
                     " cells (distinct freq_hz, duty, stroke_m), more than a diagnosis takes, " +
                     "allowed at most " + std::to_string(kMaxDiagnosedCells));
  std::uintmax_t readings = 0, bytes = 0;
  for (std::size_t i = 0; i < ds.trials.size(); ++i) {
    readings += static_cast<std::uintmax_t>(ds.trials[i].cycles) + 2;
    std::error_code ec;
    const std::uintmax_t size = std::filesystem::file_size(ds.trial_path(i), ec);
    // a file the reader refuses (recording::kMaxTrialFileBytes) is left out naming it, unread
    if (!ec && size <= recording::kMaxTrialFileBytes) bytes += size;
  }
  if (readings > kMaxHeldReadings)
    throw InputError(sweep_csv + ": the trials' cycles add up to " + std::to_string(readings) +
                     " rest readings, more than a diagnosis holds, allowed at most " +
                     std::to_string(kMaxHeldReadings));
  if (bytes > kMaxDiagnosedBytes)
    throw InputError(sweep_csv + ": the trial files hold " + bytes_text(bytes) +
                     " in all, more than a diagnosis reads, allowed at most " +
                     bytes_text(kMaxDiagnosedBytes));
}

}  // namespace

SweepCells collect_cells(const Dataset& ds, int min_trials) {
  check_budget(ds);
  // a cell short of trials is left out and listed, whether the recorder marked the sweep as cut
  // off or a lab's writer dropped a trial (the format sets no number of trials a cell); so is a
  // trial whose file is damaged
  const TrialSource from_file = [&ds](std::size_t i,
                                      const std::function<void(const TrialSeries&)>& use) {
    use(read_trial(ds, i));
  };
  SweepCells out = collect(ds.stage, ds.trials, from_file, ds.path, min_trials, true,
                           [&ds](std::size_t i) { return ds.trial_path(i); });
  out.progress = ds.progress;
  return out;
}

SweepCells collect_cells(const model::StageFile& stage, const std::vector<TrialInfo>& infos,
                         const std::vector<TrialSeries>& series, const std::string& name,
                         int min_trials, bool skip_small) {
  if (infos.size() != series.size())
    throw std::invalid_argument("collect_cells: infos and trials differ in size");
  const TrialSource in_memory = [&series](std::size_t i,
                                          const std::function<void(const TrialSeries&)>& use) {
    use(series[i]);
  };
  return collect(stage, infos, in_memory, name, min_trials, skip_small, {});
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
