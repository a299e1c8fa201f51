// What the daemon core's tests share: a small simulated-stage config, writing a config file,
// waiting for a condition, and expecting a config error.
#pragma once

#include <gtest/gtest.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <initializer_list>
#include <string>
#include <thread>

#include "daemon/config.h"
#include "model/yaml_util.h"

namespace idm::daemon::test {

inline YAML::Node yaml(const std::string& text) {
  return YAML::Load(text);
}

// Expects parse_daemon_config to fail with a message containing every one of `parts`.
inline void expect_config_error(const std::string& text, std::initializer_list<const char*> parts) {
  try {
    parse_daemon_config(yaml(text), "t.yaml");
    ADD_FAILURE() << "accepted:\n" << text;
  } catch (const model::InputError& e) {
    const std::string what = e.what();
    for (const char* p : parts)
      EXPECT_NE(what.find(p), std::string::npos) << what << " lacks " << p;
  }
}

// A small, fast configuration of the simulated stage (coarse map grid, no real-time setup).
inline std::string sim_config(const std::string& clock = "wall", const std::string& extra = "") {
  return "stage:\n  step_correction: 1.0\n  travel_m: [-5e-3, 5e-3]\n"
         "interferometer:\n  max_velocity_m_s: 1\n"
         "daq:\n  driver: sim\n  sim:\n    clock: " +
         clock +
         "\n"
         "sim:\n  plant: " +
         std::string(std::getenv("IDM_TEST_PLANT") ? std::getenv("IDM_TEST_PLANT") : "rigid") +
         "\n  seed: 3\n"
         "control:\n  freq_step_hz: 20\n  duty_step: 0.005\n  stroke_count: 4\n  min_stroke_m: "
         "0.1e-6\n  max_freq_hz: 2000\n"
         "realtime:\n  period_s: 2e-4\n  sched_fifo: false\n  lock_memory: false\n"
         "server:\n  unix_socket: \"\"\n"
         "recording:\n  data_dir: " +
         (std::filesystem::temp_directory_path() / "idmd-test-data").string() + "\n" + extra;
}

inline std::filesystem::path write_config(const std::string& name, const std::string& text) {
  const auto file = std::filesystem::temp_directory_path() /
                    ("idmd-" + name + "-" + std::to_string(::getpid()) + ".yaml");
  std::FILE* f = std::fopen(file.c_str(), "w");
  std::fwrite(text.data(), 1, text.size(), f);
  std::fclose(f);
  return file;
}

inline bool wait_for(const std::function<bool()>& cond, double timeout_s) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  while (std::chrono::steady_clock::now() < end) {
    if (cond()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  return cond();
}

}  // namespace idm::daemon::test
