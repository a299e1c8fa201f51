// The sweep dataset reader (recording/dataset.h): the fuzzer's bytes as the files of one dataset
// directory, read with read_dataset and read_trial as idm-gap and the analysis read them.
//
// Input: NUL-separated parts, written to a temporary dataset directory (in /dev/shm when there
// is one): stage.yaml, sweep.csv, then trials/t0.csv, trials/t1.csv, ... (at most 4).
//
// Invariants: a dataset is read or refused with model::InputError naming one of its files; nothing
// else is thrown; every value read is within what a stage and a sweep can be
// (recording/dataset_limits.h, the stage table: the reader checks before it holds more); a trial
// has equal-length columns, finite values and strictly increasing time; and a dataset read whole is
// written again by DatasetWriter and reads back identical (the writer's promise that writer ->
// reader is exact, here from the reader's side) when its trials have distinct files.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <fstream>
#include <set>
#include <string>
#include <string_view>
#include <vector>

#include "model/range.h"
#include "model/stage.h"
#include "recording/dataset.h"
#include "recording/dataset_limits.h"

namespace fs = std::filesystem;
using idm::recording::Dataset;
using idm::recording::TrialSeries;

namespace {

[[noreturn]] void fail(const char* what, const std::string& detail) {
  std::fprintf(stderr, "fuzz_dataset: %s: %s\n", what, detail.c_str());
  std::abort();
}

const fs::path& work_dir() {
  static const fs::path dir = [] {
    const fs::path base =
        fs::is_directory("/dev/shm") ? fs::path("/dev/shm") : fs::temp_directory_path();
    std::string name = (base / "idm-fuzz-dataset-XXXXXX").string();
    if (!::mkdtemp(name.data())) fail("mkdtemp", name);
    return fs::path(name);
  }();
  return dir;
}

void write(const fs::path& path, std::string_view text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(text.data(), static_cast<std::streamsize>(text.size()));
  if (!out) fail("cannot write", path.string());
}

void check_limits(const Dataset& d) {
  namespace rec = idm::recording;
  const idm::model::Range& stroke = idm::model::stage_key_range("stroke_m");
  for (const auto& t : d.trials)
    if (!rec::kFreqRangeHz.contains(t.freq_hz) ||
        !rec::kSampleRateRangeHz.contains(t.sample_rate_hz) || !stroke.contains(t.stroke_m) ||
        t.cycles < 1 || t.cycles > rec::kMaxCycles)
      fail("a value beyond the dataset's limits was read", t.id);
  if (!idm::model::stage_key_range("slider_mass_kg").contains(d.stage.stage.slider_mass_kg))
    fail("a stage mass beyond the stage table's range was read", d.path);
}

void check_series(const TrialSeries& s, const std::string& where) {
  if (s.xi_cmd_m.size() != s.size() || s.x_m.size() != s.size() || s.size() == 0)
    fail("columns of unequal length or empty", where);
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (!std::isfinite(s.t_s[i]) || !std::isfinite(s.xi_cmd_m[i]) || !std::isfinite(s.x_m[i]))
      fail("a value that is not finite", where);
    if (i > 0 && !(s.t_s[i] > s.t_s[i - 1])) fail("time does not increase", where);
  }
}

bool same_series(const TrialSeries& a, const TrialSeries& b) {
  return a.t_s == b.t_s && a.xi_cmd_m == b.xi_cmd_m && a.x_m == b.x_m;
}

// Writes what was read with DatasetWriter into `copy` and reads it back.
void round_trip(const Dataset& read, const std::vector<TrialSeries>& series, const fs::path& copy) {
  fs::remove_all(copy);
  {
    idm::recording::DatasetWriter writer(copy.string(), read.stage);
    for (std::size_t i = 0; i < read.trials.size(); ++i)
      writer.add_trial(read.trials[i], series[i]);
  }
  const Dataset again = idm::recording::read_dataset(copy.string());
  if (again.trials.size() != read.trials.size()) fail("round trip: trial count", copy.string());
  for (std::size_t i = 0; i < read.trials.size(); ++i) {
    const auto& a = read.trials[i];
    const auto& b = again.trials[i];
    if (a.id != b.id || a.freq_hz != b.freq_hz || a.duty != b.duty || a.stroke_m != b.stroke_m ||
        a.cycles != b.cycles || a.sample_rate_hz != b.sample_rate_hz ||
        a.guide_pos_m != b.guide_pos_m || a.file != b.file)
      fail("round trip: a row of sweep.csv changed", a.id);
    if (!same_series(series[i], idm::recording::read_trial(again, i)))
      fail("round trip: a trial's samples changed", a.id);
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view input(reinterpret_cast<const char*>(data), size);
  std::vector<std::string_view> parts;
  for (std::size_t start = 0;;) {
    const std::size_t end = input.find('\0', start);
    parts.push_back(input.substr(start, end == std::string_view::npos ? end : end - start));
    if (end == std::string_view::npos || parts.size() == 6) break;
    start = end + 1;
  }
  const fs::path dir = work_dir() / "in";
  fs::remove_all(dir);
  fs::create_directories(dir / "trials");
  write(dir / "stage.yaml", parts[0]);
  if (parts.size() > 1) write(dir / "sweep.csv", parts[1]);
  for (std::size_t i = 2; i < parts.size(); ++i)
    write(dir / "trials" / ("t" + std::to_string(i - 2) + ".csv"), parts[i]);

  Dataset dataset;
  std::vector<TrialSeries> series;
  try {
    dataset = idm::recording::read_dataset(dir.string());
    check_limits(dataset);
    for (std::size_t i = 0; i < dataset.trials.size(); ++i) {
      series.push_back(idm::recording::read_trial(dataset, i));
      check_series(series.back(), dataset.trial_path(i));
    }
  } catch (const idm::model::InputError& e) {
    const std::string what = e.what();
    if (what.rfind(dir.string() + "/", 0) != 0) fail("an error that names no file", what);
    return 0;
  } catch (const std::exception& e) {
    fail("an exception other than InputError", e.what());
  }
  // The writer gives every trial its own file; a dataset whose rows share one (which the format
  // allows) is not written again.
  std::set<std::string> files;
  for (const auto& t : dataset.trials)
    if (!files.insert(fs::path(t.file).lexically_normal().string()).second) return 0;
  try {
    round_trip(dataset, series, work_dir() / "copy");
  } catch (const std::exception& e) {
    fail("a dataset read whole cannot be written again", e.what());
  }
  return 0;
}
