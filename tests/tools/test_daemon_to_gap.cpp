// End to end: idmd's core (the Daemon that idmd runs) on the simulated backend with a hidden
// effect configured in its `sim:` section records a SWEEP; idm-gap, as a user runs it, diagnoses
// the dataset the recorder wrote and names the effect.
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <functional>
#include <string>
#include <thread>

#include "daemon/config.h"
#include "daemon/daemon.h"
#include "recording/dataset.h"
#include "tests/tools/run_tool.h"

namespace {

namespace fs = std::filesystem;

bool wait_for(const std::function<bool()>& cond, double timeout_s) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  while (std::chrono::steady_clock::now() < end) {
    if (cond()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  return cond();
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// The single-axis config form: the simulated card at a lab's sampling rate (the synthetic clock
// plays each burst at once), Table 1's stage, an effect in `sim:`.
std::string config(const fs::path& data_dir, const std::string& effects) {
  return "stage:\n  travel_m: [-5e-3, 5e-3]\n"
         "interferometer:\n  max_velocity_m_s: 1\n"
         "daq:\n  driver: sim\n  sim:\n    clock: synthetic\n    stream_rate_hz: 5e4\n"
         "sim:\n  plant: rigid\n  seed: 7\n  noise_m: 2e-9\n  effects:\n" +
         effects +
         "control:\n  freq_step_hz: 20\n  duty_step: 0.005\n  stroke_count: 4\n"
         "  min_stroke_m: 0.1e-6\n  max_freq_hz: 2000\n"
         "realtime:\n  period_s: 2e-4\n  sched_fifo: false\n  lock_memory: false\n"
         "server:\n  unix_socket: \"\"\n"
         "recording:\n  data_dir: " +
         data_dir.string() + "\n";
}

// Records a sweep with the daemon and returns the dataset's directory.
fs::path record(const fs::path& data_dir, const std::string& effects, const std::string& name) {
  idm::daemon::Daemon d(
      idm::daemon::parse_daemon_config(YAML::Load(config(data_dir, effects)), "e2e.yaml"));
  d.start();
  EXPECT_TRUE(wait_for([&] { return d.status(0).position_valid; }, 10));
  const idm::daemon::CommandError e = d.sweep(0, name, {100, 200, 300, 400, 500, 600, 700, 800},
                                              {0.05, 0.15, 0.3, 0.7, 0.85, 0.95}, 3, 10);
  EXPECT_TRUE(e.ok()) << e.text;
  EXPECT_TRUE(wait_for([&] { return d.motion_done(); }, 300));
  d.shutdown();
  EXPECT_NE(d.last_sweep_report().find("144 trials written, 0 failed"), std::string::npos)
      << d.last_sweep_report();
  return data_dir / name;
}

}  // namespace

TEST(DaemonToGap, ASweepRecordedByTheDaemonWithAnAmplifierIsDiagnosedAsTheAmplifier) {
  const fs::path data = fs::temp_directory_path() / ("idm_e2e_" + std::to_string(::getpid()));
  fs::remove_all(data);
  const fs::path ds =
      record(data, "    amplifier: {order: 2, cutoff_hz: 1800}\n", "amplifier-sweep");
  const idm::recording::Dataset read = idm::recording::read_dataset(ds.string());
  EXPECT_EQ(read.progress.status, idm::recording::SweepStatus::Complete);
  EXPECT_EQ(read.progress.axis, "x");
  ASSERT_EQ(read.trials.size(), 144u);

  const fs::path json = data / "report.json";
  const idm::test::ToolResult r =
      idm::test::run_tool("idm-gap", "diagnose " + ds.string() + " --json " + json.string());
  ASSERT_EQ(r.status, 0) << r.out;
  EXPECT_NE(r.out.find("diagnosis: amplifier;"), std::string::npos) << r.out;
  // One stroke: hysteresis cannot show, and the report says so instead of guessing.
  EXPECT_NE(r.out.find("hysteresis: not identifiable"), std::string::npos) << r.out;
  const std::string j = slurp(json);
  EXPECT_NE(j.find("\"effects\": [\"amplifier\"]"), std::string::npos) << j;
  fs::remove_all(data);
}
