// A small Instrument for the protocol, server and idmctl tests: records every call as text,
// answers from settable state, and finishes a motion after a settable number of motion_done()
// calls. Thread-safe (the server calls it from its thread while the test thread looks).
#pragma once

#include <cstdint>
#include <cstdio>
#include <mutex>
#include <stdexcept>
#include <string>
#include <vector>

#include "daemon/instrument.h"
#include "daemon/protocol.h"

namespace idm::daemon::testing {

class FakeInstrument : public Instrument {
 public:
  // ---- what the test sets ----
  void set_refusal(CommandError e) {
    std::lock_guard l(m_);
    refusal_ = std::move(e);
  }
  // motion_done() answers false this many times after a motion starts, then true.
  void set_polls_until_done(int n) {
    std::lock_guard l(m_);
    polls_until_done_ = n;
  }
  // The fault a motion ends in ("none", "stall", ...).
  void set_fault_on_finish(std::string f) {
    std::lock_guard l(m_);
    fault_on_finish_ = std::move(f);
  }
  void set_busy(bool busy) {
    std::lock_guard l(m_);
    busy_ = busy;
    remaining_ = busy ? 1 << 30 : 0;
  }
  void set_position(double x, bool valid = true) {
    std::lock_guard l(m_);
    status_.position_m = x;
    status_.position_valid = valid;
  }
  void set_last_error(std::string text) {
    std::lock_guard l(m_);
    status_.last_error = std::move(text);
  }
  void set_fault(std::string f) {
    std::lock_guard l(m_);
    status_.fault = std::move(f);
  }

  // ---- what the test reads ----
  std::vector<std::string> calls() const {
    std::lock_guard l(m_);
    return calls_;
  }
  std::size_t motion_calls() const {
    std::lock_guard l(m_);
    std::size_t n = 0;
    for (const auto& c : calls_)
      if (c.rfind("move", 0) == 0 || c.rfind("step", 0) == 0 || c.rfind("sweep", 0) == 0) ++n;
    return n;
  }
  std::string last_call() const {
    std::lock_guard l(m_);
    return calls_.empty() ? "" : calls_.back();
  }
  void clear_calls() {
    std::lock_guard l(m_);
    calls_.clear();
  }

  // ---- Instrument ----
  // identity() and motion_done() throw, as a broken implementation might.
  void set_throw(bool t) {
    std::lock_guard l(m_);
    throw_ = t;
  }
  std::string identity() override {
    std::lock_guard l(m_);
    if (throw_) throw std::runtime_error("identity broke");
    return "idm,idmd,0,test";
  }
  CommandError reset() override {
    std::lock_guard l(m_);
    calls_.push_back("reset");
    status_.fault = "none";
    remaining_ = 0;
    return {};
  }
  bool motion_done() override {
    std::lock_guard l(m_);
    if (throw_) throw std::runtime_error("motion_done broke");
    return done_locked();
  }
  InstrumentStatus status() override {
    std::lock_guard l(m_);
    InstrumentStatus s = status_;
    s.motion_done = remaining_ <= 0;
    s.state = s.motion_done ? (s.fault == "none" ? "IDLE" : "FAULT") : "MOVING";
    return s;
  }
  CommandError move_absolute(double target_m) override {
    std::lock_guard l(m_);
    return motion_locked("move_absolute(" + format_value(target_m) + ")", target_m);
  }
  CommandError move_relative(double distance_m) override {
    std::lock_guard l(m_);
    return motion_locked("move_relative(" + format_value(distance_m) + ")",
                         status_.position_m + distance_m);
  }
  CommandError step(std::int64_t cycles, double duty, double freq_hz, double stroke_m) override {
    std::lock_guard l(m_);
    return motion_locked("step(" + std::to_string(cycles) + "," + format_value(duty) + "," +
                             format_value(freq_hz) + "," + format_value(stroke_m) + ")",
                         status_.position_m);
  }
  CommandError stop() override {
    std::lock_guard l(m_);
    calls_.push_back("stop");
    remaining_ = 0;
    busy_ = false;
    return {};
  }
  CommandError set_soft_limits(double lower_m, double upper_m) override {
    std::lock_guard l(m_);
    calls_.push_back("set_soft_limits(" + format_value(lower_m) + "," + format_value(upper_m) +
                     ")");
    if (!(lower_m < upper_m)) return {error_code::kDataOutOfRange, "lower limit not below upper"};
    status_.soft_lower_m = lower_m;
    status_.soft_upper_m = upper_m;
    return {};
  }
  CommandError region(double freq_hz, double duty, double stroke_m, std::string& region,
                      double& step_m) override {
    std::lock_guard l(m_);
    calls_.push_back("region(" + format_value(freq_hz) + "," + format_value(duty) + "," +
                     format_value(stroke_m) + ")");
    if (duty <= 0 || duty >= 1) return {error_code::kDataOutOfRange, "duty must be in (0, 1)"};
    region = freq_hz > 1000 ? "CUTOFF" : "ONESTEP";
    step_m = -freq_hz * 1e-9;  // a different answer per frequency, so clients can tell theirs
    return {};
  }
  CommandError sweep(const std::string& dir, const std::vector<double>& freqs_hz,
                     const std::vector<double>& duties, int trials, int cycles) override {
    std::string f, d;
    for (double x : freqs_hz) f += (f.empty() ? "" : ";") + format_value(x);
    for (double x : duties) d += (d.empty() ? "" : ";") + format_value(x);
    std::lock_guard l(m_);
    return motion_locked("sweep(" + dir + "," + f + "," + d + "," + std::to_string(trials) + "," +
                             std::to_string(cycles) + ")",
                         status_.position_m);
  }
  LoopStats loop_stats() override {
    LoopStats s;
    s.period_s = 1e-3;
    s.wakeups = 1000;
    s.deadline_misses = 2;
    s.latency_min_s = 1e-6;
    s.latency_avg_s = 5e-6;
    s.latency_max_s = 4e-5;
    s.bin_width_s = 1e-5;
    s.bins[0] = 990;
    s.bins[3] = 10;
    return s;
  }

 private:
  CommandError motion_locked(const std::string& call, double target) {
    calls_.push_back(call);
    if (!refusal_.ok()) return refusal_;
    if (busy_) return {error_code::kSettingsConflict, "busy"};
    status_.target_m = target;
    pending_position_ = target;
    remaining_ = polls_until_done_;
    finishing_ = true;
    ++status_.moves;
    if (remaining_ <= 0) finish_locked();
    return {};
  }
  bool done_locked() {
    if (remaining_ > 0 && !busy_ && --remaining_ == 0) finish_locked();
    return remaining_ <= 0;
  }
  void finish_locked() {
    if (!finishing_) return;
    finishing_ = false;
    status_.position_m = pending_position_;
    status_.fault = fault_on_finish_;
  }

  mutable std::mutex m_;
  std::vector<std::string> calls_;
  InstrumentStatus status_{"IDLE", true, 0.0, 0.0, "none", true, -1e-3, 1e-3, 0, 0, 0, ""};
  CommandError refusal_;
  int polls_until_done_ = 0;
  int remaining_ = 0;
  bool busy_ = false;
  bool throw_ = false;
  bool finishing_ = false;
  double pending_position_ = 0;
  std::string fault_on_finish_ = "none";
};

}  // namespace idm::daemon::testing
