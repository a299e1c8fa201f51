// The daemon core: the Daemon (Instrument) on the simulated stage, with an allocation-counting
// hook showing that the loop thread allocates nothing during a full move (the configuration:
// test_daemon_config.cpp; the lock-free queues and the loop: test_rt_loop.cpp).
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <new>
#include <random>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

#include "control/calibration.h"
#include "control/positioner.h"
#include "daemon/config.h"
#include "daemon/daemon.h"
#include "daemon/protocol.h"
#include "daemon/rt_loop.h"
#include "drivers/lockfree.h"
#include "model/yaml_util.h"
#include "recording/dataset.h"
#include "tests/counting_new.h"  // counts allocations on the loop thread
#include "tests/daemon/daemon_test_util.h"

namespace {

using namespace idm::daemon;
using idm::model::InputError;
using namespace idm::daemon::test;

void count_on_this_thread(bool entering) {
  idm::test_alloc::t_counting = entering;
}

TEST(DeviceFaults, EveryFaultControlCanEnterHasACodeOfItsOwn) {
  // A fault missing from kDeviceFaults would reach a client as -200 with no code of its own.
  int faults = 0;
  for (int k = 1; k < 256; ++k) {
    const std::string name =
        idm::control::motion_fault_name(static_cast<idm::control::MotionFault>(k));
    if (name == "?") break;
    ++faults;
    const CommandError e = fault_error(name);
    EXPECT_GT(e.code, 100) << name;
    EXPECT_NE(e.text.find(name), std::string::npos) << e.text;
  }
  EXPECT_EQ(faults, static_cast<int>(std::size(kDeviceFaults)));
}

TEST(AllocationHook, CountsOnTheFlaggedThreadOnly) {
  idm::test_alloc::allocations = 0;
  count_on_this_thread(true);
  auto* v = new std::vector<int>(100);
  count_on_this_thread(false);
  delete v;
  std::thread([] { std::vector<int> w(100); }).join();
  EXPECT_EQ(idm::test_alloc::allocations.load(), 2);  // the vector object and its buffer
}

// ---- the daemon on the simulated stage ---------------------------------------------------------

class DaemonSim : public ::testing::Test {
 protected:
  std::unique_ptr<Daemon> make(const std::string& text) {
    return std::make_unique<Daemon>(parse_daemon_config(yaml(text), "t.yaml"));
  }
};

TEST_F(DaemonSim, LoopThreadAllocatesNothingDuringAFullMove) {
  auto d = make(sim_config(std::getenv("IDM_TEST_CLOCK") ? std::getenv("IDM_TEST_CLOCK") : "wall"));
  d->set_loop_thread_hook(&count_on_this_thread);
  idm::test_alloc::allocations = 0;
  d->start();
  ASSERT_TRUE(wait_for([&] { return d->status(0).position_valid; }, 10));
  const double start = d->status(0).position_m;
  ASSERT_TRUE(d->move_relative(0, 3e-6).ok());
  ASSERT_TRUE(wait_for([&] { return d->motion_done(); }, 60));
  const InstrumentStatus s = d->status(0);
  EXPECT_EQ(s.state, "IDLE") << s.fault;
  EXPECT_EQ(s.moves, 1u);
  EXPECT_GT(s.bursts, 0u);
  EXPECT_NEAR(s.position_m - start, 3e-6, 0.2e-6);
  EXPECT_TRUE(d->stop().ok());
  d->shutdown();
  EXPECT_GT(d->loop_stats().wakeups, 10u);
  // The hook counted on the loop thread only, from its first tick to its last.
  EXPECT_EQ(idm::test_alloc::allocations.load(), 0) << "the real-time loop allocated";
  EXPECT_EQ(idm::test_alloc::frees.load(), 0);
  EXPECT_DOUBLE_EQ(d->sim_output_m(), 0.0);
}

// The same on a Modbus device (idm-simdev on loopback), with a device lost and back on the way:
// the loop never calls a driver, whatever the backend, so it never allocates either.
TEST_F(DaemonSim, LoopThreadAllocatesNothingOnModbusEvenThroughALossAndReconnect) {
  int out[2];
  ASSERT_EQ(pipe(out), 0);
  const std::string simdev = std::string(IDM_BUILD_DIR) + "/tools/idm-simdev";
  const pid_t pid = fork();
  if (pid == 0) {
    dup2(out[1], 1);
    execl(simdev.c_str(), simdev.c_str(), "--port", "0", static_cast<char*>(nullptr));
    _exit(127);
  }
  close(out[1]);
  char buf[256] = {};
  ASSERT_GT(read(out[0], buf, sizeof buf - 1), 0);
  const std::string line = buf;
  const int port = std::atoi(line.substr(line.rfind(':') + 1).c_str());
  ASSERT_GT(port, 0) << line;
  const std::string text =
      "stage:\n  step_correction: 1.0\n  travel_m: [-5e-3, 5e-3]\n"
      "interferometer:\n  max_velocity_m_s: 1\n"
      "daq:\n  driver: modbus\n  modbus:\n    port: " +
      std::to_string(port) +
      "\n    timeout_s: 0.2\n"
      "control:\n  freq_step_hz: 50\n  stroke_count: 3\n  min_freq_hz: 20\n  max_chunk_s: 0.05\n"
      "realtime:\n  period_s: 1e-3\n  sched_fifo: false\n  lock_memory: false\n"
      "server:\n  unix_socket: \"\"\n";
  auto d = make(text);
  d->set_loop_thread_hook(&count_on_this_thread);
  idm::test_alloc::allocations = 0;
  idm::test_alloc::frees = 0;
  d->start();
  ASSERT_TRUE(d->move_relative(0, 20e-6).ok());
  ASSERT_TRUE(wait_for([&] { return d->motion_done(); }, 60));
  // The server stalls: the device is lost (the loop sees the events), then back.
  kill(pid, SIGSTOP);
  ASSERT_TRUE(wait_for([&] { return d->status(0).fault == "device_lost"; }, 10));
  kill(pid, SIGCONT);
  ASSERT_TRUE(
      wait_for([&] { return d->status(0).state == "IDLE" && d->status(0).position_valid; }, 10));
  ASSERT_TRUE(d->move_relative(0, -10e-6).ok());
  ASSERT_TRUE(wait_for([&] { return d->motion_done(); }, 60));
  d->shutdown();
  kill(pid, SIGTERM);
  waitpid(pid, nullptr, 0);
  EXPECT_GT(d->loop_stats().wakeups, 10u);
  EXPECT_EQ(idm::test_alloc::allocations.load(), 0) << "the real-time loop allocated";
  EXPECT_EQ(idm::test_alloc::frees.load(), 0);
}

TEST_F(DaemonSim, RefusalsBecomeProtocolErrors) {
  auto d = make(sim_config("wall", ""));
  d->start();
  ASSERT_TRUE(wait_for([&] { return d->status(0).position_valid; }, 10));
  EXPECT_EQ(d->move_absolute(0, std::nan("")).code, error_code::kNumericDataError);
  ASSERT_TRUE(d->set_soft_limits(0, -1e-3, 1e-3).ok());
  const CommandError e = d->move_absolute(0, 2e-3);
  EXPECT_EQ(e.code, error_code::kDataOutOfRange) << e.text;
  EXPECT_NE(e.text.find("soft limits"), std::string::npos);
  EXPECT_DOUBLE_EQ(d->status(0).soft_upper_m, 1e-3);
  EXPECT_EQ(d->set_soft_limits(0, 1, -1).code, error_code::kDataOutOfRange);
  EXPECT_EQ(d->step(0, 0, 0, 0, 0).code, error_code::kDataOutOfRange);
  std::string region;
  double step = 0;
  ASSERT_TRUE(d->region(0, 200, 0.1, std::nan(""), region, step).ok());
  EXPECT_FALSE(region.empty());
  EXPECT_EQ(d->identity().rfind("idm,idmd,", 0), 0u);
  d->shutdown();
}

TEST_F(DaemonSim, StepUsesEveryArgumentOrRefusesIt) {
  auto d = make(sim_config("wall"));
  d->start();
  ASSERT_TRUE(wait_for([&] { return d->status(0).position_valid; }, 10));
  const double nan = std::nan("");
  const auto refused = [&](std::int64_t n, double duty, double f, double s, const char* names) {
    const CommandError e = d->step(0, n, duty, f, s);
    EXPECT_EQ(e.code, error_code::kDataOutOfRange)
        << n << "," << duty << "," << f << "," << s << ": " << e.text;
    EXPECT_NE(e.text.find(names), std::string::npos) << e.text;
  };
  refused(10, 1.5, 200, nan, "STEP duty: 1.5");
  refused(10, -0.1, 200, 2e-5, "STEP duty: -0.1");
  refused(10, 0.1, -200, nan, "STEP freq_hz: -200");
  refused(10, 0.1, 200, -1e-6, "STEP stroke_m: -1e-6");
  refused(10, 0.1, 200, 0, "STEP stroke_m: 0");
  refused(1000000000, nan, nan, nan, "outside the soft limits");
  EXPECT_EQ(d->status(0).cycles, 0u);  // nothing was played
  // Given duty and frequency are the ones played: the slider moves the way REG? predicts.
  std::string region;
  double step_m = 0;
  ASSERT_TRUE(d->region(0, 200, 0.1, std::nan(""), region, step_m).ok());
  ASSERT_NE(region, "CUTOFF");
  const double start = d->status(0).position_m;
  ASSERT_TRUE(d->step(0, 10, 0.1, 200, nan).ok());
  ASSERT_TRUE(wait_for([&] { return d->motion_done(); }, 20));
  const InstrumentStatus s = d->status(0);
  EXPECT_EQ(s.state, "IDLE") << s.fault;
  EXPECT_EQ(s.cycles, 10u);
  const double moved = s.position_m - start;
  EXPECT_GT(moved * step_m, 0) << "moved " << moved << ", REG? step " << step_m;
  EXPECT_NEAR(moved, 10 * step_m, 0.3 * std::fabs(10 * step_m));
  d->shutdown();
}

TEST_F(DaemonSim, TheTravelBoundsMovesLimitsAndResetKeepsLimitsSetByClients) {
  const auto file = write_config("travel", sim_config("wall"));  // *RST re-reads it
  auto d = std::make_unique<Daemon>(load_daemon_config(file.string()));
  d->start();
  ASSERT_TRUE(wait_for([&] { return d->status(0).position_valid; }, 10));
  const InstrumentStatus s0 = d->status(0);
  EXPECT_DOUBLE_EQ(s0.soft_lower_m, -5e-3);  // the travel, by default
  EXPECT_DOUBLE_EQ(s0.soft_upper_m, 5e-3);
  EXPECT_NEAR(s0.target_m, s0.position_m, 1e-12);  // before any move: the target is the position
  // A unit typo (1 km) is refused before anything moves, naming the target it would reach.
  CommandError e = d->move_relative(0, 1e3);
  EXPECT_EQ(e.code, error_code::kDataOutOfRange);
  EXPECT_NE(e.text.find("target 1000"), std::string::npos) << e.text;
  EXPECT_EQ(d->move_absolute(0, -1e3).code, error_code::kDataOutOfRange);
  e = d->move_relative(0, 4e-3 - s0.position_m + 2e-3);  // ends at 6 mm
  EXPECT_NE(e.text.find("target 0.006"), std::string::npos) << e.text;
  EXPECT_EQ(d->status(0).bursts, 0u);
  e = d->set_soft_limits(0, -1e-3, 1e3);
  EXPECT_EQ(e.code, error_code::kDataOutOfRange);
  EXPECT_NE(e.text.find("upper limit 1000 m lies outside the stage's travel"), std::string::npos)
      << e.text;
  e = d->set_soft_limits(0, 1e-6, 1e-6);
  EXPECT_EQ(e.code, error_code::kDataOutOfRange);
  EXPECT_NE(e.text.find("must be below the upper limit"), std::string::npos) << e.text;
  // Limits set by a client survive another client's *RST, and so does the target.
  ASSERT_TRUE(d->set_soft_limits(0, -1e-3, 2e-3).ok());
  ASSERT_TRUE(d->move_relative(0, 2e-6).ok());
  ASSERT_TRUE(wait_for([&] { return d->motion_done(); }, 20));
  const double target = d->status(0).target_m;
  ASSERT_TRUE(d->reset().ok());
  const InstrumentStatus s1 = d->status(0);
  EXPECT_DOUBLE_EQ(s1.soft_lower_m, -1e-3);
  EXPECT_DOUBLE_EQ(s1.soft_upper_m, 2e-3);
  EXPECT_DOUBLE_EQ(s1.target_m, target);
  EXPECT_EQ(s1.moves, 1u);
  d->shutdown();
  std::filesystem::remove(file);
}

TEST_F(DaemonSim, SweepsStayInsideTheDataDirectoryAndNeverOverwrite) {
  namespace fs = std::filesystem;
  const fs::path root = fs::temp_directory_path() / ("idmd-confine-" + std::to_string(::getpid()));
  fs::remove_all(root);
  const fs::path data = root / "data", outside = root / "outside";
  fs::create_directories(data);
  fs::create_directories(outside);
  { std::ofstream(outside / "precious.txt") << "keep me\n"; }
  fs::create_symlink(outside, data / "link");
  fs::create_directories(data / "old");
  { std::ofstream(data / "old" / "sweep.csv") << "trial\n"; }
  std::string text = sim_config("wall");
  text.replace(text.find("recording:\n  data_dir: "), std::string::npos,
               "recording:\n  data_dir: " + data.string() + "\n");
  auto d = make(text);
  d->start();
  ASSERT_TRUE(wait_for([&] { return d->status(0).position_valid; }, 10));
  for (const std::string& dir :
       {std::string("../outside/x"), outside.string() + "/x", std::string("link/x"),
        std::string("link"), std::string("old"), std::string("a/../../outside"), std::string("./x"),
        std::string("a//b")}) {
    const CommandError e = d->sweep(0, dir, {500}, {0.1}, 1, 2);
    EXPECT_EQ(e.code, error_code::kDataOutOfRange) << dir << ": " << e.text;
  }
  EXPECT_TRUE(d->motion_done());
  EXPECT_EQ(std::distance(fs::directory_iterator(outside), fs::directory_iterator{}), 1);
  EXPECT_EQ(fs::file_size(outside / "precious.txt"), 8u);
  EXPECT_EQ(fs::file_size(data / "old" / "sweep.csv"), 6u);
  // A new name, with new parents, is fine; the same name again is refused.
  ASSERT_TRUE(d->sweep(0, "2026/run1", {500}, {0.1}, 1, 2).ok());
  ASSERT_TRUE(wait_for([&] { return d->motion_done(); }, 30));
  EXPECT_TRUE(fs::exists(data / "2026" / "run1" / "sweep.csv"));
  EXPECT_EQ(d->sweep(0, "2026/run1", {500}, {0.1}, 1, 2).code, error_code::kDataOutOfRange);
  d->shutdown();
  fs::remove_all(root);
}

TEST_F(DaemonSim, StopMidMoveBringsTheOutputToRest) {
  auto d = make(sim_config("wall"));
  d->start();
  ASSERT_TRUE(wait_for([&] { return d->status(0).position_valid; }, 10));
  ASSERT_TRUE(d->move_relative(0, -200e-6).ok());
  ASSERT_TRUE(wait_for([&] { return d->status(0).bursts > 0; }, 10));
  EXPECT_FALSE(d->motion_done());
  ASSERT_TRUE(d->stop().ok());
  ASSERT_TRUE(wait_for([&] { return d->motion_done(); }, 5));
  EXPECT_EQ(d->status(0).state, "IDLE");
  d->shutdown();
  EXPECT_DOUBLE_EQ(d->sim_output_m(), 0.0);
}

TEST_F(DaemonSim, ShutdownMidMoveEndsAtRestWithZeroOutput) {
  auto d = make(sim_config("wall"));
  d->start();
  ASSERT_TRUE(wait_for([&] { return d->status(0).position_valid; }, 10));
  ASSERT_TRUE(d->move_relative(0, 200e-6).ok());
  ASSERT_TRUE(wait_for([&] { return d->status(0).bursts > 0; }, 10));
  d->shutdown();
  EXPECT_FALSE(d->loop_running());
  EXPECT_DOUBLE_EQ(d->sim_output_m(), 0.0);
  EXPECT_EQ(d->link_of(0).device(0).output->state(), idm::drivers::LifecycleState::Finalized);
}

TEST_F(DaemonSim, SweepWritesADatasetFromTheLoopsSamples) {
  const std::string name = "idmd-sweep-" + std::to_string(::getpid());
  const auto dir = std::filesystem::temp_directory_path() / "idmd-test-data" / name;
  std::filesystem::create_directories(dir.parent_path());
  std::filesystem::remove_all(dir);
  auto d = make(sim_config("wall"));
  d->start();
  ASSERT_TRUE(wait_for([&] { return d->status(0).position_valid; }, 10));
  const CommandError e = d->sweep(0, name, {500, 1000}, {0.1, 0.9}, 2, 3);
  ASSERT_TRUE(e.ok()) << e.text;
  EXPECT_FALSE(d->motion_done());
  EXPECT_EQ(d->sweep(0, name + "-b", {500}, {0.1}, 1, 1).code, error_code::kSettingsConflict);
  ASSERT_TRUE(wait_for([&] { return d->motion_done(); }, 60));
  d->shutdown();
  EXPECT_NE(d->last_sweep_report().find("8 trials written, 0 failed"), std::string::npos)
      << d->last_sweep_report();
  const idm::recording::Dataset ds = idm::recording::read_dataset(dir.string());
  ASSERT_EQ(ds.trials.size(), 8u);
  // The recorder's mark: the whole plan played, by axis x, every planned cell full.
  EXPECT_EQ(ds.progress.status, idm::recording::SweepStatus::Complete);
  EXPECT_EQ(ds.progress.axis, "x");
  ASSERT_EQ(ds.progress.planned.size(), 4u);
  for (const auto& c : ds.progress.planned) {
    EXPECT_EQ(c.trials, 2);
    EXPECT_DOUBLE_EQ(c.stroke_m, 20.35e-6);
  }
  EXPECT_TRUE(ds.progress.missing.empty());
  for (std::size_t i = 0; i < ds.trials.size(); ++i) {
    const auto series = idm::recording::read_trial(ds, i);
    EXPECT_EQ(ds.trials[i].cycles, 3);
    EXPECT_DOUBLE_EQ(ds.trials[i].sample_rate_hz, 1e5);
    ASSERT_GT(series.size(), 100u);
    EXPECT_LT(series.t_s.front(), 0.0);  // rest before the first cycle
    double xi_max = 0;
    for (double xi : series.xi_cmd_m) xi_max = std::max(xi_max, xi);
    EXPECT_NEAR(xi_max, 20.35e-6, 1e-9);
    // The slider moved in the direction of the duty (< 0.5: negative).
    const double moved = series.x_m.back() - series.x_m.front();
    EXPECT_EQ(moved > 0, ds.trials[i].duty > 0.5) << ds.trials[i].id << " moved " << moved;
  }
  std::filesystem::remove_all(dir);
}

TEST_F(DaemonSim, SweepArgumentsCheckedAtOnce) {
  auto d = make(sim_config("wall"));
  d->start();
  EXPECT_EQ(d->sweep(0, "", {100}, {0.1}, 1, 1).code, error_code::kMissingParameter);
  EXPECT_EQ(d->sweep(0, "x", {1e6}, {0.1}, 1, 1).code, error_code::kDataOutOfRange);
  EXPECT_EQ(d->sweep(0, "x", {100}, {1.5}, 1, 1).code, error_code::kDataOutOfRange);
  EXPECT_EQ(d->sweep(0, "x", {100}, {0.1}, 0, 1).code, error_code::kDataOutOfRange);
  d->shutdown();
}

TEST_F(DaemonSim, MissingDeviceIsANoHardwareStartError) {
  const std::string text =
      "stage:\n  travel_m: [-1e-3, 1e-3]\n"
      "daq:\n  driver: modbus\n  modbus:\n    host: 127.0.0.1\n    port: 1\n    timeout_s: 0.2\n"
      "realtime:\n  sched_fifo: false\n  lock_memory: false\n";
  Daemon daemon(parse_daemon_config(yaml(text), "t.yaml"));
  try {
    daemon.start();
    ADD_FAILURE() << "started without a device";
  } catch (const StartError& e) {
    EXPECT_EQ(e.exit_code(), exit_code::kNoHardware);
    EXPECT_NE(std::string(e.what()).find("modbus"), std::string::npos) << e.what();
  }
}

TEST_F(DaemonSim, ReloadAppliesNewControlSettings) {
  const auto file = std::filesystem::temp_directory_path() /
                    ("idmd-reload-" + std::to_string(::getpid()) + ".yaml");
  {
    std::FILE* f = std::fopen(file.c_str(), "w");
    const std::string text = sim_config("wall");
    std::fwrite(text.data(), 1, text.size(), f);
    std::fclose(f);
  }
  Daemon d(load_daemon_config(file.string()));
  d.start();
  // A move is judged against the limits only once there is a position to move from.
  ASSERT_TRUE(wait_for([&] { return d.status(0).position_valid; }, 10));
  {
    std::FILE* f = std::fopen(file.c_str(), "w");
    std::string changed = sim_config("wall");
    changed.replace(changed.find("control:\n"), 9, "control:\n  soft_upper_m: 5e-4\n");
    std::fwrite(changed.data(), 1, changed.size(), f);
    std::fclose(f);
  }
  std::string error;
  ASSERT_TRUE(d.reload_control(error)) << error;
  // The positioner has the new limits when reload_control returns; the status shows them from
  // the loop's next publication on.
  EXPECT_EQ(d.move_absolute(0, 1e-3).code, error_code::kDataOutOfRange);
  EXPECT_TRUE(wait_for([&] { return d.status(0).soft_upper_m == 5e-4; }, 10))
      << d.status(0).soft_upper_m;
  {
    std::FILE* f = std::fopen(file.c_str(), "w");
    const std::string bad = "control:\n  max_retries: oops\n";
    std::fwrite(bad.data(), 1, bad.size(), f);
    std::fclose(f);
  }
  EXPECT_FALSE(d.reload_control(error));
  EXPECT_NE(error.find("control.max_retries"), std::string::npos) << error;
  EXPECT_DOUBLE_EQ(d.status(0).soft_upper_m, 5e-4);  // the old settings stay
  d.shutdown();
  std::filesystem::remove(file);
}

// sim_config() with control.calibration_file set.
std::string with_calibration_file(const std::string& path) {
  std::string text = sim_config("wall");
  text.replace(text.find("control:\n"), 9, "control:\n  calibration_file: " + path + "\n");
  return text;
}

TEST_F(DaemonSim, CalibrationIsSavedAfterTheMoveThatChangedIt) {
  const auto cal =
      std::filesystem::temp_directory_path() / ("idmd-cal-" + std::to_string(::getpid()) + ".txt");
  std::filesystem::remove(cal);
  auto d = make(with_calibration_file(cal.string()));
  d->start();
  ASSERT_TRUE(wait_for([&] { return d->status(0).position_valid; }, 10));
  ASSERT_TRUE(d->move_relative(0, 5e-6).ok());
  ASSERT_TRUE(wait_for([&] { return d->motion_done(); }, 60));
  // Saved by the housekeeping thread while the daemon runs, not only at shutdown.
  ASSERT_TRUE(wait_for([&] { return std::filesystem::exists(cal); }, 10))
      << "no calibration file after a move";
  idm::control::Calibration loaded(d->config().axes[0].stage.stage,
                                   d->config().axes[0].control.calibration);
  std::string error;
  ASSERT_TRUE(loaded.load(cal.string(), error)) << error;
  EXPECT_GT(loaded.total_updates(), 0u);
  EXPECT_TRUE(d->take_notes().empty());
  EXPECT_EQ(d->status(0).last_error, "");
  d->shutdown();
  std::filesystem::remove(cal);
}

TEST_F(DaemonSim, AFailedCalibrationSaveIsLoggedOnceWithTheFileAndReason) {
  const std::string cal = "/nonexistent-idmd-dir/cal.txt";
  auto d = make(with_calibration_file(cal));
  d->start();
  ASSERT_TRUE(wait_for([&] { return d->status(0).position_valid; }, 10));
  std::vector<std::string> notes;
  for (double step : {5e-6, -5e-6}) {
    ASSERT_TRUE(d->move_relative(0, step).ok());
    ASSERT_TRUE(wait_for([&] { return d->motion_done(); }, 60));
    ASSERT_TRUE(wait_for(
        [&] {
          for (auto& n : d->take_notes()) notes.push_back(n.text);
          return !notes.empty();
        },
        10));
  }
  d->shutdown();
  for (auto& n : d->take_notes()) notes.push_back(n.text);
  ASSERT_EQ(notes.size(), 1u) << "the same failure is logged once";
  EXPECT_NE(notes[0].find(cal), std::string::npos) << notes[0];
  EXPECT_NE(notes[0].find("cannot save the calibration"), std::string::npos) << notes[0];
}

TEST_F(DaemonSim, StatusCarriesTheLastFailedSaveUntilReset) {
  const auto file = write_config("lasterr", with_calibration_file("/nonexistent-idmd-dir/cal.txt"));
  Daemon d(load_daemon_config(file.string()));
  d.start();
  ASSERT_TRUE(wait_for([&] { return d.status(0).position_valid; }, 10));
  EXPECT_EQ(d.status(0).last_error, "");
  ASSERT_TRUE(d.move_relative(0, 5e-6).ok());
  ASSERT_TRUE(wait_for([&] { return !d.status(0).last_error.empty(); }, 60));
  EXPECT_NE(d.status(0).last_error.find("/nonexistent-idmd-dir/cal.txt"), std::string::npos)
      << d.status(0).last_error;
  const CommandError e = d.reset();
  ASSERT_TRUE(e.ok()) << e.text;
  EXPECT_EQ(d.status(0).last_error, "");
  d.shutdown();
  std::filesystem::remove(file);
}

TEST_F(DaemonSim, ResetDuringASweepLetsTheSweepWindDownInTheBackground) {
  const std::string name = "idmd-rst-sweep-" + std::to_string(::getpid());
  const auto dir = std::filesystem::temp_directory_path() / "idmd-test-data" / name;
  std::filesystem::remove_all(dir);
  const auto file = write_config("rst", sim_config("wall"));
  Daemon d(load_daemon_config(file.string()));
  d.start();
  ASSERT_TRUE(wait_for([&] { return d.status(0).position_valid; }, 10));
  ASSERT_TRUE(d.sweep(0, name, {500, 1000}, {0.1, 0.9}, 200, 3).ok());
  ASSERT_TRUE(wait_for([&] { return std::filesystem::exists(dir / "sweep.csv"); }, 30));
  const CommandError e = d.reset();
  ASSERT_TRUE(e.ok()) << e.text;
  // *OPC? semantics: not done until the sweep has ended and the settings are reloaded.
  ASSERT_TRUE(wait_for([&] { return d.motion_done(); }, 60));
  EXPECT_NE(d.last_sweep_report().find("stopped"), std::string::npos) << d.last_sweep_report();
  EXPECT_EQ(d.status(0).last_error, "");
  EXPECT_EQ(d.sweep_status().state, "STOPPED");
  for (const auto& note : d.take_notes()) EXPECT_FALSE(note.warning) << note.text;
  // The dataset says it was stopped, why, and which planned cells are short.
  const idm::recording::Dataset ds = idm::recording::read_dataset(dir.string());
  EXPECT_EQ(ds.progress.status, idm::recording::SweepStatus::Stopped);
  EXPECT_TRUE(ds.progress.interrupted());
  EXPECT_NE(ds.progress.note.find("stopped by a client"), std::string::npos) << ds.progress.note;
  EXPECT_EQ(ds.progress.axis, "x");
  EXPECT_EQ(ds.progress.planned.size(), 4u);
  EXPECT_FALSE(ds.progress.missing.empty());
  // The daemon moves again after the reset.
  const CommandError m = d.move_relative(0, 2e-6);
  EXPECT_TRUE(m.ok()) << m.text;
  ASSERT_TRUE(wait_for([&] { return d.motion_done(); }, 60));
  EXPECT_EQ(d.status(0).state, "IDLE");
  d.shutdown();
  std::filesystem::remove(file);
  std::filesystem::remove_all(dir);
}

// A setting a command changes (MOVE:WINDow, MOVE:DWELl, EOT:STEP, EOT:CYCLes, HOLD, HOLD:WINDow,
// MOVE:VELocity) is accepted exactly when the config file's reader accepts the axis's settings
// as they stand with that value in them: the key's own range and every relation between keys (a
// window of at least one count, a hold window no smaller than the move window, an end-of-travel
// step above one count per cycle). A refusal shows what the file's reader shows ("allowed ...").
// One mixed sequence of settings drawn at random, around and across each range's ends and around
// one count, so a value can break a relation with one set earlier.
TEST_F(DaemonSim, EverySettingACommandChangesIsCheckedByTheConfigsOwnRangeAndRelations) {
  const std::string text = sim_config("wall", "");
  auto d = make(text);
  d->start();
  ASSERT_TRUE(wait_for([&] { return d->status(0).position_valid; }, 10));
  const struct {
    MotionSetting which;
    const char* key;
  } kSettings[] = {
      {MotionSetting::Window, "tolerance_m"},    {MotionSetting::Dwell, "dwell_s"},
      {MotionSetting::EotStep, "eot_step_m"},    {MotionSetting::EotCycles, "eot_cycles"},
      {MotionSetting::Hold, "hold_s"},           {MotionSetting::HoldWindow, "hold_window_m"},
      {MotionSetting::MaxSpeed, "max_speed_m_s"}};
  // The oracle: the whole config file with the settings set so far and the new value in control:
  // "" when it loads, else the reader's message.
  std::vector<std::pair<std::string, double>> set_so_far;
  const auto file_error = [&](const std::string& key, double v) -> std::string {
    YAML::Node root = YAML::Load(text);
    for (const auto& [k, x] : set_so_far) root["control"][k] = idm::model::format_number(x, 17);
    root["control"][key] = idm::model::format_number(v, 17);
    try {
      (void)parse_daemon_config(YAML::Load(YAML::Dump(root)), "t.yaml");
    } catch (const InputError& e) {
      return e.what();
    }
    return {};
  };
  // The scale of each key's values, from what the file reader takes alone.
  std::vector<double> scale;
  for (const auto& s : kSettings) {
    double top = 0;
    for (double probe = 1e-9; probe <= 1e6; probe *= 10)
      if (file_error(s.key, probe).empty()) top = probe;
    ASSERT_GT(top, 0) << s.key;
    scale.push_back(top);
  }
  std::mt19937_64 rng(31);
  std::vector<int> accepted(std::size(kSettings)), refused(std::size(kSettings));
  int relation_refusals = 0;
  for (int k = 0; k < 900; ++k) {
    const std::size_t i = rng() % std::size(kSettings);
    const auto& s = kSettings[i];
    double v = std::uniform_real_distribution<double>(-1.5, 1.5)(rng) * scale[i];
    switch (rng() % 6) {
      case 0:
        v = std::round(v);
        break;
      case 1:
        v = rng() % 3 == 0 ? -1 : 0;
        break;
      case 2:
        v = std::nextafter(scale[i] * (rng() % 2 ? 1 : 0), rng() % 2 ? 1e300 : -1e300);
        break;
      case 3:  // log-uniform down to a fraction of a count (lambda/64 is ~1e-8 m)
        v = std::pow(10.0, std::uniform_real_distribution<double>(-10, std::log10(scale[i]))(rng));
        break;
      default:
        break;
    }
    const std::string why = file_error(s.key, v);
    const bool file_takes = why.empty();
    const CommandError e = d->set_motion_setting(0, s.which, v);
    ASSERT_EQ(e.ok(), file_takes) << s.key << " = " << v << ": protocol: " << e.text
                                  << "; file: " << why;
    if (e.ok()) {
      ++accepted[i];
      set_so_far.emplace_back(s.key, v);
      // 0 reads back as what it stands for (one count, the move window).
      const bool stands_for_another =
          v == 0 && (s.which == MotionSetting::Window || s.which == MotionSetting::HoldWindow);
      if (!stands_for_another) {
        EXPECT_EQ(d->motion_setting(0, s.which), v) << s.key;
      }
    } else {
      ++refused[i];
      EXPECT_EQ(e.code, error_code::kDataOutOfRange) << e.text;
      // The file's words past the key (its own refusal of a non-integer quotes the text).
      const std::size_t at = why.find("allowed ");
      const std::string said = at != std::string::npos ? why.substr(at) : "is not an integer";
      EXPECT_NE(e.text.find(said), std::string::npos)
          << "protocol: " << e.text << "\nfile:     " << why;
      relation_refusals += why.find("(") != std::string::npos ? 1 : 0;
    }
  }
  for (std::size_t i = 0; i < std::size(kSettings); ++i) {
    EXPECT_GT(accepted[i], 5) << kSettings[i].key;
    EXPECT_GT(refused[i], 5) << kSettings[i].key;
  }
  EXPECT_GT(relation_refusals, 5);
  d->shutdown();
}

}  // namespace

namespace {

// The names of this process's threads (/proc/self/task/*/comm).
std::vector<std::string> thread_names() {
  std::vector<std::string> out;
  for (const auto& t : std::filesystem::directory_iterator("/proc/self/task")) {
    std::ifstream f(t.path() / "comm");
    std::string name;
    std::getline(f, name);
    out.push_back(name);
  }
  return out;
}

// Every thread the daemon starts is named for its job (top -H, ps -L, gdb): the loop, the
// server, housekeeping, the recorder and each device's I/O thread.
TEST_F(DaemonSim, EveryThreadItStartsIsNamedForItsJob) {
  const std::vector<std::string> before = thread_names();
  auto d = make(sim_config("wall", ""));
  d->start();
  ASSERT_TRUE(wait_for([&] { return d->status(0).position_valid; }, 10));
  std::vector<std::string> started = thread_names();
  for (const std::string& b : before) {
    const auto it = std::find(started.begin(), started.end(), b);
    if (it != started.end()) started.erase(it);
  }
  d->shutdown();
  ASSERT_FALSE(started.empty());
  for (const char* job : {"idmd-rt", "idmd-house", "idmd-sweep"})
    EXPECT_NE(std::find(started.begin(), started.end(), job), started.end()) << job;
  EXPECT_TRUE(std::any_of(started.begin(), started.end(),
                          [](const std::string& n) { return n.rfind("idmd-io-", 0) == 0; }));
  // ThreadSanitizer's runtime starts a background thread of its own (named as the process) when
  // the first thread is created: not the daemon's.
#if defined(__SANITIZE_THREAD__)
  std::string process;
  std::getline(std::ifstream("/proc/self/comm"), process);
  const auto runtime = std::find(started.begin(), started.end(), process);
  if (runtime != started.end()) started.erase(runtime);
#endif
  for (const std::string& n : started) EXPECT_EQ(n.rfind("idmd-", 0), 0u) << n;
}

}  // namespace

// The log's line about a motion speaks the clients' frame: positions plus the user offset, which
// it names; a distance is the same in both frames.
TEST(MotionNoteText, GivesPositionsInTheUserFrameAndNamesTheOffset) {
  MotionNote n;
  n.kind = MotionNote::Kind::Ended;
  n.result = idm::control::MoveResult::Limit;
  n.motion = idm::control::MotionKind::Move;
  n.position_valid = true;
  n.position_m = 1e-3;
  n.target_m = 2e-3;
  n.distance_m = 1e-3;
  EXPECT_EQ(motion_note_text("x", n),
            "axis x: MOVE ended LIMIT: position 0.001 m, target 0.002 m, distance 0.001 m");
  n.user_offset_m = -5e-4;
  EXPECT_EQ(motion_note_text("x", n),
            "axis x: MOVE ended LIMIT: position 0.0005 m, target 0.0015 m, distance 0.001 m, user "
            "offset -0.0005 m");
}
