// The daemon's configuration: the shipped files, and bad files named by file, line and key.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <limits>
#include <string>
#include <vector>

#include "daemon/config.h"
#include "daemon/daemon.h"
#include "model/yaml_util.h"
#include "tests/daemon/daemon_test_util.h"

namespace {

using namespace idm::daemon;
using namespace idm::daemon::test;
using idm::model::InputError;

// ---- configuration ---------------------------------------------------------------------------

TEST(DaemonConfig, ShippedConfigsParse) {
  for (const char* name : {"idmd.yaml", "idmd-modbus.yaml", "idmd-usb.yaml"}) {
    const std::string path = std::string(IDM_SOURCE_DIR) + "/config/" + name;
    SCOPED_TRACE(path);
    const DaemonConfig c = load_daemon_config(path);
    EXPECT_FALSE(c.devices[0].driver.empty());
  }
  const DaemonConfig c = load_daemon_config(std::string(IDM_SOURCE_DIR) + "/config/idmd.yaml");
  EXPECT_EQ(c.devices[0].driver, "sim");
  EXPECT_DOUBLE_EQ(c.axes[0].stage.stage.slider_mass_kg, 0.16557);  // Table 1
  EXPECT_DOUBLE_EQ(c.axes[0].stage.stage.stroke_m, 20.35e-6);
  EXPECT_EQ(c.server.tcp_port, 5025);
  EXPECT_DOUBLE_EQ(c.realtime.period_s, 1e-4);
}

// Found by tests/fuzz/fuzz_config: a key that is a map ("{a: 1}: 2") escaped as yaml-cpp's
// BadConversion instead of an error naming the file and line; an alias to a node that holds it
// would recurse without end.
TEST(DaemonConfig, AKeyThatIsNoPlainNameAndEndlessNestingNameTheFileAndLine) {
  for (const auto& [name, text, line] :
       std::vector<std::tuple<std::string, std::string, std::string>>{
           {"map-key", "{a: 1}: 2\n", ":1:"},
           {"list-key", "server:\n  [1, 2]: 3\n", ":2:"},
           {"null-key", "server:\n  ? \n  : 3\n", ":3:"},
           {"alias-loop", "stage: &a\n  - *a\n", ":"},
       }) {
    SCOPED_TRACE(name);
    const auto file = std::filesystem::temp_directory_path() /
                      ("idmd-fuzz-" + name + "-" + std::to_string(::getpid()) + ".yaml");
    std::FILE* f = std::fopen(file.c_str(), "w");
    ASSERT_NE(f, nullptr);
    std::fwrite(text.data(), 1, text.size(), f);
    std::fclose(f);
    try {
      load_daemon_config(file.string());
      ADD_FAILURE() << "accepted: " << text;
    } catch (const InputError& e) {
      EXPECT_EQ(std::string(e.what()).rfind(file.string() + line, 0), 0u) << e.what();
    }
    std::filesystem::remove(file);
  }
}

TEST(DaemonConfig, DefaultsWhenSectionsAreMissing) {
  const DaemonConfig c = parse_daemon_config(
      yaml("stage:\n  travel_m: [-2e-3, 3e-3]\ndaq:\n  driver: sim\n"), "t.yaml");
  EXPECT_EQ(c.server.tcp_address, "127.0.0.1");
  EXPECT_EQ(c.realtime.priority, 80);
  // The soft limits default to the travel.
  EXPECT_DOUBLE_EQ(c.axes[0].control.positioner.soft_lower_m, -2e-3);
  EXPECT_DOUBLE_EQ(c.axes[0].control.positioner.soft_upper_m, 3e-3);
  EXPECT_DOUBLE_EQ(c.axes[0].control.planner.resolution_m,
                   c.axes[0].stage.interferometer.resolution_m);
}

TEST(DaemonConfig, UnknownSectionNamesKeyAndLine) {
  expect_config_error("daq:\n  driver: sim\nservr:\n  tcp_port: 1\n",
                      {"t.yaml:3", "servr", "unknown section"});
}

TEST(DaemonConfig, UnknownKeyNamesKeyAndLine) {
  expect_config_error("server:\n  tcp_port: 5025\n  tcp_prot: 1\n",
                      {"t.yaml:3", "server.tcp_prot", "allowed"});
  expect_config_error("control:\n  calibration:\n    forget: 1\n",
                      {"t.yaml:3", "control.calibration.forget"});
  expect_config_error("stage:\n  mass: 1\n", {"t.yaml:2", "stage.mass"});
  expect_config_error("daq:\n  sim:\n    clok: wall\n", {"t.yaml:3", "daq.sim.clok"});
}

TEST(DaemonConfig, WrongTypeNamesKeyAndLine) {
  expect_config_error("realtime:\n  priority: high\n", {"t.yaml:2", "realtime.priority"});
  expect_config_error("realtime:\n  sched_fifo: maybe\n", {"t.yaml:2", "realtime.sched_fifo"});
  expect_config_error("server:\n  tcp_port: [1, 2]\n", {"t.yaml:2", "server.tcp_port"});
}

TEST(DaemonConfig, OutOfRangeNamesKeyLineAndRange) {
  expect_config_error("realtime:\n  priority: 100\n", {"t.yaml:2", "realtime.priority", "[1, 99]"});
  expect_config_error("server:\n  tcp_port: 70000\n", {"t.yaml:2", "server.tcp_port", "65535"});
  expect_config_error("control:\n  max_retries: -1\n", {"t.yaml:2", "control.max_retries"});
  expect_config_error("stage:\n  friction_coefficient: 5\n",
                      {"t.yaml:2", "stage.friction_coefficient"});
  expect_config_error("\n\nrealtime:\n  period_s: 1\n", {"t.yaml:4", "realtime.period_s"});
  expect_config_error("logging:\n  level: loud\n", {"t.yaml:2", "logging.level", "allowed"});
  expect_config_error("control:\n  min_freq_hz: 500\n  max_freq_hz: 100\n",
                      {"t.yaml:2", "control.min_freq_hz: 500 is out of range, allowed (0, 100]"});
}

TEST(DaemonConfig, TheTravelIsRequiredAndBoundsTheSoftLimits) {
  expect_config_error("daq:\n  driver: sim\n",
                      {"stage.travel_m", "missing", "travel_m: [-5e-3, 5e-3]"});
  expect_config_error("stage:\n  travel_m: [1e-3, -1e-3]\n",
                      {"t.yaml:2", "stage.travel_m", "lower must be below upper"});
  expect_config_error("stage:\n  travel_m: 5e-3\n",
                      {"t.yaml:2", "stage.travel_m", "[lower, upper]"});
  expect_config_error("stage:\n  travel_m: [-1e-3, 1e-3]\ncontrol:\n  soft_upper_m: 2e-3\n",
                      {"t.yaml:4",
                       "control.soft_upper_m: 0.002 is out of range, allowed "
                       "(-0.001, 0.001] (> soft_lower_m; within stage.travel_m)"});
  expect_config_error("stage:\n  travel_m: [-1e-3, 1e-3]\ncontrol:\n  soft_lower_m: -2e-3\n",
                      {"t.yaml:4",
                       "control.soft_lower_m: -0.002 is out of range, allowed "
                       "[-0.001, 0.001) (< soft_upper_m; within stage.travel_m)"});
  expect_config_error(
      "stage:\n  travel_m: [-1e-3, 1e-3]\ncontrol:\n  soft_lower_m: 5e-4\n  soft_upper_m: 5e-4\n",
      {"t.yaml:4", "control.soft_lower_m: 0.0005 is out of range, allowed [-0.001, 0.0005)"});
}

// Keys whose allowed values depend on other values (the relations of control_params() and
// device_params()): each broken relation is one error naming the file, the line, the key, its
// value and the range the others leave it; the same file with the value at the edge of that range
// is accepted. One count here: 632.991e-9 m / 64 = 9.89048437e-9 m.
TEST(DaemonConfig, RelationsBetweenKeysNameTheKeyItsValueAndTheAllowedRange) {
  struct Case {
    const char* what;
    std::string bad, good;
    std::vector<std::string> parts;
  };
  const std::string stage = "stage:\n  travel_m: [-1e-3, 1e-3]\n  stroke_m: 2e-5\n";
  const std::string control = stage + "control:\n";
  const std::vector<Case> cases = {
      {"min_stroke_m above the stage's stroke",
       control + "  min_stroke_m: 3e-5\n",
       control + "  min_stroke_m: 2e-5\n",
       {"t.yaml:5: control.min_stroke_m: 3e-5 is out of range, allowed (0, 2e-5] (<= the "
        "largest stroke: max_stroke_m (0: stage.stroke_m), capped by the output's reach"}},
      {"min_stroke_m above max_stroke_m",
       control + "  max_stroke_m: 4e-6\n  min_stroke_m: 5e-6\n",
       control + "  max_stroke_m: 4e-6\n  min_stroke_m: 4e-6\n",
       {"t.yaml:6: control.min_stroke_m: 5e-6 is out of range, allowed (0, 4e-6]"}},
      {"min_stroke_m beyond the output's reach",
       stage + "daq:\n  sim:\n    max_voltage_v: 2\ncontrol:\n  min_stroke_m: 1e-5\n",
       stage + "daq:\n  sim:\n    max_voltage_v: 2\ncontrol:\n  min_stroke_m: 8e-6\n",
       {"t.yaml:8: control.min_stroke_m: 1e-5 is out of range, allowed (0, 8e-6]"}},
      {"min_freq_hz above max_freq_hz",
       control + "  max_freq_hz: 100\n  min_freq_hz: 500\n",
       control + "  max_freq_hz: 100\n  min_freq_hz: 100\n",
       {"t.yaml:6: control.min_freq_hz: 500 is out of range, allowed (0, 100] (<= max_freq_hz, "
        "narrowed by the output)"}},
      {"min_freq_hz above what the output plays (a quarter of its clock)",
       control + "  output_sample_rate_hz: 4000\n  min_freq_hz: 1500\n",
       control + "  output_sample_rate_hz: 4000\n  min_freq_hz: 1000\n",
       {"control.min_freq_hz: 1500 is out of range, allowed (0, 1000]"}},
      {"a window below one count",
       control + "  tolerance_m: 5e-9\n",
       control + "  tolerance_m: 9.9e-9\n",
       {"t.yaml:5: control.tolerance_m: 5e-9 is out of range, allowed 0 or [9.89048437e-9, "
        "0.001] (>= one count"}},
      {"a hold window below the move window",
       control + "  tolerance_m: 5e-8\n  hold_window_m: 3e-8\n",
       control + "  tolerance_m: 5e-8\n  hold_window_m: 5e-8\n",
       {"t.yaml:6: control.hold_window_m: 3e-8 is out of range, allowed 0 or [5e-8, 0.001]"}},
      {"a hold window below one count (the move window)",
       control + "  hold_window_m: 5e-9\n",
       control + "  hold_window_m: 0\n",
       {"control.hold_window_m: 5e-9 is out of range, allowed 0 or [9.89048437e-9, 0.001]"}},
      {"an end-of-travel step below one count over its cycles",
       control + "  eot_cycles: 10\n  eot_step_m: 9e-10\n",
       control + "  eot_cycles: 10\n  eot_step_m: 1e-9\n",
       {"t.yaml:6: control.eot_step_m: 9e-10 is out of range, allowed 0 or (9.89048437e-10, "
        "0.001] (> one count / eot_cycles)"}},
      {"a soft limit beyond the other end of the travel: the key given is named",
       control + "  soft_upper_m: -2e-3\n",
       control + "  soft_upper_m: -0.9e-3\n",
       {"t.yaml:5: control.soft_upper_m: -0.002 is out of range, allowed (-0.001, 0.001]"}},
      {"no value left to a soft limit: 'none'",
       control + "  soft_lower_m: -1e-3\n  soft_upper_m: -2e-3\n",
       control + "  soft_lower_m: -1e-3\n  soft_upper_m: -0.5e-3\n",
       {"t.yaml:5: control.soft_lower_m: -0.001 is out of range, allowed none (< soft_upper_m; "
        "within stage.travel_m)"}},
      {"min_step_counts not below final_step_counts",
       control + "  final_step_counts: 1\n  min_step_counts: 1\n",
       control + "  final_step_counts: 1\n  min_step_counts: 0.99\n",
       {"t.yaml:6: control.min_step_counts: 1 is out of range, allowed [0, 1) (< "
        "final_step_counts)"}},
      {"the longest reconnect wait below the first",
       stage + "daq:\n  reconnect_min_s: 1\n  reconnect_max_s: 0.5\n",
       stage + "daq:\n  reconnect_min_s: 1\n  reconnect_max_s: 1\n",
       {"t.yaml:6: daq.reconnect_max_s: 0.5 is out of range, allowed [1, 3600] (>= "
        "reconnect_min_s)"}},
      {"an axis of several",
       "devices:\n  card:\n    driver: sim\naxes:\n  x:\n    stage: {travel_m: [-1e-3, 1e-3]}\n"
       "  y:\n    stage: {travel_m: [-1e-3, 1e-3], stroke_m: 1e-5}\n    control:\n"
       "      min_stroke_m: 2e-5\n",
       "devices:\n  card:\n    driver: sim\naxes:\n  x:\n    stage: {travel_m: [-1e-3, 1e-3]}\n"
       "  y:\n    stage: {travel_m: [-1e-3, 1e-3], stroke_m: 1e-5}\n    control:\n"
       "      min_stroke_m: 1e-5\n",
       {"t.yaml:10: axes.y.control.min_stroke_m: 2e-5 is out of range, allowed (0, 1e-5]"}},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.what);
    try {
      parse_daemon_config(yaml(c.bad), "t.yaml");
      ADD_FAILURE() << "accepted:\n" << c.bad;
    } catch (const InputError& e) {
      for (const std::string& part : c.parts)
        EXPECT_NE(std::string(e.what()).find(part), std::string::npos) << e.what();
    }
    EXPECT_NO_THROW(parse_daemon_config(yaml(c.good), "t.yaml")) << c.good;
  }
}

// The relations hold for values set in code too (ParamTable::validate): control's and the
// positioner's (whose pair checks moved into its table).
TEST(DaemonConfig, RelationsAreCheckedForValuesSetInCode) {
  ControlConfig c;
  c.planner.resolution_m = 1e-8;
  c.positioner.soft_lower_m = -1e-3;
  c.positioner.soft_upper_m = 1e-3;
  EXPECT_NO_THROW(control_params().validate(c, "control"));
  c.positioner.tolerance_m = 5e-9;
  try {
    control_params().validate(c, "control");
    ADD_FAILURE() << "a window of half a count was accepted";
  } catch (const InputError& e) {
    EXPECT_EQ(std::string(e.what()),
              "control.tolerance_m: 5e-9 is out of range, allowed 0 or [1e-8, 0.001] (>= one "
              "count (interferometer resolution_m))");
  }

  idm::control::PositionerConfig p;
  p.min_step_counts = 3;
  p.final_step_counts = 2;
  EXPECT_THROW(idm::control::validate(p), InputError);
  p.min_step_counts = 1;
  p.soft_lower_m = std::numeric_limits<double>::infinity();
  EXPECT_THROW(idm::control::validate(p), InputError);  // +inf as the lower limit: no interval
  p.soft_lower_m = -std::numeric_limits<double>::infinity();
  EXPECT_NO_THROW(idm::control::validate(p));
}

TEST(DaemonConfig, ADuplicateKeyIsRefusedNamingBothLines) {
  expect_config_error(
      "stage:\n  travel_m: [-1e-3, 1e-3]\ncontrol:\n  max_retries: 3\n  settle_s: 0.01\n  "
      "max_retries: 30\n",
      {"t.yaml:6", "control.max_retries", "duplicate key", "line 4"});
  expect_config_error(
      "stage:\n  travel_m: [-1e-3, 1e-3]\nserver:\n  tcp_port: 1\nserver:\n  tcp_port: 2\n",
      {"t.yaml:5", "server", "also at line 3"});
  // Through the file loader too (idmd --check-config, SIGHUP).
  const auto file =
      std::filesystem::temp_directory_path() / ("idmd-dup-" + std::to_string(::getpid()) + ".yaml");
  { std::ofstream(file) << "stage:\n  stroke_m: 2e-5\n  stroke_m: 3e-5\n"; }
  try {
    load_daemon_config(file.string());
    ADD_FAILURE() << "a duplicate key was accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find(":3: stage.stroke_m: duplicate key: also at line 2"),
              std::string::npos)
        << e.what();
  }
  std::filesystem::remove(file);
}

TEST(DaemonConfig, AChunkThatCannotFitTheCaptureIsRefusedAtStart) {
  // 0.1 s at the simulated device's 100 kHz stream is 10001 records; it holds 8192.
  const std::string text = sim_config("synthetic", "");
  std::string bad = text;
  bad.replace(bad.find("    clock: synthetic\n"), 21,
              "    clock: synthetic\n    stream_capacity: 8192\n");
  bad.replace(bad.find("  max_freq_hz: 2000\n"), 20,
              "  max_freq_hz: 2000\n  max_chunk_s: 0.1\n  min_freq_hz: 20\n");
  Daemon daemon(parse_daemon_config(yaml(bad), "t.yaml"));
  try {
    daemon.start();
    ADD_FAILURE() << "started with a chunk longer than the capture";
  } catch (const StartError& e) {
    EXPECT_EQ(e.exit_code(), exit_code::kBadConfig);
    const std::string what = e.what();
    EXPECT_NE(what.find("control.max_chunk_s"), std::string::npos) << what;
    EXPECT_NE(what.find("8192"), std::string::npos) << what;
  }
}

TEST(DaemonConfig, UnknownDriverListsKnownOnes) {
  expect_config_error("daq:\n  driver: gpib\n", {"t.yaml:2", "daq.driver", "sim, modbus, usb"});
}

TEST(DaemonConfig, SimSectionCheckedWhateverTheDriver) {
  expect_config_error("daq:\n  driver: modbus\nsim:\n  plant: spring\n", {"t.yaml:4", "sim.plant"});
}

TEST(DaemonConfig, DeviceLimitsNarrowToTheOutput) {
  const DaemonConfig c = parse_daemon_config(yaml(sim_config()), "t.yaml");
  idm::drivers::OutputCapabilities caps;
  caps.max_sample_rate_hz = 2e4;
  caps.max_voltage_v = 2.0;  // 2 V / 2.5e5 V/m = 8 um
  const auto lim = device_limits(c.axes[0].control, c.axes[0].stage.stage, caps);
  EXPECT_DOUBLE_EQ(lim.output_sample_rate_hz, 2e4);
  EXPECT_LE(lim.max_freq_hz, 2e4 / 4);
  EXPECT_DOUBLE_EQ(lim.max_stroke_m, 8e-6);
}

}  // namespace
