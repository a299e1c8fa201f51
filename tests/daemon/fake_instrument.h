// A small Instrument for the protocol, server and idmctl tests: records every call as text
// (calls on axis k > 0 prefixed "axisK+1:"), answers from settable state, and finishes a motion
// after a settable number of motion_done() calls. One axis "x" unless set_axes() says more.
// Thread-safe (the server calls it from its thread while the test thread looks).
#pragma once

#include <cmath>
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
  void set_axes(std::vector<std::string> names) {
    std::lock_guard l(m_);
    names_ = std::move(names);
    statuses_.assign(names_.size(), status_);
    for (std::size_t i = 0; i < names_.size(); ++i) statuses_[i].name = names_[i];
  }
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
  void set_position(double x, bool valid = true, int axis = 0) {
    std::lock_guard l(m_);
    at(axis).position_m = x;
    at(axis).position_valid = valid;
  }
  void set_last_error(std::string text) {
    std::lock_guard l(m_);
    at(0).last_error = std::move(text);
  }
  void set_fault(std::string f) {
    std::lock_guard l(m_);
    at(0).fault = std::move(f);
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
  int axis_count() override {
    std::lock_guard l(m_);
    return static_cast<int>(statuses_.size());
  }
  std::string axis_name(int axis) override {
    std::lock_guard l(m_);
    return at(axis).name;
  }
  CommandError reset() override {
    std::lock_guard l(m_);
    calls_.push_back("reset");
    for (auto& s : statuses_) s.fault = "none";
    remaining_ = 0;
    return {};
  }
  bool motion_done() override {
    std::lock_guard l(m_);
    if (throw_) throw std::runtime_error("motion_done broke");
    return done_locked();
  }
  bool motion_done(int axis) override {
    std::lock_guard l(m_);
    (void)at(axis);
    if (throw_) throw std::runtime_error("motion_done broke");
    return done_locked();
  }
  InstrumentStatus status(int axis) override {
    std::lock_guard l(m_);
    InstrumentStatus s = at(axis);
    s.motion_done = remaining_ <= 0;
    s.state = s.motion_done ? (s.fault == "none" ? "IDLE" : "FAULT") : "MOVING";
    s.resolution_m = 9.8906e-9;
    s.device = "up";
    return s;
  }
  std::vector<double> positions() override {
    std::lock_guard l(m_);
    std::vector<double> out;
    for (const auto& s : statuses_) out.push_back(s.position_valid ? s.position_m : std::nan(""));
    return out;
  }
  CommandError move_absolute(int axis, double target_m) override {
    std::lock_guard l(m_);
    return motion_locked(axis, "move_absolute(" + format_value(target_m) + ")", target_m);
  }
  CommandError move_relative(int axis, double distance_m) override {
    std::lock_guard l(m_);
    return motion_locked(axis, "move_relative(" + format_value(distance_m) + ")",
                         at(axis).position_m + distance_m);
  }
  CommandError step(int axis, std::int64_t cycles, double duty, double freq_hz,
                    double stroke_m) override {
    std::lock_guard l(m_);
    return motion_locked(axis,
                         "step(" + std::to_string(cycles) + "," + format_value(duty) + "," +
                             format_value(freq_hz) + "," + format_value(stroke_m) + ")",
                         at(axis).position_m);
  }
  CommandError stop() override {
    std::lock_guard l(m_);
    calls_.push_back("stop");
    remaining_ = 0;
    busy_ = false;
    return {};
  }
  CommandError stop(int axis) override {
    std::lock_guard l(m_);
    calls_.push_back(prefix(axis) + "stop_axis");
    remaining_ = 0;
    busy_ = false;
    return {};
  }
  CommandError set_soft_limits(int axis, double lower_m, double upper_m) override {
    std::lock_guard l(m_);
    calls_.push_back(prefix(axis) + "set_soft_limits(" + format_value(lower_m) + "," +
                     format_value(upper_m) + ")");
    if (!(lower_m < upper_m)) return {error_code::kDataOutOfRange, "lower limit not below upper"};
    at(axis).soft_lower_m = lower_m;
    at(axis).soft_upper_m = upper_m;
    return {};
  }
  CommandError set_position(int axis, double position_m) override {
    std::lock_guard l(m_);
    calls_.push_back(prefix(axis) + "set_position(" + format_value(position_m) + ")");
    InstrumentStatus& s = at(axis);
    s.user_offset_m += position_m - s.position_m;
    s.position_m = position_m;
    return {};
  }
  CommandError set_user_offset(int axis, double offset_m) override {
    std::lock_guard l(m_);
    calls_.push_back(prefix(axis) + "set_user_offset(" + format_value(offset_m) + ")");
    InstrumentStatus& s = at(axis);
    s.position_m += offset_m - s.user_offset_m;
    s.user_offset_m = offset_m;
    return {};
  }
  RegionRange region_range(int axis) override {
    std::lock_guard l(m_);
    calls_.push_back(prefix(axis) + "region_range()");
    return {10.0, 2000.0, 1e-7, 2e-5};
  }
  CommandError region(int axis, double freq_hz, double duty, double stroke_m, std::string& region,
                      double& step_m) override {
    std::lock_guard l(m_);
    calls_.push_back(prefix(axis) + "region(" + format_value(freq_hz) + "," + format_value(duty) +
                     "," + format_value(stroke_m) + ")");
    if (duty <= 0 || duty >= 1) return {error_code::kDataOutOfRange, "duty must be in (0, 1)"};
    region = freq_hz > 1000 ? "CUTOFF" : "ONESTEP";
    step_m = -freq_hz * 1e-9;  // a different answer per frequency, so clients can tell theirs
    return {};
  }
  CommandError sweep(int axis, const std::string& dir, const std::vector<double>& freqs_hz,
                     const std::vector<double>& duties, int trials, int cycles) override {
    std::string f, d;
    for (double x : freqs_hz) f += (f.empty() ? "" : ";") + format_value(x);
    for (double x : duties) d += (d.empty() ? "" : ";") + format_value(x);
    std::lock_guard l(m_);
    return motion_locked(axis,
                         "sweep(" + dir + "," + f + "," + d + "," + std::to_string(trials) + "," +
                             std::to_string(cycles) + ")",
                         at(axis).position_m);
  }
  CommandError set_motion_setting(int axis, MotionSetting which, double value) override {
    std::lock_guard l(m_);
    calls_.push_back(prefix(axis) + "set_motion_setting(" +
                     std::to_string(static_cast<int>(which)) + "," + format_value(value) + ")");
    if (static_cast<std::size_t>(which) < std::size(settings_))
      settings_[static_cast<std::size_t>(which)] = value;
    return {};
  }
  double motion_setting(int, MotionSetting which) override {
    std::lock_guard l(m_);
    const auto k = static_cast<std::size_t>(which);
    return k < std::size(settings_) ? settings_[k] : 0;
  }
  CommandError reference(int axis, ReferenceMethod method) override {
    std::lock_guard l(m_);
    return motion_locked(axis, "reference(" + std::to_string(static_cast<int>(method)) + ")",
                         at(axis).position_m);
  }
  CommandError sim_push(int axis, double distance_m) override {
    std::lock_guard l(m_);
    calls_.push_back(prefix(axis) + "sim_push(" + format_value(distance_m) + ")");
    return {};
  }
  CommandError sim_fault(int axis, const std::string& fault, double value) override {
    std::lock_guard l(m_);
    calls_.push_back(prefix(axis) + "sim_fault(" + fault + "," + format_value(value) + ")");
    return {};
  }
  SweepStatus sweep_status() override {
    SweepStatus s;
    s.state = "DONE";
    s.planned = s.written = 4;
    s.directory = "d";
    return s;
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
  double settings_[static_cast<std::size_t>(MotionSetting::MaxSpeed) + 1] = {};
  InstrumentStatus& at(int axis) {
    if (axis < 0 || static_cast<std::size_t>(axis) >= statuses_.size())
      throw std::out_of_range("FakeInstrument: no axis " + std::to_string(axis));
    return statuses_[static_cast<std::size_t>(axis)];
  }
  static std::string prefix(int axis) {
    return axis == 0 ? "" : "axis" + std::to_string(axis + 1) + ":";
  }
  CommandError motion_locked(int axis, const std::string& call, double target) {
    calls_.push_back(prefix(axis) + call);
    if (!refusal_.ok()) return refusal_;
    if (busy_) return {error_code::kSettingsConflict, "busy"};
    at(axis).target_m = target;
    moving_axis_ = axis;
    pending_position_ = target;
    remaining_ = polls_until_done_;
    finishing_ = true;
    ++at(axis).moves;
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
    at(moving_axis_).position_m = pending_position_;
    at(moving_axis_).fault = fault_on_finish_;
  }

  static InstrumentStatus initial() {
    InstrumentStatus s;
    s.name = "x";
    s.state = "IDLE";
    s.position_valid = true;
    s.fault = "none";
    s.soft_lower_m = -1e-3;
    s.soft_upper_m = 1e-3;
    return s;
  }

  mutable std::mutex m_;
  std::vector<std::string> calls_;
  InstrumentStatus status_ = initial();
  std::vector<std::string> names_{"x"};
  std::vector<InstrumentStatus> statuses_{initial()};
  CommandError refusal_;
  int polls_until_done_ = 0;
  int remaining_ = 0;
  int moving_axis_ = 0;
  bool busy_ = false;
  bool throw_ = false;
  bool finishing_ = false;
  double pending_position_ = 0;
  std::string fault_on_finish_ = "none";
};

}  // namespace idm::daemon::testing
