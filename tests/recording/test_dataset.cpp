#include <gtest/gtest.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <sstream>
#include <string>
#include <system_error>
#include <vector>

#include "recording/dataset.h"

using namespace idm::recording;
namespace fs = std::filesystem;

namespace {

const std::string kSample = IDM_SAMPLE_SWEEP_DIR;  // tests/data/README.md

// A fresh directory per test (ctest runs tests in parallel processes), removed afterwards.
struct TempDir {
  fs::path path;
  TempDir() {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    path = fs::temp_directory_path() /
           ("idm_test_analysis_" + std::string(info->name()) + "_" + std::to_string(::getpid()));
    fs::remove_all(path);
    fs::create_directories(path);
  }
  ~TempDir() {
    std::error_code ignored;
    fs::remove_all(path, ignored);
  }
  std::string str() const { return path.string(); }
  std::string operator/(const std::string& name) const { return (path / name).string(); }
};

void write_text(const fs::path& path, const std::string& text) {
  fs::create_directories(path.parent_path());
  std::ofstream out(path, std::ios::binary);
  out << text;
}

std::string read_text(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

const char* kStageYaml =
    "stage:\n"
    "  slider_mass_kg: 0.16557\n"
    "  counter_mass_kg: 0.05761\n"
    "  friction_coefficient: 0.4\n"
    "  gravity_m_s2: 9.8\n"
    "  stroke_m: 20.35e-6\n"
    "  step_correction: 0.35\n"
    "interferometer:\n"
    "  resolution_m: 9.8906e-9\n";

const char* kSweepHeader = "trial,freq_hz,duty,stroke_m,cycles,sample_rate_hz,guide_pos_m,file\n";
const char* kGoodTrial = "t_s,xi_cmd_m,x_m\n0,0,0.01\n0.0001,1e-6,0.01\n0.0002,2e-6,0.0100001\n";

// A small valid dataset with one trial, "a", in trials/a.csv.
void write_small_dataset(const TempDir& dir) {
  write_text(dir / "stage.yaml", kStageYaml);
  write_text(dir / "sweep.csv",
             std::string(kSweepHeader) + "a,100,0.1,2e-05,3,10000,0.01,trials/a.csv\n");
  write_text(dir / "trials/a.csv", kGoodTrial);
}

// The message of the InputError that reading the dataset (and every trial) throws, or "".
std::string read_error(const std::string& dir) {
  try {
    const Dataset d = read_dataset(dir);
    for (std::size_t i = 0; i < d.trials.size(); ++i) read_trial(d, i);
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

// Every line of a CSV file split at its commas, read here without the library (for files whose
// fields hold no quotes).
std::vector<std::vector<std::string>> csv_lines(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  EXPECT_TRUE(in.good()) << "cannot open " << path;
  std::vector<std::vector<std::string>> lines;
  std::string line, field;
  while (std::getline(in, line)) {
    std::stringstream fields(line);
    lines.emplace_back();
    while (std::getline(fields, field, ',')) lines.back().push_back(field);
  }
  return lines;
}

// The series holds every number of the trial file, exactly and in order.
void expect_as_in_file(const std::string& path, const TrialSeries& s) {
  const std::vector<std::vector<std::string>> lines = csv_lines(path);
  ASSERT_EQ(lines.size(), s.size() + 1) << path;
  EXPECT_EQ(lines[0], (std::vector<std::string>{"t_s", "xi_cmd_m", "x_m"})) << path;
  for (std::size_t k = 0; k < s.size(); ++k) {
    ASSERT_EQ(lines[k + 1].size(), 3u) << path << ":" << k + 2;
    EXPECT_EQ(s.t_s[k], std::stod(lines[k + 1][0])) << path << ":" << k + 2;
    EXPECT_EQ(s.xi_cmd_m[k], std::stod(lines[k + 1][1])) << path << ":" << k + 2;
    EXPECT_EQ(s.x_m[k], std::stod(lines[k + 1][2])) << path << ":" << k + 2;
  }
}

std::size_t index_of(const Dataset& d, const std::string& id) {
  for (std::size_t i = 0; i < d.trials.size(); ++i)
    if (d.trials[i].id == id) return i;
  ADD_FAILURE() << "no trial " << id;
  return 0;
}

std::vector<fs::path> temporary_files(const fs::path& root) {
  std::vector<fs::path> found;
  for (const auto& entry : fs::recursive_directory_iterator(root))
    if (entry.is_regular_file() && entry.path().extension() == ".tmp")
      found.push_back(entry.path());
  return found;
}

TrialSeries ramp_series(std::size_t n, double x0) {
  TrialSeries s;
  for (std::size_t i = 0; i < n; ++i) {
    s.t_s.push_back(-0.0005 + 5e-5 * static_cast<double>(i));
    s.xi_cmd_m.push_back(1e-7 * std::sin(0.1 * static_cast<double>(i)));
    s.x_m.push_back(x0 + 9.8906e-9 * static_cast<double>(i / 3));
  }
  return s;
}

TrialInfo cell(double freq_hz, double duty, double stroke_m) {
  TrialInfo t;
  t.freq_hz = freq_hz;
  t.duty = duty;
  t.stroke_m = stroke_m;
  t.cycles = 12;
  t.sample_rate_hz = 20000;
  t.guide_pos_m = 0.02;
  return t;
}

}  // namespace

// ---------------------------------------------------------------- the sample sweep

// The sample sweep (tests/data/README.md: idm-model sweep, 480 trials). The numbers the reader
// returns are the file's, exactly: the expected values are read from the text here, line by line,
// without the library.
TEST(Dataset, ReadsTheSampleSweep) {
  const Dataset d = read_dataset(kSample);
  ASSERT_EQ(d.trials.size(), 480u);
  EXPECT_DOUBLE_EQ(d.stage.stage.slider_mass_kg, 0.16557);
  EXPECT_DOUBLE_EQ(d.stage.stage.stroke_m, 2.035e-05);
  EXPECT_DOUBLE_EQ(d.stage.interferometer.resolution_m, 9.8906e-09);

  const TrialInfo& first = d.trials.front();
  EXPECT_EQ(first.id, "f100_d0.050_s20.35um_t0");
  EXPECT_EQ(first.freq_hz, 100.0);
  EXPECT_EQ(first.duty, 0.05);
  EXPECT_EQ(first.stroke_m, 2.035e-05);
  EXPECT_EQ(first.cycles, 12);
  EXPECT_EQ(first.sample_rate_hz, 20000.0);
  const std::vector<std::string> row = csv_lines(kSample + "/sweep.csv")[1];
  ASSERT_EQ(row.size(), 8u);
  EXPECT_EQ(first.guide_pos_m, std::stod(row[6]));
  EXPECT_EQ(first.file, "trials/f100_d0.050_s20.35um_t0.csv");
  EXPECT_EQ(d.trial_path(0), kSample + "/trials/f100_d0.050_s20.35um_t0.csv");
  EXPECT_EQ(d.trials.back().id, "f800_d0.950_s10.18um_t2");

  const TrialSeries s = read_trial(d, 0);
  ASSERT_EQ(s.size(), 2811u);  // 0.5 ms at rest, 12 cycles and 2 at rest at 100 Hz, 20 kHz
  EXPECT_EQ(s.t_s[0], -0.0005);
  EXPECT_EQ(s.xi_cmd_m[0], 0.0);
  EXPECT_EQ(s.t_s[10], 0.0);  // file line 12: the first extension starts
  EXPECT_EQ(s.t_s[12], 0.0001);
  EXPECT_DOUBLE_EQ(s.xi_cmd_m[12], 4.07e-06);  // a fifth of the way up (duty 0.05 at 100 Hz)
  EXPECT_EQ(s.t_s.back(), 0.14);
  expect_as_in_file(d.trial_path(0), s);

  const std::size_t fast_index = index_of(d, "f800_d0.950_s10.18um_t2");
  const TrialSeries fast = read_trial(d, fast_index);
  EXPECT_EQ(fast.size(), 361u);
  expect_as_in_file(d.trial_path(fast_index), fast);
  EXPECT_THROW(read_trial(d, 480), std::out_of_range);
}

// Reads every trial whole. How fast is a benchmark's question (bench/), not a test's: the time is
// printed only.
TEST(Dataset, ReadsEveryTrialOfTheSample) {
  const auto start = std::chrono::steady_clock::now();
  const Dataset d = read_dataset(kSample);
  std::size_t samples = 0;
  for (std::size_t i = 0; i < d.trials.size(); ++i) {
    const TrialSeries s = read_trial(d, i);
    ASSERT_GT(s.size(), 100u) << d.trials[i].id;
    ASSERT_EQ(s.xi_cmd_m.size(), s.size());
    ASSERT_EQ(s.x_m.size(), s.size());
    samples += s.size();
  }
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::cout << "read " << d.trials.size() << " trials, " << samples << " samples in " << seconds
            << " s\n";
}

// ---------------------------------------------------------------- round trip

TEST(Dataset, WriterAndReaderRoundTripExactly) {
  TempDir tmp;
  const std::string dir = tmp / "sweep";
  idm::model::StageFile stage;
  stage.stage.slider_mass_kg = 0.2345678901234567;
  stage.stage.friction_coefficient = 0.1 + 0.2;  // 0.30000000000000004
  stage.interferometer.resolution_m = 1.0 / 3.0 * 1e-8;

  std::vector<TrialInfo> infos;
  std::vector<TrialSeries> series;
  {
    DatasetWriter w(dir, stage);
    TrialInfo a = cell(100, 0.05, 20.35e-6);
    a.guide_pos_m = -0.0123456789012345678;
    series.push_back(ramp_series(2800, 0.0268594672336));
    series.back().x_m[5] = 1e-310;  // subnormal
    series.back().xi_cmd_m[7] = -2.2250738585072014e-308;
    series.back().t_s[0] = -1.0 / 3.0;
    infos.push_back(w.add_trial(a, series.back()));

    TrialInfo b = cell(123.456789, 0.95, 10.175e-6);
    b.id = "odd, \"quoted\" id ";
    b.file = "trials/sub dir/odd,name.csv";
    b.cycles = 7;
    b.sample_rate_hz = 1.0 / 7e-6;
    series.push_back(ramp_series(50, 0.04));
    infos.push_back(w.add_trial(b, series.back()));

    for (int k = 0; k < 3; ++k) {
      series.push_back(ramp_series(10 + k, 0.001 * k));
      infos.push_back(w.add_trial(cell(800, 0.45, 10.175e-6), series.back()));
    }
    EXPECT_EQ(w.dataset().trials.size(), 5u);
  }
  EXPECT_EQ(infos[0].id, "f100_d0.050_s20.35um_t0");
  EXPECT_EQ(infos[0].file, "trials/f100_d0.050_s20.35um_t0.csv");
  EXPECT_EQ(infos[2].id, "f800_d0.450_s10.18um_t0");
  EXPECT_EQ(infos[4].id, "f800_d0.450_s10.18um_t2");
  EXPECT_TRUE(fs::exists(tmp.path / "sweep/trials/f800_d0.450_s10.18um_t2.csv"));

  const Dataset d = read_dataset(dir);
  EXPECT_EQ(d.stage.stage.slider_mass_kg, stage.stage.slider_mass_kg);
  EXPECT_EQ(d.stage.stage.friction_coefficient, stage.stage.friction_coefficient);
  EXPECT_EQ(d.stage.interferometer.resolution_m, stage.interferometer.resolution_m);
  ASSERT_EQ(d.trials.size(), infos.size());
  for (std::size_t i = 0; i < infos.size(); ++i) {
    const TrialInfo& r = d.trials[i];
    EXPECT_EQ(r.id, infos[i].id);
    EXPECT_EQ(r.freq_hz, infos[i].freq_hz);
    EXPECT_EQ(r.duty, infos[i].duty);
    EXPECT_EQ(r.stroke_m, infos[i].stroke_m);
    EXPECT_EQ(r.cycles, infos[i].cycles);
    EXPECT_EQ(r.sample_rate_hz, infos[i].sample_rate_hz);
    EXPECT_EQ(r.guide_pos_m, infos[i].guide_pos_m);
    EXPECT_EQ(r.file, infos[i].file);
    const TrialSeries s = read_trial(d, i);
    EXPECT_EQ(s.t_s, series[i].t_s);
    EXPECT_EQ(s.xi_cmd_m, series[i].xi_cmd_m);
    EXPECT_EQ(s.x_m, series[i].x_m);
  }
  EXPECT_TRUE(temporary_files(tmp.path).empty());
}

TEST(Dataset, TrialNamesFollowTheSample) {
  EXPECT_EQ(trial_name(100, 0.05, 20.35e-6, 0), "f100_d0.050_s20.35um_t0");
  EXPECT_EQ(trial_name(800, 0.95, 10.175e-6, 2), "f800_d0.950_s10.18um_t2");
  EXPECT_EQ(trial_name(2500.5, 0.5, 1e-6, 11), "f2500.5_d0.500_s1.00um_t11");
}

// ---------------------------------------------------------------- other writers' habits

TEST(Dataset, ColumnsInAnyOrderExtraColumnsCrlfAndNumberForms) {
  TempDir tmp;
  write_text(tmp / "stage.yaml",
             std::string(kStageYaml) + "  noise_m: 1e-9\nsomething_else:\n  key: 3\n");
  write_text(tmp / "sweep.csv",
             "\xEF\xBB\xBF"
             "file, notes ,guide_pos_m,cycles,sample_rate_hz,stroke_m,duty,freq_hz,trial\r\n"
             "trials/x.csv,first run,-1.5E-2,1.2e1,2E4,+20.35e-6,.05,100.,x\r\n"
             "\"trials/y.csv\",\"a, b\",0,3,20000,2.035e-05,0.95,800,\"y\"\r\n"
             "\r\n"
             "\r\n");
  write_text(tmp / "trials/x.csv",
             "x_m,comment,t_s,xi_cmd_m\r\n0.01,,-5e-4,0\r\n0.0100000098906,ok,0,0\r\n"
             "1.00000098906E-2,ok,+5.0e-05,2.035E-06\r\n\r\n");
  write_text(tmp / "trials/y.csv",
             "t_s,xi_cmd_m,x_m\n0,0,0\n1,1e-400,-1e-400");  // no final newline

  const Dataset d = read_dataset(tmp.str());
  EXPECT_EQ(d.stage.interferometer.noise_m, 1e-9);
  ASSERT_EQ(d.trials.size(), 2u);
  const TrialInfo& x = d.trials[0];
  EXPECT_EQ(x.id, "x");
  EXPECT_EQ(x.freq_hz, 100.0);
  EXPECT_EQ(x.duty, 0.05);
  EXPECT_EQ(x.stroke_m, 20.35e-6);
  EXPECT_EQ(x.cycles, 12);
  EXPECT_EQ(x.sample_rate_hz, 20000.0);
  EXPECT_EQ(x.guide_pos_m, -0.015);
  EXPECT_EQ(x.file, "trials/x.csv");
  EXPECT_EQ(d.trials[1].id, "y");
  EXPECT_EQ(d.trials[1].file, "trials/y.csv");

  const TrialSeries s = read_trial(d, 0);
  ASSERT_EQ(s.size(), 3u);
  EXPECT_EQ(s.t_s, (std::vector<double>{-5e-4, 0, 5e-5}));
  EXPECT_EQ(s.xi_cmd_m, (std::vector<double>{0, 0, 2.035e-6}));
  EXPECT_EQ(s.x_m, (std::vector<double>{0.01, 0.0100000098906, 0.0100000098906}));
  const TrialSeries y = read_trial(d, 1);
  ASSERT_EQ(y.size(), 2u);
  EXPECT_EQ(y.xi_cmd_m[1], 0.0);  // below the smallest double
  EXPECT_EQ(y.x_m[1], 0.0);
}

// ---------------------------------------------------------------- format errors

TEST(DatasetErrors, MissingRequiredKeyInStageYaml) {
  TempDir tmp;
  write_small_dataset(tmp);
  write_text(tmp / "stage.yaml",
             "stage:\n  slider_mass_kg: 0.16557\n  counter_mass_kg: 0.05761\n"
             "  friction_coefficient: 0.4\n  stroke_m: 20.35e-6\n  step_correction: 0.35\n"
             "interferometer:\n  resolution_m: 9.8906e-9\n");
  EXPECT_EQ(read_error(tmp.str()),
            tmp / "stage.yaml" + ":2: stage.gravity_m_s2: missing required key");
  write_text(tmp / "stage.yaml", std::string(kStageYaml) + "  wobble: 1\n");  // unknown: ignored
  EXPECT_EQ(read_error(tmp.str()), "");
  write_text(tmp / "stage.yaml", "stage:\n  slider_mass_kg: heavy\n");
  EXPECT_EQ(read_error(tmp.str()),
            tmp / "stage.yaml" + ":2: stage.slider_mass_kg: 'heavy' is not a number");
}

TEST(DatasetErrors, NonNumericValues) {
  TempDir tmp;
  write_small_dataset(tmp);
  write_text(tmp / "sweep.csv", std::string(kSweepHeader) +
                                    "a,100,0.1,2e-05,3,10000,0.01,trials/a.csv\n"
                                    "b,200,abc,2e-05,3,10000,0.01,trials/a.csv\n");
  EXPECT_EQ(read_error(tmp.str()), tmp / "sweep.csv" + ":3:3 (duty): 'abc' is not a number");

  write_small_dataset(tmp);
  write_text(tmp / "trials/a.csv", "t_s,xi_cmd_m,x_m\n0,0,0.01\n0.0001,1e-6 m,0.01\n");
  EXPECT_EQ(read_error(tmp.str()),
            tmp / "trials/a.csv" + ":3:2 (xi_cmd_m): '1e-6 m' is not a number");

  write_text(tmp / "trials/a.csv", "t_s,xi_cmd_m,x_m\n0,0,0.01\n0.0001,,0.01\n");
  EXPECT_EQ(read_error(tmp.str()),
            tmp / "trials/a.csv" + ":3:2 (xi_cmd_m): empty value, expected a number");

  write_small_dataset(tmp);
  write_text(tmp / "sweep.csv",
             std::string(kSweepHeader) + "a,100,0.1,2e-05,3.5,10000,0.01,trials/a.csv\n");
  EXPECT_EQ(read_error(tmp.str()),
            tmp / "sweep.csv" + ":2:5 (cycles): '3.5' is not a whole number");
}

TEST(DatasetErrors, MissingTrialFile) {
  TempDir tmp;
  write_small_dataset(tmp);
  write_text(tmp / "sweep.csv", std::string(kSweepHeader) +
                                    "a,100,0.1,2e-05,3,10000,0.01,trials/a.csv\n"
                                    "b,100,0.1,2e-05,3,10000,0.01,trials/b.csv\n");
  EXPECT_EQ(read_error(tmp.str()), tmp / "sweep.csv" +
                                       ":3:8 (file): 'trials/b.csv' does not exist (" +
                                       tmp / "trials/b.csv" + ")");
}

TEST(DatasetErrors, TimeGoingBackwards) {
  TempDir tmp;
  write_small_dataset(tmp);
  write_text(tmp / "trials/a.csv", "t_s,xi_cmd_m,x_m\n0,0,0.01\n0.0002,1e-6,0.01\n0.0001,0,0\n");
  EXPECT_EQ(
      read_error(tmp.str()),
      tmp / "trials/a.csv" + ":4:1 (t_s): time 0.0001 does not increase (previous row: 0.0002)");
  // Equal times are not strictly increasing either; columns in another order name the right one.
  write_text(tmp / "trials/a.csv", "x_m,xi_cmd_m,t_s\n0.01,0,0\n0.01,0,0\n");
  EXPECT_EQ(read_error(tmp.str()),
            tmp / "trials/a.csv" + ":3:3 (t_s): time 0 does not increase (previous row: 0)");
}

TEST(DatasetErrors, NotANumberOrInfinite) {
  TempDir tmp;
  write_small_dataset(tmp);
  write_text(tmp / "trials/a.csv", "t_s,xi_cmd_m,x_m\n0,0,0.01\n0.0001,0,nan\n");
  EXPECT_EQ(read_error(tmp.str()),
            tmp / "trials/a.csv" + ":3:3 (x_m): 'nan' is not a finite number");
  write_text(tmp / "trials/a.csv", "t_s,xi_cmd_m,x_m\n0,-inf,0.01\n");
  EXPECT_EQ(read_error(tmp.str()),
            tmp / "trials/a.csv" + ":2:2 (xi_cmd_m): '-inf' is not a finite number");
  write_text(tmp / "trials/a.csv", "t_s,xi_cmd_m,x_m\n0,0,1e999\n");
  EXPECT_EQ(read_error(tmp.str()),
            tmp / "trials/a.csv" + ":2:3 (x_m): '1e999' is not a finite number");
  write_small_dataset(tmp);
  write_text(tmp / "sweep.csv",
             std::string(kSweepHeader) + "a,NaN,0.1,2e-05,3,10000,0.01,trials/a.csv\n");
  EXPECT_EQ(read_error(tmp.str()),
            tmp / "sweep.csv" + ":2:2 (freq_hz): 'NaN' is not a finite number");
}

TEST(DatasetErrors, OutOfRangeValues) {
  TempDir tmp;
  write_small_dataset(tmp);
  auto with_row = [&](const std::string& row) {
    write_text(tmp / "sweep.csv", std::string(kSweepHeader) + row + "\n");
    return read_error(tmp.str());
  };
  const std::string sweep = tmp / "sweep.csv";
  EXPECT_EQ(with_row("a,100,1,2e-05,3,10000,0.01,trials/a.csv"),
            sweep + ":2:3 (duty): 1 is out of range, allowed (0, 1)");
  EXPECT_EQ(with_row("a,100,0,2e-05,3,10000,0.01,trials/a.csv"),
            sweep + ":2:3 (duty): 0 is out of range, allowed (0, 1)");
  EXPECT_EQ(with_row("a,-100,0.1,2e-05,3,10000,0.01,trials/a.csv"),
            sweep + ":2:2 (freq_hz): -100 is out of range, allowed (0, 1000000]");
  EXPECT_EQ(with_row("a,100,0.1,0,3,10000,0.01,trials/a.csv"),
            sweep + ":2:4 (stroke_m): 0 is out of range, allowed (0, 0.001]");
  EXPECT_EQ(with_row("a,100,0.1,2e-05,0,10000,0.01,trials/a.csv"),
            sweep + ":2:5 (cycles): 0 is out of range, allowed [1, 100000]");
  EXPECT_EQ(with_row("a,100,0.1,2e-05,3,0,0.01,trials/a.csv"),
            sweep + ":2:6 (sample_rate_hz): 0 is out of range, allowed (0, 100000000]");
  // beyond what a stage and a sweep can be (recording/dataset_limits.h, the stage table), refused
  // before anything is read or held for them
  EXPECT_EQ(with_row("a,1e9,0.1,2e-05,3,10000,0.01,trials/a.csv"),
            sweep + ":2:2 (freq_hz): 1e+09 is out of range, allowed (0, 1000000]");
  EXPECT_EQ(with_row("a,100,0.1,0.01,3,10000,0.01,trials/a.csv"),
            sweep + ":2:4 (stroke_m): 0.01 is out of range, allowed (0, 0.001]");
  EXPECT_EQ(with_row("a,100,0.1,2e-05,100001,10000,0.01,trials/a.csv"),
            sweep + ":2:5 (cycles): 100001 is out of range, allowed [1, 100000]");
  EXPECT_EQ(with_row("a,100,0.1,2e-05,3,1e9,0.01,trials/a.csv"),
            sweep + ":2:6 (sample_rate_hz): 1e+09 is out of range, allowed (0, 100000000]");
  EXPECT_EQ(with_row(",100,0.1,2e-05,3,10000,0.01,trials/a.csv"),
            sweep + ":2:1 (trial): empty trial id");
  EXPECT_EQ(with_row("a,100,0.1,2e-05,3,10000,0.01,trials/a.csv"), "");
}

TEST(DatasetErrors, AStageBeyondWhatAStageCanBeIsRefusedNamingKeyAndRange) {
  TempDir tmp;
  write_small_dataset(tmp);
  std::string yaml = kStageYaml;
  yaml.replace(yaml.find("0.16557"), 7, "1e-300");
  write_text(tmp / "stage.yaml", yaml);
  EXPECT_EQ(read_error(tmp.str()), tmp / "stage.yaml" +
                                       ":2: stage.slider_mass_kg: 1e-300 is out of range, allowed "
                                       "[1e-06, 1000]");
}

TEST(DatasetErrors, APlanBeyondWhatASweepCanBeIsRefused) {
  TempDir tmp;
  write_small_dataset(tmp);
  write_text(
      tmp / "plan.yaml",
      "status: complete\ncells:\n  - {freq_hz: 1e9, duty: 0.1, stroke_m: 2e-05, trials: 1}\n");
  EXPECT_EQ(read_error(tmp.str()),
            tmp / "plan.yaml" + ":3: cells[0].freq_hz: 1e+09 is out of range, allowed (0, 1e+06]");
  write_text(tmp / "plan.yaml",
             "status: complete\ncells:\n  - {freq_hz: 100, duty: 0.1, stroke_m: 2e-05, trials: "
             "1000000}\n");
  EXPECT_NE(read_error(tmp.str()).find("cells[0].trials"), std::string::npos);
}

TEST(DatasetErrors, MoreTrialsOfACellThanASweepCanHoldAreRefusedNamingTheLine) {
  TempDir tmp;
  write_small_dataset(tmp);
  std::string csv = kSweepHeader;
  for (int i = 0; i <= 100000; ++i)
    csv += "t" + std::to_string(i) + ",100,0.1,2e-05,3,10000,0.01,trials/a.csv\n";
  write_text(tmp / "sweep.csv", csv);
  EXPECT_EQ(read_error(tmp.str()),
            tmp / "sweep.csv" +
                ":100002:1 (trial): more than 100000 trials of one cell (100 Hz, duty 0.1, stroke "
                "2e-05 m), allowed at most 100000");
}

// `read` (the message of its InputError, or "") run in a child process, so that a reader that
// blocks does not hang the suite: "(blocked)" when the child has not finished within 10 s.
std::string error_in_child(const std::function<std::string()>& read) {
  int fds[2];
  if (::pipe(fds) != 0) return "(no pipe)";
  const pid_t child = ::fork();
  if (child == 0) {
    ::close(fds[0]);
    const std::string e = read();
    if (::write(fds[1], e.data(), e.size()) < 0) ::_exit(3);
    ::_exit(0);
  }
  ::close(fds[1]);
  int status = 0;
  for (int i = 0; i < 1000 && ::waitpid(child, &status, WNOHANG) == 0; ++i) ::usleep(10000);
  if (::waitpid(child, &status, WNOHANG) == 0) {
    ::kill(child, SIGKILL);
    ::waitpid(child, &status, 0);
    ::close(fds[0]);
    return "(blocked)";
  }
  std::string out;
  char buf[512];
  for (ssize_t n; (n = ::read(fds[0], buf, sizeof buf)) > 0;) out.append(buf, n);
  ::close(fds[0]);
  return out;
}

TEST(DatasetErrors, AFifoIsRefusedAtOnceNamingTheFile) {
  for (const char* name : {"sweep.csv", "stage.yaml", "plan.yaml"}) {
    TempDir tmp;
    write_small_dataset(tmp);
    fs::remove(tmp / name);
    ASSERT_EQ(::mkfifo((tmp / name).c_str(), 0600), 0) << name;
    EXPECT_EQ(error_in_child([&] { return read_error(tmp.str()); }),
              tmp / name + ": not a regular file (a FIFO), allowed: a regular file")
        << name;
  }
  TempDir tmp;
  const std::string fifo = tmp / "trial.csv";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  EXPECT_EQ(error_in_child([&] {
              try {
                read_trial_file(fifo);
              } catch (const InputError& e) {
                return std::string(e.what());
              }
              return std::string();
            }),
            fifo + ": not a regular file (a FIFO), allowed: a regular file");
}

TEST(DatasetErrors, AFileLargerThanTheReaderTakesIsRefusedNamingItAndTheLimit) {
  TempDir tmp;
  write_small_dataset(tmp);
  // sparse: 300 MiB that take no room on the disk
  fs::resize_file(tmp / "trials/a.csv", std::uintmax_t{300} << 20);
  EXPECT_EQ(read_error(tmp.str()),
            tmp / "trials/a.csv" +
                ": 314572800 bytes (300 MiB), more than the reader takes in one file, allowed at "
                "most 268435456 bytes (256 MiB)");
}

TEST(DatasetErrors, FilePathMustStayInsideTheDataset) {
  TempDir tmp;
  write_small_dataset(tmp);
  const std::string sweep = tmp / "sweep.csv";
  auto with_file = [&](const std::string& file) {
    write_text(tmp / "sweep.csv",
               std::string(kSweepHeader) + "a,100,0.1,2e-05,3,10000,0.01," + file + "\n");
    return read_error(tmp.str());
  };
  const std::string outside = tmp / "trials/a.csv";
  EXPECT_EQ(with_file(outside),
            sweep + ":2:8 (file): '" + outside +
                "' is an absolute path, expected a path relative to the dataset");
  EXPECT_EQ(with_file("trials/../../a.csv"),
            sweep + ":2:8 (file): 'trials/../../a.csv' leaves the dataset directory ('..')");
  EXPECT_EQ(with_file(""), sweep + ":2:8 (file): empty path");
  EXPECT_EQ(with_file("trials"), sweep + ":2:8 (file): 'trials' is not a regular file");
  EXPECT_EQ(with_file("./trials/a.csv"), "");
}

TEST(DatasetErrors, HeaderAndRowShape) {
  TempDir tmp;
  write_small_dataset(tmp);
  const std::string sweep = tmp / "sweep.csv";
  const std::string trial = tmp / "trials/a.csv";

  write_text(sweep, "trial,freq_hz,duty,stroke_m,cycles,sample_rate_hz,file\n");
  EXPECT_EQ(read_error(tmp.str()),
            sweep +
                ":1: missing required column 'guide_pos_m' (required: trial, freq_hz, duty, "
                "stroke_m, cycles, sample_rate_hz, guide_pos_m, file)");
  write_text(sweep, "a,100,0.1,2e-05,3,10000,0.01,trials/a.csv\n");  // no header
  EXPECT_NE(read_error(tmp.str()).find(sweep + ":1: missing required column 'trial'"),
            std::string::npos);
  write_text(sweep, "");
  EXPECT_EQ(read_error(tmp.str()), sweep + ":1: empty file, expected a header line");
  write_text(sweep, std::string(kSweepHeader) + "a,100,0.1,2e-05,3,10000,0.01,trials/a.csv\n" +
                        "a,200,0.1,2e-05,3,10000,0.01,trials/a.csv\n");
  EXPECT_EQ(read_error(tmp.str()), sweep + ":3:1 (trial): 'a' repeats the trial id of line 2");
  write_text(sweep, std::string(kSweepHeader) + "a,100,0.1,2e-05,3,10000,0.01\n");
  EXPECT_EQ(read_error(tmp.str()),
            sweep + ":2:8 (file): missing value (the row has 7 fields, the header 8)");
  write_text(sweep, std::string(kSweepHeader) + "a,100,0.1,2e-05,3,10000,0.01,trials/a.csv,x\n");
  EXPECT_EQ(read_error(tmp.str()), sweep + ":2:9: the row has 9 fields, the header 8");
  write_text(sweep, std::string(kSweepHeader) + "\"a,100,0.1,2e-05,3,10000,0.01,trials/a.csv\n");
  EXPECT_EQ(read_error(tmp.str()),
            sweep + ":2:1 (trial): unterminated quote (a field cannot span lines)");

  write_small_dataset(tmp);
  write_text(trial, "t_s,xi_cmd_m,x_m,t_s\n0,0,0,0\n");
  EXPECT_EQ(read_error(tmp.str()),
            trial + ":1:4 (t_s): column 't_s' appears twice (also column 1)");
  write_text(trial, "t_s,xi_cmd_m,x_m\n0,0,0\n\n1,1,1\n");
  EXPECT_EQ(read_error(tmp.str()), trial + ":3: empty line before the end of the data");
  write_text(trial, "t_s,xi_cmd_m,x_m\r\n\r\n");
  EXPECT_EQ(read_error(tmp.str()), trial + ":2: no samples after the header");
  EXPECT_EQ(read_error(tmp / "nowhere"),
            tmp / "nowhere" + ": not a dataset directory (does not exist)");
}

// ---------------------------------------------------------------- writer: bad input, crash safety

TEST(DatasetWriter, RejectsBadTrialsBeforeWritingAnything) {
  TempDir tmp;
  const std::string dir = tmp / "sweep";
  DatasetWriter w(dir, {});
  w.add_trial(cell(100, 0.1, 20e-6), ramp_series(10, 0.0));
  const std::string before = read_text(tmp.path / "sweep/sweep.csv");

  TrialSeries nan = ramp_series(10, 0.0);
  nan.x_m[4] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(w.add_trial(cell(100, 0.1, 20e-6), nan), InputError);
  TrialSeries backwards = ramp_series(10, 0.0);
  backwards.t_s[5] = backwards.t_s[6] = -0.00025;
  try {
    w.add_trial(cell(100, 0.1, 20e-6), backwards);
    ADD_FAILURE();
  } catch (const InputError& e) {
    EXPECT_EQ(std::string(e.what()),
              dir +
                  ": trial 'f100_d0.100_s20.00um_t1': t_s[6] = -0.00025 does not increase "
                  "(t_s[5] = -0.00025)");
  }
  EXPECT_THROW(w.add_trial(cell(100, 1.2, 20e-6), ramp_series(10, 0.0)), InputError);
  TrialInfo dup = cell(100, 0.1, 20e-6);
  dup.id = "f100_d0.100_s20.00um_t0";
  EXPECT_THROW(w.add_trial(dup, ramp_series(10, 0.0)), InputError);
  TrialInfo escape = cell(100, 0.1, 20e-6);
  escape.file = "../elsewhere.csv";
  EXPECT_THROW(w.add_trial(escape, ramp_series(10, 0.0)), InputError);
  TrialSeries ragged = ramp_series(10, 0.0);
  ragged.x_m.pop_back();
  EXPECT_THROW(w.add_trial(cell(100, 0.1, 20e-6), ragged), InputError);
  EXPECT_THROW(w.add_trial(cell(100, 0.1, 20e-6), TrialSeries{}), InputError);

  EXPECT_EQ(read_text(tmp.path / "sweep/sweep.csv"), before);
  EXPECT_FALSE(fs::exists(tmp.path / "sweep/trials/f100_d0.100_s20.00um_t1.csv"));
  EXPECT_FALSE(fs::exists(tmp.path / "elsewhere.csv"));
  EXPECT_EQ(read_dataset(dir).trials.size(), 1u);
  // A directory that already holds a sweep is not overwritten.
  EXPECT_THROW(DatasetWriter(dir, {}), InputError);
}

TEST(DatasetWriter, EveryStepLeavesAValidDatasetAndNoTemporaryFile) {
  TempDir tmp;
  const std::string dir = tmp / "sweep";
  DatasetWriter w(dir, {});
  EXPECT_EQ(read_dataset(dir).trials.size(), 0u);  // header only: a valid, empty sweep
  for (int k = 0; k < 4; ++k) {
    w.add_trial(cell(200, 0.25, 20e-6), ramp_series(100, 0.01 * k));
    EXPECT_EQ(read_dataset(dir).trials.size(), static_cast<std::size_t>(k + 1));
    EXPECT_TRUE(temporary_files(tmp.path).empty());
  }
  EXPECT_EQ(read_error(dir), "");
}

TEST(DatasetWriter, AKilledSweepLeavesTheFinishedTrials) {
  TempDir tmp;
  const std::string dir = tmp / "sweep";
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    DatasetWriter w(dir, {});
    for (int k = 0; k < 3; ++k) w.add_trial(cell(300, 0.35, 10e-6), ramp_series(500, 0.0));
    ::kill(::getpid(), SIGKILL);  // no destructor, no flush: as if the power went
    ::_exit(1);
  }
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFSIGNALED(status));
  const Dataset d = read_dataset(dir);
  ASSERT_EQ(d.trials.size(), 3u);
  EXPECT_EQ(read_trial(d, 2).x_m, ramp_series(500, 0.0).x_m);
}

TEST(DatasetWriter, AFailedSweepWriteLeavesTheOldSweepCsv) {
  TempDir tmp;
  const std::string dir = tmp / "sweep";
  DatasetWriter w(dir, {});
  for (int k = 0; k < 2; ++k) w.add_trial(cell(400, 0.15, 20e-6), ramp_series(20, 0.0));
  const fs::path sweep = tmp.path / "sweep/sweep.csv";
  const std::string before = read_text(sweep);

  // The temporary name cannot be created: sweep.csv must not change and the new trial's file goes.
  const fs::path blocker = tmp.path / "sweep/.sweep.csv.tmp";
  fs::create_directory(blocker);
  EXPECT_THROW(w.add_trial(cell(400, 0.15, 20e-6), ramp_series(20, 0.0)), std::system_error);
  EXPECT_EQ(read_text(sweep), before);
  EXPECT_FALSE(fs::exists(tmp.path / "sweep/trials/f400_d0.150_s20.00um_t2.csv"));
  EXPECT_EQ(w.dataset().trials.size(), 2u);
  fs::remove(blocker);

  // A trial file that cannot be written leaves sweep.csv alone too.
  const fs::path trial_blocker = tmp.path / "sweep/trials/.f400_d0.150_s20.00um_t2.csv.tmp";
  fs::create_directory(trial_blocker);
  EXPECT_THROW(w.add_trial(cell(400, 0.15, 20e-6), ramp_series(20, 0.0)), std::system_error);
  EXPECT_EQ(read_text(sweep), before);
  fs::remove(trial_blocker);

  // The disk fills up in the middle of writing sweep.csv (a file size limit: write fails with
  // EFBIG part way): the temporary file is removed and sweep.csv is as it was.
  ::signal(SIGXFSZ, SIG_IGN);
  rlimit old_limit{};
  ASSERT_EQ(::getrlimit(RLIMIT_FSIZE, &old_limit), 0);
  rlimit small = old_limit;
  small.rlim_cur = before.size() + 10;  // room for a short trial file, not for the new sweep.csv
  ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &small), 0);
  bool threw = false;
  try {
    w.add_trial(cell(400, 0.15, 20e-6), ramp_series(2, 0.0));
  } catch (const std::system_error& e) {
    threw = true;
    EXPECT_NE(std::string(e.what()).find("cannot write"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("sweep.csv"), std::string::npos) << e.what();
  }
  ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &old_limit), 0);
  ::signal(SIGXFSZ, SIG_DFL);
  EXPECT_TRUE(threw);
  EXPECT_EQ(read_text(sweep), before);
  EXPECT_TRUE(temporary_files(tmp.path).empty());
  EXPECT_EQ(read_dataset(dir).trials.size(), 2u);

  // Once the fault is gone the same writer carries on.
  w.add_trial(cell(400, 0.15, 20e-6), ramp_series(20, 0.0));
  const Dataset d = read_dataset(dir);
  ASSERT_EQ(d.trials.size(), 3u);
  EXPECT_EQ(d.trials[2].id, "f400_d0.150_s20.00um_t2");
  EXPECT_TRUE(temporary_files(tmp.path).empty());
}
