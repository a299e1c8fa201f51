// The recorder's mark (recording/sweep_plan.h): a sweep with a plan says in_progress until it is
// finished, so a sweep cut off by SIGKILL reads back as interrupted with its missing cells; a
// dataset without the mark (another lab's) reads exactly as before.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <sstream>

#include "recording/dataset.h"

using namespace idm::recording;
namespace fs = std::filesystem;

namespace {

const std::string kSample = IDM_SAMPLE_SWEEP_DIR;  // tests/data/README.md

struct TempDir {
  fs::path path;
  TempDir() {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    path = fs::temp_directory_path() /
           ("idm_test_plan_" + std::string(info->name()) + "_" + std::to_string(::getpid()));
    fs::remove_all(path);
    fs::create_directories(path);
  }
  ~TempDir() {
    std::error_code ignored;
    fs::remove_all(path, ignored);
  }
  std::string operator/(const std::string& name) const { return (path / name).string(); }
};

std::string read_text(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

void write_text(const fs::path& path, const std::string& text) {
  std::ofstream(path, std::ios::binary) << text;
}

TrialSeries short_series() {
  TrialSeries s;
  for (int i = 0; i < 50; ++i) {
    s.t_s.push_back(-5e-4 + 5e-5 * i);
    s.xi_cmd_m.push_back(0.0);
    s.x_m.push_back(0.01 + 1e-9 * i);
  }
  return s;
}

TrialInfo trial(const PlannedCell& c) {
  TrialInfo t;
  t.freq_hz = c.freq_hz;
  t.duty = c.duty;
  t.stroke_m = c.stroke_m;
  t.cycles = 12;
  t.sample_rate_hz = 20000;
  t.guide_pos_m = 0.01;
  return t;
}

// 2 frequencies x 2 duties, 3 trials each (the duties as a sample clock snaps them).
std::vector<PlannedCell> grid() {
  std::vector<PlannedCell> g;
  for (double f : {100.0, 437.5})
    for (double d : {0.05, 0.8125}) g.push_back({f, d, 20.35e-6, 3});
  return g;
}

}  // namespace

TEST(SweepPlan, AMarkedSweepIsInProgressUntilFinished) {
  TempDir tmp;
  const std::string dir = tmp / "sweep";
  DatasetWriter w(dir, {}, grid());
  Dataset d = read_dataset(dir);
  EXPECT_EQ(d.progress.status, SweepStatus::InProgress);
  EXPECT_TRUE(d.progress.interrupted());
  ASSERT_EQ(d.progress.missing.size(), 4u);
  EXPECT_EQ(d.progress.missing[0].recorded, 0);

  for (const PlannedCell& c : grid())
    for (int k = 0; k < c.trials; ++k) w.add_trial(trial(c), short_series());
  d = read_dataset(dir);
  EXPECT_EQ(d.progress.status, SweepStatus::InProgress);  // every trial there, but not finished
  EXPECT_TRUE(d.progress.missing.empty());

  w.finish();
  d = read_dataset(dir);
  EXPECT_EQ(d.progress.status, SweepStatus::Complete);
  EXPECT_FALSE(d.progress.interrupted());
  EXPECT_EQ(d.progress.planned.size(), 4u);
  EXPECT_EQ(d.progress.planned[3].duty, 0.8125);  // exact round trip
  EXPECT_EQ(d.trials.size(), 12u);
  EXPECT_THROW(w.add_trial(trial(grid()[0]), short_series()), std::logic_error);
  EXPECT_THROW(w.finish(), std::logic_error);
}

TEST(SweepPlan, ASweepKilledMidwayReadsBackAsInterruptedWithItsMissingCells) {
  TempDir tmp;
  const std::string dir = tmp / "sweep";
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    DatasetWriter w(dir, {}, grid());
    // the first cell whole, one trial of the second, then the power goes
    for (int k = 0; k < 3; ++k) w.add_trial(trial(grid()[0]), short_series());
    w.add_trial(trial(grid()[1]), short_series());
    ::kill(::getpid(), SIGKILL);
    ::_exit(1);
  }
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFSIGNALED(status));
  const Dataset d = read_dataset(dir);
  EXPECT_EQ(d.trials.size(), 4u);
  EXPECT_EQ(d.progress.status, SweepStatus::InProgress);
  EXPECT_TRUE(d.progress.interrupted());
  ASSERT_EQ(d.progress.missing.size(), 3u);
  EXPECT_EQ(d.progress.missing[0].planned.duty, 0.8125);
  EXPECT_EQ(d.progress.missing[0].recorded, 1);
  EXPECT_EQ(d.progress.missing[1].planned.freq_hz, 437.5);
  EXPECT_EQ(d.progress.missing[1].recorded, 0);
  EXPECT_EQ(d.progress.missing[2].recorded, 0);
  for (std::size_t i = 0; i < d.trials.size(); ++i) EXPECT_NO_THROW(read_trial(d, i));
}

TEST(SweepPlan, AStoppedSweepSaysWhyAndACompleteOneListsFailedTrials) {
  TempDir tmp;
  {
    DatasetWriter w(tmp / "stopped", {}, grid());
    w.add_trial(trial(grid()[0]), short_series());
    w.finish(SweepStatus::Stopped, "STOP from a client \"bench\"\nat trial 2");
  }
  Dataset d = read_dataset(tmp / "stopped");
  EXPECT_EQ(d.progress.status, SweepStatus::Stopped);
  EXPECT_TRUE(d.progress.interrupted());
  EXPECT_EQ(d.progress.note, "STOP from a client \"bench\" at trial 2");
  EXPECT_EQ(d.progress.missing.size(), 4u);

  {
    DatasetWriter w(tmp / "complete", {}, grid());
    for (const PlannedCell& c : grid())
      for (int k = 0; k < c.trials - (c.freq_hz == 100 ? 1 : 0); ++k)
        w.add_trial(trial(c), short_series());
    w.finish(SweepStatus::Complete);
  }
  d = read_dataset(tmp / "complete");
  EXPECT_FALSE(d.progress.interrupted());
  ASSERT_EQ(d.progress.missing.size(), 2u);  // the recorder went through the plan; 2 trials failed
  EXPECT_EQ(d.progress.missing[0].recorded, 2);
  EXPECT_THROW(DatasetWriter(tmp / "x", {}, grid()).finish(SweepStatus::InProgress),
               std::invalid_argument);
}

TEST(SweepPlan, ADatasetWithoutTheMarkReadsAsBefore) {
  const Dataset d = read_dataset(kSample);
  EXPECT_EQ(d.progress.status, SweepStatus::Unmarked);
  EXPECT_FALSE(d.progress.interrupted());
  EXPECT_FALSE(d.progress.marked());
  EXPECT_TRUE(d.progress.planned.empty());
  EXPECT_TRUE(d.progress.missing.empty());
  EXPECT_EQ(d.trials.size(), 480u);

  // The writer without a plan leaves no mark; finish() changes nothing on disk.
  TempDir tmp;
  DatasetWriter w(tmp / "plain", {});
  w.add_trial(trial(grid()[0]), short_series());
  w.finish();
  EXPECT_FALSE(fs::exists(tmp.path / "plain" / kPlanFile));
  EXPECT_EQ(read_dataset(tmp / "plain").progress.status, SweepStatus::Unmarked);
}

TEST(SweepPlan, TheWriterRefusesABadPlanAndTrialsOutsideIt) {
  TempDir tmp;
  std::vector<PlannedCell> bad = grid();
  bad[2].duty = 1.2;
  try {
    DatasetWriter w(tmp / "bad", {}, bad);
    ADD_FAILURE() << "no error";
  } catch (const InputError& e) {
    EXPECT_NE(
        std::string(e.what()).find("planned cell 3 duty: 1.2 is out of range, allowed (0, 1)"),
        std::string::npos)
        << e.what();
  }
  EXPECT_FALSE(fs::exists(tmp.path / "bad"));  // nothing written
  bad = grid();
  bad[3] = bad[1];
  EXPECT_THROW(DatasetWriter(tmp / "twice", {}, bad), InputError);

  DatasetWriter w(tmp / "sweep", {}, grid());
  PlannedCell unplanned = grid()[1];
  unplanned.duty = 0.8;  // asked for 0.8, the clock played 0.8125
  try {
    w.add_trial(trial(unplanned), short_series());
    ADD_FAILURE() << "no error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("is not a planned cell"), std::string::npos) << e.what();
  }
  EXPECT_TRUE(w.dataset().trials.empty());
}

TEST(SweepPlan, ABadMarkNamesFileLineAndKey) {
  TempDir tmp;
  const std::string dir = tmp / "sweep";
  { DatasetWriter w(dir, {}, grid()); }
  const fs::path plan = fs::path(dir) / kPlanFile;
  const std::string good = read_text(plan);
  struct Case {
    std::string from, to, expect;
  } cases[] = {
      {"status: in_progress", "status: halfway", "plan.yaml:3: status: 'halfway' is not allowed"},
      {"status: in_progress", "state: in_progress", "plan.yaml: status: missing"},
      {"duty: 0.8125", "duty: 1.5",
       "plan.yaml:6: cells[1].duty: 1.5 is out of range, allowed (0, 1)"},
      {"trials: 3}\n", "trials: 0}\n", "plan.yaml:5: cells[0].trials: 0 is out of range"},
      {", stroke_m: 2.035e-05, trials: 3}\n  - {freq_hz: 437.5",
       ", trials: 3}\n  - {freq_hz: 437.5", "plan.yaml:6: cells[1].stroke_m: missing"},
      {"freq_hz: 437.5, duty: 0.05", "freq_hz: 100, duty: 0.05", "repeats cells[0]"},
  };
  for (const Case& c : cases) {
    std::string text = good;
    const std::size_t at = text.find(c.from);
    ASSERT_NE(at, std::string::npos) << c.from << "\n" << good;
    text.replace(at, c.from.size(), c.to);
    write_text(plan, text);
    try {
      read_dataset(dir);
      ADD_FAILURE() << "no error for " << c.to;
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find(c.expect), std::string::npos) << e.what();
    }
  }
}
