#include "daemon/daemon.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <sstream>
#include <system_error>
#include <utility>

#include "daemon/data_dir.h"
#include "drivers/backends.h"
#include "drivers/clock.h"
#include "drivers/sim/sim_backend.h"
#include "model/waveform.h"
#include "model/yaml_util.h"

#ifndef IDM_VERSION
#define IDM_VERSION "0"
#endif

namespace idm::daemon {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr std::size_t kStreamChunk = 4096;  // words read from the stream per call

void sleep_s(double s) { std::this_thread::sleep_for(std::chrono::duration<double>(s)); }

std::string num(double v) { return model::format_number(v); }

}  // namespace

struct Daemon::SweepJob {
  std::optional<recording::DatasetWriter> writer;
  std::string dir;
  std::vector<double> freqs_hz, duties;
  int trials = 0;
  int cycles = 0;
  double stroke_m = 0;
};

Daemon::Daemon(DaemonConfig config) : config_(std::move(config)), loop_(config_.realtime, *this) {
  soft_lower_m_ = config_.control.positioner.soft_lower_m;
  soft_upper_m_ = config_.control.positioner.soft_upper_m;
}

Daemon::~Daemon() {
  try {
    shutdown();
  } catch (...) {
  }
}

// ---------------------------------------------------------------------------------------------
// Lifecycle

std::string Daemon::start() {
  if (started_) return {};
  try {
    device_ = drivers::make_backend_from_config(config_.root, config_.file);
  } catch (const model::InputError& e) {
    throw StartError(exit_code::kBadConfig, e.what());
  }
  if (drivers::DriverStatus s = device_.configure(); !s.ok())
    throw StartError(exit_code::kNoHardware,
                     "cannot open the " + device_.driver + " device: " + s.message + " (" +
                         drivers::driver_error_name(s.error) + ")");
  if (drivers::DriverStatus s = device_.activate(); !s.ok()) {
    device_.shutdown();
    throw StartError(exit_code::kNoHardware,
                     "cannot activate the " + device_.driver + " device: " + s.message);
  }
  try {
    limits_ = device_limits(config_.control, config_.stage.stage, device_.output->capabilities());
    build_map();
    if (config_.control.calibration.enabled) {
      calibration_ = std::make_unique<control::Calibration>(config_.stage.stage,
                                                            config_.control.calibration);
      if (!config_.control.calibration_file.empty() &&
          std::filesystem::exists(config_.control.calibration_file)) {
        std::string error;
        if (!calibration_->load(config_.control.calibration_file, error))
          sweep_report_ = "calibration not loaded: " + error;  // logged by the caller via report
      }
    }
    build_positioner();
    if (calibration_) {
      const control::CalibrationState state = calibration_->state();
      calibration_snapshot_.store(state);
      calibration_published_updates_ = calibration_saved_updates_ = state.total_updates;
    }
  } catch (const model::InputError& e) {
    device_.shutdown();
    throw StartError(exit_code::kBadConfig, e.what());
  }
  const auto& caps = device_.output->capabilities();
  if (caps.mode == drivers::OutputMode::BufferedSamples)
    burst_.assign(std::min<std::size_t>(caps.max_burst_samples, std::size_t{1} << 21), 0.0);
  stream_buf_.assign(kStreamChunk, drivers::TimedWord{});

  pub_.soft_lower_m = soft_lower_m_;
  pub_.soft_upper_m = soft_upper_m_;
  pub_.motion = positioner_->status();
  published_.store(pub_);
  recorder_ = StackThread(kRecorderStackBytes, [this] { recorder_main(); });
  started_ = true;
  return loop_.start();
}

void Daemon::shutdown() {
  if (!started_ || shut_down_) return;
  shut_down_ = true;
  stop_all_.store(true, std::memory_order_release);
  sweep_abort_.store(true, std::memory_order_release);
  park_request_.store(false, std::memory_order_release);
  {
    std::lock_guard<std::mutex> lock(recorder_mutex_);
    recorder_quit_ = true;
  }
  recorder_cv_.notify_all();
  // The playing chunk ends by itself (at most max_chunk_s); a sweep burst is stopped at once.
  wait_at_rest(std::max(2.0, 4 * config_.control.positioner.max_chunk_s));
  if (recorder_.joinable()) recorder_.join();
  loop_.stop();
  // The loop has ended: this thread owns the device again.
  device_.output->stop();
  device_.deactivate();
  // The recorder has ended: this thread saves the final state (a failure becomes a note).
  if (calibration_) save_calibration(calibration_->state());
  device_.shutdown();
}

double Daemon::sim_output_m() const {
  return device_.sim ? device_.sim->commanded_elongation_m() : kNaN;
}

void Daemon::build_map() {
  map_ = std::make_unique<control::RegionMap>(
      region_map_config(config_.control, config_.stage.stage, limits_));
}

void Daemon::build_positioner() {
  control::PositionerConfig pc = config_.control.positioner;
  pc.soft_lower_m = soft_lower_m_;
  pc.soft_upper_m = soft_upper_m_;
  positioner_ = std::make_unique<control::Positioner>(*map_, config_.control.planner, pc,
                                                      *device_.output, *device_.interferometer,
                                                      calibration_.get());
}

template <typename Fn>
bool Daemon::with_loop_parked(double timeout_s, Fn&& fn) {
  park_request_.store(true, std::memory_order_release);
  const double deadline = drivers::monotonic_s() + timeout_s;
  while (!parked_.load(std::memory_order_acquire)) {
    if (drivers::monotonic_s() > deadline || !loop_.running()) {
      park_request_.store(false, std::memory_order_release);
      return false;
    }
    sleep_s(1e-4);
  }
  fn();
  park_request_.store(false, std::memory_order_release);
  while (parked_.load(std::memory_order_acquire) && loop_.running()) sleep_s(1e-5);
  return true;
}

bool Daemon::reload_control(std::string& error, SoftLimits limits) {
  ControlConfig fresh;
  try {
    const YAML::Node root = model::load_yaml_file(config_.file);
    fresh = parse_control_config(root, config_.file, config_.stage);
  } catch (const std::exception& e) {
    error = e.what();
    return false;
  }
  std::lock_guard<std::mutex> lock(control_mutex_);
  const ControlConfig old = config_.control;
  const bool map_changed =
      fresh.freq_step_hz != old.freq_step_hz || fresh.duty_step != old.duty_step ||
      fresh.stroke_count != old.stroke_count || fresh.min_freq_hz != old.min_freq_hz ||
      fresh.max_freq_hz != old.max_freq_hz || fresh.min_stroke_m != old.min_stroke_m ||
      fresh.max_stroke_m != old.max_stroke_m ||
      fresh.output_sample_rate_hz != old.output_sample_rate_hz ||
      fresh.friction_uncertainty != old.friction_uncertainty;
  // Build what allocates before parking, swap while parked.
  std::unique_ptr<control::RegionMap> new_map;
  control::DeviceLimits new_limits = limits_;
  try {
    if (map_changed) {
      new_limits = device_limits(fresh, config_.stage.stage, device_.output->capabilities());
      new_map = std::make_unique<control::RegionMap>(
          region_map_config(fresh, config_.stage.stage, new_limits));
    }
  } catch (const std::exception& e) {
    error = e.what();
    return false;
  }
  // A move in progress stops at its chunk end first (the loop does it while parking).
  std::string build_error;
  const bool ok = with_loop_parked(std::max(2.0, 4 * fresh.positioner.max_chunk_s), [&] {
    const control::MotionStatus previous = positioner_->status();
    config_.control = fresh;
    if (limits == SoftLimits::FromFile) {
      soft_lower_m_ = fresh.positioner.soft_lower_m;
      soft_upper_m_ = fresh.positioner.soft_upper_m;
    }
    if (new_map) {
      positioner_.reset();
      map_ = std::move(new_map);
      limits_ = new_limits;
    }
    try {
      build_positioner();
    } catch (const std::exception& e) {
      build_error = e.what();
      config_.control = old;
      if (limits == SoftLimits::FromFile) {
        soft_lower_m_ = old.positioner.soft_lower_m;
        soft_upper_m_ = old.positioner.soft_upper_m;
      }
      build_positioner();
    }
    positioner_->continue_from(previous);
    pub_.soft_lower_m = soft_lower_m_;
    pub_.soft_upper_m = soft_upper_m_;
  });
  if (!ok) {
    error = "the real-time loop did not come to rest within the timeout (motion in progress?)";
    return false;
  }
  if (!build_error.empty()) {
    error = build_error;
    return false;
  }
  return true;
}

// ---------------------------------------------------------------------------------------------
// The real-time loop's tick: no allocation, no lock, no log.

void Daemon::tick(double now_s) {
  if (park_request_.load(std::memory_order_acquire)) {
    if (!parked_.load(std::memory_order_relaxed)) {
      if (sweep_phase_ == SweepPhase::Idle && positioner_->at_rest()) {
        pub_.parked = true;
        published_.store(pub_);
        parked_.store(true, std::memory_order_release);
      } else {
        // Bring whatever moves to rest first: a move ends at its chunk end, a trial at once.
        positioner_->stop();
        if (sweep_phase_ == SweepPhase::Playing) sweep_fail(TrialFailure::Stopped);
        positioner_->tick(now_s);
        publish();
        return;
      }
    }
    if (parked_.load(std::memory_order_relaxed)) return;
  } else if (parked_.load(std::memory_order_relaxed)) {
    parked_.store(false, std::memory_order_release);
    pub_.parked = false;
  }

  const bool stopping = stop_all_.load(std::memory_order_acquire);
  // The server waits for one command at a time: at most one is popped per tick, and it is
  // acknowledged after the status that reflects it is published (so that MOVE:DONE? right after
  // a MOVE already sees the motion).
  Command cmd;
  std::uint64_t ack = 0;
  if (commands_.pop(cmd)) {
    if (stopping && cmd.kind != CommandKind::Stop && cmd.kind != CommandKind::SetLimits) {
      acked_refusal_.store(static_cast<std::uint8_t>(control::Refusal::Busy), std::memory_order_relaxed);
    } else {
      apply(cmd);
    }
    ack = cmd.seq;
  }
  if (stopping) positioner_->stop();

  if (sweep_phase_ != SweepPhase::Idle || !trial_requests_.empty()) {
    sweep_tick(now_s);
  } else {
    positioner_->tick(now_s);
  }
  publish();
  if (ack != 0) acked_seq_.store(ack, std::memory_order_release);
}

void Daemon::apply(const Command& cmd) {
  control::Refusal r = control::Refusal::None;
  const bool sweeping = sweep_phase_ != SweepPhase::Idle || sweep_active_.load(std::memory_order_acquire);
  switch (cmd.kind) {
    case CommandKind::MoveAbsolute:
      r = sweeping ? control::Refusal::Busy : positioner_->move_absolute(cmd.a);
      break;
    case CommandKind::MoveRelative:
      r = sweeping ? control::Refusal::Busy : positioner_->move_relative(cmd.a);
      break;
    case CommandKind::Step:
      r = sweeping ? control::Refusal::Busy : positioner_->step_open_loop(cmd.n, cmd.a, cmd.b, cmd.c);
      break;
    case CommandKind::Stop:
      positioner_->stop();
      if (sweep_phase_ != SweepPhase::Idle) sweep_fail(TrialFailure::Stopped);
      break;
    case CommandKind::SetLimits:
      r = positioner_->set_soft_limits(cmd.a, cmd.b);
      if (r == control::Refusal::None) {
        soft_lower_m_ = cmd.a;
        soft_upper_m_ = cmd.b;
        pub_.soft_lower_m = cmd.a;
        pub_.soft_upper_m = cmd.b;
      }
      break;
  }
  acked_target_m_.store(cmd.kind == CommandKind::SetLimits || cmd.kind == CommandKind::Stop
                            ? kNaN
                            : positioner_->requested_target_m(),
                        std::memory_order_relaxed);
  acked_refusal_.store(static_cast<std::uint8_t>(r), std::memory_order_relaxed);
}

void Daemon::publish() {
  pub_.motion = positioner_->status();
  pub_.sweep_trial_active = sweep_phase_ != SweepPhase::Idle;
  published_.store(pub_);
  if (pub_.motion.fault != noted_fault_) note_fault();
  // Only when a burst updated it (at most once per chunk): a copy of a few hundred bytes.
  if (calibration_ && calibration_->total_updates() != calibration_published_updates_) {
    calibration_published_updates_ = calibration_->total_updates();
    calibration_snapshot_.store(calibration_->state());
  }
}

void Daemon::note_fault() {
  noted_fault_ = pub_.motion.fault;
  if (noted_fault_ == control::MotionFault::None) return;
  ErrorNote note;
  note.t_s = drivers::monotonic_s();
  // "fault <name>" or "fault driver: <the driver's message>"; no allocation (fixed buffer).
  auto append = [&note, used = std::size_t{0}](const char* s, std::size_t n) mutable {
    n = std::min(n, sizeof note.text - 1 - used);
    std::memcpy(note.text + used, s, n);
    used += n;
    note.text[used] = '\0';
  };
  append("fault ", 6);
  const char* name = control::motion_fault_name(noted_fault_);
  append(name, std::strlen(name));
  if (noted_fault_ == control::MotionFault::Driver && !positioner_->last_driver_error().empty()) {
    append(": ", 2);
    append(positioner_->last_driver_error().data(), positioner_->last_driver_error().size());
  }
  fault_note_.store(note);
}

void Daemon::sweep_fail(TrialFailure why) {
  if (sweep_phase_ == SweepPhase::Playing) device_.output->stop();
  if (sweep_phase_ == SweepPhase::Positioning) positioner_->stop();
  TrialRecord rec;
  rec.event = TrialEvent::Failed;
  rec.index = trial_.index;
  rec.word = static_cast<std::uint64_t>(why);
  trial_records_.push(rec);  // the recorder waits for it; the ring is drained continuously
  sweep_phase_ = SweepPhase::Idle;
}

void Daemon::sweep_tick(double now_s) {
  if (sweep_phase_ == SweepPhase::Idle) {
    if (!trial_requests_.pop(trial_)) return;
    if (stop_all_.load(std::memory_order_acquire) || sweep_abort_.load(std::memory_order_acquire)) {
      sweep_phase_ = SweepPhase::Positioning;  // so that sweep_fail reports it
      return sweep_fail(TrialFailure::Stopped);
    }
    if (!positioner_->at_rest()) {
      sweep_phase_ = SweepPhase::Positioning;
      return sweep_fail(TrialFailure::Busy);
    }
    if (std::isfinite(trial_.return_to_m)) {
      if (positioner_->move_absolute(trial_.return_to_m) != control::Refusal::None) {
        sweep_phase_ = SweepPhase::Positioning;
        return sweep_fail(TrialFailure::Positioning);
      }
      sweep_phase_ = SweepPhase::Positioning;
      positioner_->tick(now_s);
      return;
    }
    sweep_phase_ = SweepPhase::Positioning;  // no positioning: starts below at once
  }
  if (sweep_abort_.load(std::memory_order_acquire)) return sweep_fail(TrialFailure::Stopped);

  if (sweep_phase_ == SweepPhase::Positioning) {
    if (std::isfinite(trial_.return_to_m)) {
      positioner_->tick(now_s);
      if (!positioner_->at_rest()) return;
      if (positioner_->status().fault != control::MotionFault::None)
        return sweep_fail(TrialFailure::Positioning);
    }
    // Start the trial: latch where the slider is, load and play the burst.
    TrialRecord begin;
    begin.event = TrialEvent::Begin;
    begin.index = trial_.index;
    if (!device_.interferometer->latch(begin.word).ok()) return sweep_fail(TrialFailure::Driver);
    drivers::DriverStatus s;
    if (trial_.period_samples > 0) {
      const std::size_t P = trial_.period_samples, k = trial_.extension_samples;
      const std::size_t n = trial_.rest_samples + trial_.cycles * P + trial_.settle_samples + 1;
      if (n > burst_.size()) return sweep_fail(TrialFailure::Driver);
      double* out = burst_.data();
      std::size_t i = 0;
      for (std::size_t j = 0; j < trial_.rest_samples; ++j) out[i++] = 0.0;
      for (std::size_t c = 0; c < trial_.cycles; ++c)
        for (std::size_t j = 0; j < P; ++j)
          out[i++] = j <= k ? trial_.stroke_m * static_cast<double>(j) / static_cast<double>(k)
                            : trial_.stroke_m * static_cast<double>(P - j) / static_cast<double>(P - k);
      for (std::size_t j = 0; j <= trial_.settle_samples; ++j) out[i++] = 0.0;
      const double rate = trial_.freq_hz * static_cast<double>(P);
      trial_t0_s_ = static_cast<double>(trial_.rest_samples) / rate;
      s = device_.output->write_burst(out, n, rate);
    } else {
      model::TriangleWave wave;
      wave.freq_hz = trial_.freq_hz;
      wave.duty = trial_.duty;
      wave.stroke_m = trial_.stroke_m;
      wave.cycles = static_cast<int>(trial_.cycles);
      trial_t0_s_ = 0.0;
      s = device_.output->write_burst_parameters(wave);
    }
    if (!s.ok()) return sweep_fail(TrialFailure::Driver);
    begin.t_s = trial_t0_s_;
    if (!trial_records_.push(begin)) return sweep_fail(TrialFailure::Overflow);
    if (!device_.output->start().ok()) return sweep_fail(TrialFailure::Driver);
    sweep_phase_ = SweepPhase::Playing;
    return;
  }

  // Playing: stream the samples out until the device is done and the stream is empty.
  bool done = false;
  if (!device_.output->is_done(done).ok()) return sweep_fail(TrialFailure::Driver);
  for (;;) {
    std::size_t n = 0;
    if (!device_.interferometer->read_stream(stream_buf_.data(), stream_buf_.size(), n).ok())
      return sweep_fail(TrialFailure::Driver);
    for (std::size_t i = 0; i < n; ++i) {
      TrialRecord rec;
      rec.event = TrialEvent::Sample;
      rec.index = trial_.index;
      rec.t_s = stream_buf_[i].t_s;
      rec.word = stream_buf_[i].word;
      if (!trial_records_.push(rec)) return sweep_fail(TrialFailure::Overflow);
    }
    if (n < stream_buf_.size()) break;
  }
  if (!done) return;
  TrialRecord end;
  end.event = TrialEvent::End;
  end.index = trial_.index;
  if (!trial_records_.push(end)) return sweep_fail(TrialFailure::Overflow);
  sweep_phase_ = SweepPhase::Idle;
}

// ---------------------------------------------------------------------------------------------
// Server side (Instrument)

CommandError Daemon::submit(Command cmd) {
  if (!loop_.running()) return {error_code::kExecutionError, "the real-time loop is not running"};
  cmd.seq = ++next_seq_;
  const double deadline = drivers::monotonic_s() + 5.0;
  while (!commands_.push(cmd)) {
    if (drivers::monotonic_s() > deadline)
      return {error_code::kQueueOverflow, "the real-time loop's command queue is full"};
    sleep_s(1e-4);
  }
  while (acked_seq_.load(std::memory_order_acquire) < cmd.seq) {
    if (drivers::monotonic_s() > deadline || !loop_.running())
      return {error_code::kExecutionError, "the real-time loop did not take the command"};
    sleep_s(2e-5);
  }
  const auto r = static_cast<control::Refusal>(acked_refusal_.load(std::memory_order_relaxed));
  return refusal_error(r, acked_target_m_.load(std::memory_order_relaxed), cmd.kind);
}

CommandError Daemon::fault_error(control::MotionFault fault) {
  const char* name = control::motion_fault_name(fault);
  const std::string text = std::string("in FAULT (") + name + "): send *RST to clear it";
  for (const DeviceFault& f : kDeviceFaults)
    if (std::strcmp(f.name, name) == 0) return {f.code, text};
  return {error_code::kSettingsConflict, text};
}

CommandError Daemon::refusal_error(control::Refusal r, double value, CommandKind kind) {
  const Published p = published_.load();
  switch (r) {
    case control::Refusal::None: return {};
    case control::Refusal::NotFinite:
      return {error_code::kNumericDataError, "the argument is not a finite number"};
    case control::Refusal::OutsideSoftLimits:
      return {error_code::kDataOutOfRange,
              (std::isnan(value) ? std::string("the motion's end") : "target " + num(value) + " m") +
                  " is outside the soft limits [" + num(p.soft_lower_m) + ", " +
                  num(p.soft_upper_m) + "] m; nothing moved"};
    case control::Refusal::Faulted: return fault_error(p.motion.fault);
    case control::Refusal::Busy:
      if (kind == CommandKind::SetLimits)
        return {error_code::kSettingsConflict,
                "the motion in progress ends at " + num(p.motion.target_m) +
                    " m, outside the new limits: STOP it first"};
      if (stop_all_.load()) return {error_code::kSettingsConflict, "the daemon is shutting down"};
      if (sweep_active_.load()) return {error_code::kSettingsConflict, "a sweep is running: STOP it first"};
      return {error_code::kSettingsConflict, "a motion is in progress: STOP it or wait for MOVE:DONE? 1"};
    case control::Refusal::OutOfRange:
      return {error_code::kDataOutOfRange, "outside the device limits (cycles, duty, frequency or stroke)"};
    case control::Refusal::NoPosition:
      return {error_code::kHardwareError, "the position is not known (no valid interferometer word)"};
  }
  return {error_code::kExecutionError, control::refusal_name(r)};
}

bool Daemon::wait_at_rest(double timeout_s) {
  const double deadline = drivers::monotonic_s() + timeout_s;
  for (;;) {
    const Published p = published_.load();
    const bool rest = (p.motion.state == control::MotionState::Idle ||
                       p.motion.state == control::MotionState::Fault) &&
                      !p.sweep_trial_active;
    if (rest || !loop_.running()) return rest;
    if (drivers::monotonic_s() > deadline) return false;
    sleep_s(1e-3);
  }
}

std::string Daemon::identity() { return std::string("idm,idmd,0,") + IDM_VERSION; }

CommandError Daemon::reset() {
  errors_cleared_s_ = drivers::monotonic_s();
  if (CommandError e = stop(); !e.ok()) return e;
  if (reset_pending_.load(std::memory_order_acquire)) return {};  // already on its way
  {
    std::lock_guard<std::mutex> lock(recorder_mutex_);
    if (sweep_active_.load(std::memory_order_acquire)) {
      // A sweep winds down on the recorder thread (the playing trial is stopped at once, a trial
      // being written finishes first): rather than hold the server thread (and every other
      // client) meanwhile, the recorder reloads the settings once the sweep has ended.
      // motion_done() is false until then, so "*RST;*OPC?" waits for the reset to be complete.
      sweep_abort_.store(true, std::memory_order_release);
      reset_pending_.store(true, std::memory_order_release);
      recorder_cv_.notify_all();
      return {};
    }
  }
  // No sweep: the loop parks at the playing chunk's end (at most control.max_chunk_s).
  std::string error;
  if (!reload_control(error, SoftLimits::Keep)) return {error_code::kExecutionError, "*RST: " + error};
  return {};
}

bool Daemon::motion_done() {
  if (sweep_active_.load(std::memory_order_acquire) || reset_pending_.load(std::memory_order_acquire))
    return false;
  const Published p = published_.load();
  return (p.motion.state == control::MotionState::Idle ||
          p.motion.state == control::MotionState::Fault) &&
         !p.sweep_trial_active;
}

InstrumentStatus Daemon::status() {
  const Published p = published_.load();
  InstrumentStatus s;
  s.state = control::motion_state_name(p.motion.state);
  s.position_valid = p.motion.position_valid;
  s.position_m = p.motion.position_m;
  s.target_m = p.motion.target_m;
  s.fault = control::motion_fault_name(p.motion.fault);
  s.motion_done = motion_done();
  s.soft_lower_m = p.soft_lower_m;
  s.soft_upper_m = p.soft_upper_m;
  s.moves = p.motion.moves;
  s.bursts = p.motion.bursts;
  s.cycles = p.motion.cycles;
  const ErrorNote fault = fault_note_.load();
  const ErrorNote other = housekeeping_note_.load();
  const ErrorNote& last = fault.t_s >= other.t_s ? fault : other;
  if (last.t_s >= 0 && last.t_s >= errors_cleared_s_) s.last_error = last.text;
  return s;
}

CommandError Daemon::move_absolute(double target_m) {
  Command c;
  c.kind = CommandKind::MoveAbsolute;
  c.a = target_m;
  return submit(c);
}

CommandError Daemon::move_relative(double distance_m) {
  Command c;
  c.kind = CommandKind::MoveRelative;
  c.a = distance_m;
  return submit(c);
}

CommandError Daemon::step(std::int64_t cycles, double duty, double freq_hz, double stroke_m) {
  if (cycles == 0) return {error_code::kDataOutOfRange, "STEP cycles: must not be 0"};
  const bool cell_given = !std::isnan(duty) || !std::isnan(freq_hz);
  if (cell_given && (std::isnan(duty) || std::isnan(freq_hz)))
    return {error_code::kMissingParameter, "STEP takes <n> or <n>,<duty>,<freq_hz>[,<stroke_m>]"};
  if (!std::isnan(stroke_m) && !cell_given)
    return {error_code::kMissingParameter, "STEP stroke_m needs duty and freq_hz before it"};
  const auto out_of_range = [](const char* what, double v, const std::string& allowed) {
    return CommandError{error_code::kDataOutOfRange,
                        std::string("STEP ") + what + ": " + num(v) + " is out of range, allowed " + allowed};
  };
  control::DeviceLimits limits;
  {
    std::lock_guard<std::mutex> lock(control_mutex_);
    limits = limits_;
  }
  if (cell_given) {
    if (!(duty > 0 && duty < 1) || duty == 0.5)
      return out_of_range("duty", duty, "(0, 1) except 0.5 (the sign of n picks the direction)");
    if (!(freq_hz >= limits.min_freq_hz && freq_hz <= limits.max_freq_hz))
      return out_of_range("freq_hz", freq_hz,
                          "[" + num(limits.min_freq_hz) + ", " + num(limits.max_freq_hz) + "] Hz");
  }
  if (!std::isnan(stroke_m) && !(stroke_m >= limits.min_stroke_m && stroke_m <= limits.max_stroke_m))
    return out_of_range("stroke_m", stroke_m,
                        "[" + num(limits.min_stroke_m) + ", " + num(limits.max_stroke_m) + "] m");
  Command c;
  c.kind = CommandKind::Step;
  c.n = cycles;
  c.a = duty;
  c.b = freq_hz;
  c.c = stroke_m;
  return submit(c);
}

CommandError Daemon::stop() {
  Command c;
  c.kind = CommandKind::Stop;
  return submit(c);
}

CommandError Daemon::set_soft_limits(double lower_m, double upper_m) {
  if (std::isnan(lower_m) || std::isnan(upper_m))
    return {error_code::kNumericDataError, "a soft limit is not a number"};
  if (!(lower_m < upper_m))
    return {error_code::kDataOutOfRange, "the lower limit " + num(lower_m) +
                                             " m must be below the upper limit " + num(upper_m) + " m"};
  const model::StageFile& st = config_.stage;
  const std::string travel = "the stage's travel [" + num(st.travel_lower_m) + ", " +
                             num(st.travel_upper_m) + "] m";
  if (lower_m < st.travel_lower_m)
    return {error_code::kDataOutOfRange, "the lower limit " + num(lower_m) + " m lies outside " + travel};
  if (upper_m > st.travel_upper_m)
    return {error_code::kDataOutOfRange, "the upper limit " + num(upper_m) + " m lies outside " + travel};
  Command c;
  c.kind = CommandKind::SetLimits;
  c.a = lower_m;
  c.b = upper_m;
  return submit(c);
}

CommandError Daemon::region(double freq_hz, double duty, double stroke_m, std::string& region,
                            double& step_m) {
  if (!std::isfinite(freq_hz) || !std::isfinite(duty) || !std::isfinite(stroke_m))
    return {error_code::kNumericDataError, "the argument is not a finite number"};
  if (!(freq_hz > 0) || !(duty > 0 && duty < 1) || stroke_m < 0)
    return {error_code::kDataOutOfRange, "need freq_hz > 0, 0 < duty < 1, stroke_m >= 0"};
  std::lock_guard<std::mutex> lock(control_mutex_);
  const double stroke = stroke_m > 0 ? stroke_m : limits_.max_stroke_m;
  try {
    const control::RegionCell cell = map_->at(freq_hz, duty, stroke);
    switch (cell.region) {
      case model::Region::Cutoff: region = "CUTOFF"; break;
      case model::Region::OneStep: region = "ONESTEP"; break;
      default: region = "MULTISTEP"; break;
    }
    step_m = cell.step_m;
  } catch (const model::InputError& e) {
    return {error_code::kDataOutOfRange, e.what()};
  }
  return {};
}

LoopStats Daemon::loop_stats() { return loop_.stats(); }

std::string Daemon::last_sweep_report() {
  std::lock_guard<std::mutex> lock(recorder_mutex_);
  return sweep_report_;
}

std::vector<std::string> Daemon::take_notes() {
  std::lock_guard<std::mutex> lock(recorder_mutex_);
  return std::exchange(notes_, {});
}

void Daemon::add_note(std::string line) {
  std::lock_guard<std::mutex> lock(recorder_mutex_);
  if (notes_.size() < 100) notes_.push_back(std::move(line));
}

void Daemon::set_housekeeping_error(const std::string& text) {
  ErrorNote note;
  note.t_s = drivers::monotonic_s();
  const std::size_t n = std::min(text.size(), sizeof note.text - 1);
  std::memcpy(note.text, text.data(), n);
  note.text[n] = '\0';
  housekeeping_note_.store(note);
}

// ---------------------------------------------------------------------------------------------
// Calibration: saved by the recorder thread after each move that changed it.

void Daemon::save_calibration_if_changed() {
  if (!calibration_) return;
  const control::CalibrationState state = calibration_snapshot_.load();
  if (state.total_updates == calibration_saved_updates_ || !motion_done()) return;
  save_calibration(state);
}

void Daemon::save_calibration(const control::CalibrationState& state) {
  std::string path;
  control::CalibrationConfig cal_config;
  {
    std::lock_guard<std::mutex> lock(control_mutex_);
    path = config_.control.calibration_file;
    cal_config = config_.control.calibration;
  }
  calibration_saved_updates_ = state.total_updates;  // a failure is retried at the next change
  if (path.empty()) return;
  std::string error;
  try {
    // A copy of the loop's calibration, so that the loop's own object is never read here.
    control::Calibration copy(config_.stage.stage, cal_config);
    copy.set_state(state);
    copy.save(path);
  } catch (const std::exception& e) {
    error = e.what();
  }
  if (error.empty()) {
    calibration_save_error_.clear();
    return;
  }
  const std::string text = "cannot save the calibration to " + path + ": " + error;
  set_housekeeping_error(text);
  if (text != calibration_save_error_) add_note(text);  // once per distinct failure
  calibration_save_error_ = text;
}

// ---------------------------------------------------------------------------------------------
// SWEEP: argument checks here (server thread), trials in the recorder thread.

CommandError Daemon::sweep(const std::string& dir, const std::vector<double>& freqs_hz,
                           const std::vector<double>& duties, int trials, int cycles) {
  if (dir.empty()) return {error_code::kMissingParameter, "SWEEP needs a directory"};
  if (freqs_hz.empty() || duties.empty())
    return {error_code::kMissingParameter, "SWEEP needs at least one frequency and one duty"};
  if (trials < 1 || trials > kMaxSweepTrials)
    return {error_code::kDataOutOfRange, "SWEEP trials: " + std::to_string(trials) +
                                             " is out of range, allowed [1, " +
                                             std::to_string(kMaxSweepTrials) + "]"};
  if (cycles < 1 || cycles > kMaxSweepCycles)
    return {error_code::kDataOutOfRange, "SWEEP cycles: " + std::to_string(cycles) +
                                             " is out of range, allowed [1, " +
                                             std::to_string(kMaxSweepCycles) + "]"};
  const std::size_t total = freqs_hz.size() * duties.size() * static_cast<std::size_t>(trials);
  if (total > static_cast<std::size_t>(config_.recording.sweep_max_trials))
    return {error_code::kDataOutOfRange,
            std::to_string(total) + " trials, more than recording.sweep_max_trials (" +
                std::to_string(config_.recording.sweep_max_trials) + ")"};
  if (sweep_active_.load()) return {error_code::kSettingsConflict, "a sweep is already running"};
  if (!motion_done())
    return {error_code::kSettingsConflict, "a motion is in progress: STOP it or wait for MOVE:DONE? 1"};
  const Published p = published_.load();
  if (p.motion.state == control::MotionState::Fault) return fault_error(p.motion.fault);

  const auto& caps = device_.output->capabilities();
  const bool buffered = caps.mode == drivers::OutputMode::BufferedSamples;
  const double stroke = std::min(config_.stage.stage.stroke_m, caps.max_elongation_m());
  for (double f : freqs_hz) {
    if (!std::isfinite(f)) return {error_code::kNumericDataError, "a frequency is not finite"};
    if (f < limits_.min_freq_hz || f > limits_.max_freq_hz)
      return {error_code::kDataOutOfRange, "frequency " + num(f) + " Hz outside the device's [" +
                                               num(limits_.min_freq_hz) + ", " +
                                               num(limits_.max_freq_hz) + "] Hz"};
    for (double d : duties) {
      if (!std::isfinite(d)) return {error_code::kNumericDataError, "a duty is not finite"};
      if (!(d > 0 && d < 1)) return {error_code::kDataOutOfRange, "duty " + num(d) + ": allowed (0, 1)"};
      if (buffered) {
        const auto w = control::snap_to_sample_clock(limits_.output_sample_rate_hz, f, d);
        const double n = config_.recording.sweep_rest_s * limits_.output_sample_rate_hz +
                         static_cast<double>(cycles + config_.recording.sweep_settle_cycles) *
                             w.period_samples + 2;
        if (n > static_cast<double>(burst_.size()))
          return {error_code::kDataOutOfRange,
                  "a trial at " + num(f) + " Hz with " + std::to_string(cycles) +
                      " cycles needs " + num(n) + " samples, the output holds " +
                      std::to_string(burst_.size())};
      } else if (static_cast<std::uint32_t>(cycles) > caps.max_cycles) {
        return {error_code::kDataOutOfRange, "cycles above the device's max_cycles"};
      }
    }
  }
  // Confined to the data directory, a new directory every time (never a symlink followed, never
  // a file overwritten).
  std::string error;
  std::error_code mkdir_error;  // the configured data directory itself may be created
  std::filesystem::create_directories(config_.recording.data_dir, mkdir_error);
  const std::string path = create_dataset_dir(config_.recording.data_dir, dir, error);
  if (path.empty()) return {error_code::kDataOutOfRange, "SWEEP: " + error};
  auto job = std::make_unique<SweepJob>();
  try {
    job->writer.emplace(path, config_.stage);
  } catch (const std::exception& e) {
    return {error_code::kExecutionError, std::string("cannot create the dataset: ") + e.what()};
  }
  job->dir = path;
  job->freqs_hz = freqs_hz;
  job->duties = duties;
  job->trials = trials;
  job->cycles = cycles;
  job->stroke_m = stroke;
  {
    std::lock_guard<std::mutex> lock(recorder_mutex_);
    sweep_abort_.store(false);
    sweep_active_.store(true, std::memory_order_release);
    pending_job_ = std::move(job);
  }
  recorder_cv_.notify_all();
  return {};
}

// The recorder is also the daemon's housekeeping thread: it saves the calibration after the moves
// that changed it, and finishes a *RST that had to wait for a sweep.
void Daemon::recorder_main() {
  for (;;) {
    std::unique_ptr<SweepJob> job;
    {
      std::unique_lock<std::mutex> lock(recorder_mutex_);
      recorder_cv_.wait_for(lock, std::chrono::milliseconds(100), [&] {
        return recorder_quit_ || pending_job_ || reset_pending_.load(std::memory_order_acquire);
      });
      if (!pending_job_ && recorder_quit_) return;
      job = std::move(pending_job_);
    }
    if (job) {
      run_sweep(*job);
      std::lock_guard<std::mutex> lock(recorder_mutex_);
      sweep_active_.store(false, std::memory_order_release);
    }
    if (reset_pending_.load(std::memory_order_acquire)) {
      std::string error;
      if (!reload_control(error, SoftLimits::Keep)) {
        set_housekeeping_error("*RST: " + error);
        add_note("*RST after the sweep: " + error);
      }
      reset_pending_.store(false, std::memory_order_release);
    }
    save_calibration_if_changed();
  }
}

void Daemon::run_sweep(SweepJob& job) {
  const auto& caps = device_.output->capabilities();
  const bool buffered = caps.mode == drivers::OutputMode::BufferedSamples;
  drivers::PositionDecoder decoder(device_.interferometer->capabilities().word);
  const double stream_rate = device_.interferometer->capabilities().stream_rate_hz;
  std::size_t written = 0, failed = 0;
  std::string first_error;
  double sweep_start_m = kNaN, last_m = kNaN;
  std::uint32_t index = 0;
  bool aborted = false;

  for (double f_req : job.freqs_hz) {
    for (double d_req : job.duties) {
      for (int t = 0; t < job.trials && !aborted; ++t, ++index) {
        if (sweep_abort_.load()) {
          aborted = true;
          break;
        }
        TrialRequest req;
        req.index = index;
        req.stroke_m = job.stroke_m;
        req.cycles = static_cast<std::uint32_t>(job.cycles);
        if (buffered) {
          const auto w = control::snap_to_sample_clock(limits_.output_sample_rate_hz, f_req, d_req);
          req.freq_hz = w.freq_hz;
          req.duty = w.duty;
          req.period_samples = w.period_samples;
          req.extension_samples = w.extension_samples;
          const double rate = w.freq_hz * w.period_samples;
          req.rest_samples = static_cast<std::uint32_t>(std::lround(config_.recording.sweep_rest_s * rate));
          req.settle_samples = static_cast<std::uint32_t>(config_.recording.sweep_settle_cycles) * w.period_samples;
        } else {
          req.freq_hz = f_req;
          req.duty = d_req;
        }
        req.return_to_m = kNaN;
        if (std::isfinite(sweep_start_m) && std::isfinite(last_m) &&
            std::fabs(last_m - sweep_start_m) > config_.recording.sweep_span_m) {
          req.return_to_m = sweep_start_m;
        }
        while (!trial_requests_.push(req)) sleep_s(1e-3);

        // Collect the trial's records.
        model::TriangleWave wave;
        wave.freq_hz = req.freq_hz;
        wave.duty = req.duty;
        wave.stroke_m = req.stroke_m;
        wave.cycles = static_cast<int>(req.cycles);
        recording::TrialSeries series;
        recording::TrialInfo info;
        info.freq_hz = req.freq_hz;
        info.duty = req.duty;
        info.stroke_m = req.stroke_m;
        info.cycles = static_cast<int>(req.cycles);
        info.sample_rate_hz = stream_rate;
        double t0 = 0;
        bool ok = true, finished = false;
        TrialFailure why = TrialFailure::None;
        while (!finished) {
          TrialRecord rec;
          if (!trial_records_.pop(rec)) {
            sleep_s(5e-4);
            continue;
          }
          switch (rec.event) {
            case TrialEvent::Begin: {
              decoder.reset();
              const drivers::PositionSample s = decoder.decode(rec.word);
              ok = s.valid();
              info.guide_pos_m = s.position_m;
              t0 = rec.t_s;
              break;
            }
            case TrialEvent::Sample: {
              const drivers::PositionSample s = decoder.decode(rec.word);
              if (!s.valid()) ok = false;
              const double t = rec.t_s - t0;
              if (!series.t_s.empty() && !(t > series.t_s.back())) break;
              series.t_s.push_back(t);
              series.xi_cmd_m.push_back(wave.xi_m(t));
              series.x_m.push_back(s.position_m);
              break;
            }
            case TrialEvent::End: finished = true; break;
            case TrialEvent::Failed:
              finished = true;
              ok = false;
              why = static_cast<TrialFailure>(rec.word);
              break;
          }
        }
        if (why == TrialFailure::Stopped) {
          aborted = true;
          break;
        }
        if (ok && series.size() >= 2) {
          try {
            job.writer->add_trial(info, series);
            ++written;
            if (!std::isfinite(sweep_start_m)) sweep_start_m = info.guide_pos_m;
            last_m = series.x_m.back();
          } catch (const std::exception& e) {
            ++failed;
            if (first_error.empty()) first_error = e.what();
          }
        } else {
          ++failed;
          if (first_error.empty()) {
            static const char* const kWhy[] = {"invalid interferometer samples", "positioning failed",
                                               "driver error", "sample queue overflow", "stopped",
                                               "motion in progress"};
            first_error = std::string("trial ") + std::to_string(index) + ": " +
                          kWhy[static_cast<int>(why)];
          }
        }
      }
    }
  }
  std::ostringstream report;
  report << "sweep " << job.dir << ": " << written << " trials written, " << failed << " failed"
         << (aborted ? ", stopped" : "") << (first_error.empty() ? "" : " (first: " + first_error + ")");
  if (failed > 0) set_housekeeping_error(report.str());
  std::lock_guard<std::mutex> lock(recorder_mutex_);
  sweep_report_ = report.str();
}

}  // namespace idm::daemon
