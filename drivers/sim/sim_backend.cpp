#include "drivers/sim/sim_backend.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <sstream>

#include "drivers/clock.h"
#include "model/range.h"
#include "model/yaml_util.h"

namespace idm::drivers::sim {

using model::InputError;
using model::located;
using model::read_bool;
using model::read_double;
using model::read_integer;
using model::read_string;

namespace {

model::InterferometerParams sensor_of(const SimDeviceConfig& c) {
  // The model's sensor quantizes to one count of the codec, so the encoder's rounding of the
  // reading is exact.
  model::InterferometerParams p = c.interferometer.sensor;
  p.resolution_m = c.interferometer.word.count_m();
  return p;
}

PositionWordConfig word_of(const SimDeviceConfig& c) {
  PositionWordConfig w = c.interferometer.word;
  w.sample_interval_s = 1.0 / c.stream_rate_hz;
  return w;
}

void validate(const SimDeviceConfig& c) {
  const std::string where = "daq.sim";
  sim_device_params().validate(c, where);
  validate(c.output, where);
  validate(word_of(c), "interferometer");
}

DriverStatus disconnected_error() {
  return DriverStatus::failure(DriverError::Disconnected,
                               "the simulated device is disconnected (injected fault; "
                               "reconnect() restores it)");
}

}  // namespace

const char* clock_mode_name(ClockMode mode) {
  return mode == ClockMode::Synthetic ? "synthetic" : "wall";
}

const model::ParamTable<SimFaults>& sim_fault_params() {
  using F = SimFaults;
  static const model::ParamTable<F> table({
      model::boolean<F>(
          "beam_lost", "every word carries measurement-signal-lost",
          [](auto& f) -> auto& { return f.beam_lost; }),
      model::real<F>(
          "glitch_probability", "1", {0, 1}, "per word: a wild count (off by 2^20 .. 2^24 counts)",
          [](auto& f) -> auto& { return f.glitch_probability; }),
      model::boolean<F>(
          "glitch_flagged", "a glitch word carries the board's glitch bit",
          [](auto& f) -> auto& { return f.glitch_flagged; }),
      model::boolean<F>(
          "slider_stalled", "the slider is held (it does not move)",
          [](auto& f) -> auto& { return f.slider_stalled; }),
      model::real<F>(
          "friction_scale", "1", {0, 100, true}, "kinetic friction coefficient times this",
          [](auto& f) -> auto& { return f.friction_scale; }),
      model::boolean<F>(
          "disconnected", "every call fails (Disconnected) until reconnect",
          [](auto& f) -> auto& { return f.disconnected; }),
      model::boolean<F>(
          "timeouts", "latch and read_stream time out",
          [](auto& f) -> auto& { return f.timeouts; }),
  });
  return table;
}

const model::ParamTable<SimDeviceConfig>& sim_device_params() {
  using C = SimDeviceConfig;
  static const model::ParamTable<C> table(model::join<C>({
      {
          model::choice<C, ClockMode>(
              "clock", {{"synthetic", ClockMode::Synthetic}, {"wall", ClockMode::Wall}},
              "synthetic: time advances as the device is driven; wall: real time",
              [](auto& c) -> auto& { return c.clock; }),
          model::choice<C, OutputMode>(
              "output",
              {{"samples", OutputMode::BufferedSamples},
               {"parameters", OutputMode::BurstParameters}},
              "the output it reports: buffered DAC samples or burst parameters",
              [](auto& c) -> auto& { return c.output.mode; }),
          model::real<C>(
              "stream_rate_hz", "Hz", {0, 1e8, true}, "the burst stream's sample rate",
              [](auto& c) -> auto& { return c.stream_rate_hz; }),
          model::integer<C>(
              "stream_capacity", "count", 1, 1L << 28, "samples the stream buffer holds",
              [](auto& c) -> auto& { return c.stream_capacity; }),
          model::real<C>(
              "settle_s", "s", {0, 10},
              "the plant runs (and the stream records) this long after a burst's last sample",
              [](auto& c) -> auto& { return c.settle_s; }),
          model::real<C>(
              "stop_ramp_s", "s", {0, 1, true}, "a stop ramps the output to zero over this time",
              [](auto& c) -> auto& { return c.stop_ramp_s; }),
          model::real<C>(
              "timeout_s", "s", {0, 60}, "an injected timeout waits this long (wall clock only)",
              [](auto& c) -> auto& { return c.timeout_s; }),
          model::nested<C>(
              "faults", "injected faults (daq.sim.faults below)", sim_fault_params(),
              [](auto& c) -> auto& { return c.faults; }),
      },
      model::lifted<C>(
          output_capability_params(), [](auto& c) -> auto& { return c.output; }),
  }));
  return table;
}

SimDeviceConfig parse_sim_device_yaml(const YAML::Node& root, const std::string& file) {
  SimDeviceConfig c;
  const bool has_root = detail::present(root);
  if (has_root && !root.IsMap()) throw InputError(file + ": expected a YAML map");
  c.stage = model::parse_stage_yaml(has_root ? root : YAML::Node(YAML::NodeType::Map), file).stage;
  c.interferometer = parse_interferometer_yaml(root, file);
  const YAML::Node sim = detail::child(root, "sim");
  if (detail::present(sim)) c.sim = model::parse_sim_yaml(sim, file);
  const YAML::Node node = detail::child(detail::child(root, "daq"), "sim");
  if (!detail::present(node)) {
    validate(c);
    return c;
  }
  sim_device_params().read(node, file, "daq.sim", c);
  try {
    validate(c);
  } catch (const InputError& e) {
    throw InputError(located(file, node, "daq.sim", e.what()));
  }
  return c;
}

// ---- SimCrosstalk ----

void SimCrosstalk::moved(const SimBackend* source, double dx_m) {
  for (SimBackend* m : members_)
    if (m != source) m->stage().displace(fraction_ * dx_m);
}

// ---- SimBackend ----

SimBackend::SimBackend(const SimDeviceConfig& config)
    : config_((validate(config), config)),
      stage_(config.stage, sensor_of(config), config.sim),
      encoder_(word_of(config)),
      base_kinetic_friction_(stage_.plant().friction().kinetic_coefficient),
      faults_(config.faults) {
  set_slider_stalled(faults_.slider_stalled);
  set_friction_scale(faults_.friction_scale);
}

void SimBackend::set_glitch_probability(double probability, bool flagged) {
  model::check_range(probability >= 0 && probability <= 1, "sim", "glitch_probability", probability,
                     "[0, 1]");
  faults_.glitch_probability = probability;
  faults_.glitch_flagged = flagged;
}

void SimBackend::set_slider_stalled(bool stalled) {
  faults_.slider_stalled = stalled;
  stage_.plant().set_slider_held(stalled);
}

void SimBackend::set_friction_scale(double scale) {
  model::check_range(scale > 0 && scale <= 100, "sim", "friction_scale", scale, "(0, 100]");
  faults_.friction_scale = scale;
  stage_.plant().friction().kinetic_coefficient = base_kinetic_friction_ * scale;
}

void SimBackend::disconnect() {
  if (users_ > 0) {
    sync();
    abort_burst();
  }
  faults_.disconnected = true;
}

std::uint64_t SimBackend::fresh_count_epoch() {
  std::random_device entropy;
  return (static_cast<std::uint64_t>(entropy()) << 32) ^ entropy();
}

void SimBackend::power_cycle() {
  if (users_ > 0) {
    sync();
    abort_burst();
  }
  powered_ = false;  // the next open starts over from the start position
  ++count_epoch_;
  faults_.disconnected = true;
}

void SimBackend::push(double dx_m) {
  if (users_ > 0) sync();
  const double before = stage_.position_m();
  stage_.displace(dx_m);
  check_mark();
  if (crosstalk_) crosstalk_->moved(this, stage_.position_m() - before);
}

void SimBackend::advance_s(double dt_s) {
  model::check_range(dt_s >= 0 && dt_s <= 1e4, "sim", "advance_s", dt_s, "[0, 1e4]");
  if (config_.clock != ClockMode::Synthetic)
    throw InputError("sim: advance_s: only with the synthetic clock (the wall clock moves itself)");
  advance_to(t_s_ + dt_s);
}

DriverStatus SimBackend::open() {
  if (faults_.disconnected) return disconnected_error();
  if (users_++ > 0) return DriverStatus::success();
  if (!powered_) {
    // Power on: the slider at its start, the count from there. A re-open after a disconnect
    // finds the device as it was (it kept its count, and the slider where it is).
    stage_.reset(config_.sim.start_position_m, config_.sim.seed);
    stage_.plant().set_slider_held(faults_.slider_stalled);
    fault_rng_.seed(config_.sim.seed * 0x9E3779B97F4A7C15ull + 0x5EED);
    mark_side_ = mark_side();
    mark_pending_ = false;
    t_s_ = 0.0;
    epoch_s_ = monotonic_s();
    powered_ = true;
  } else {
    sync();
  }
  xi_cmd_m_ = 0.0;
  running_ = false;
  burst_t_s_.clear();
  burst_xi_m_.clear();
  burst_t_s_.reserve(config_.output.max_burst_samples);
  burst_xi_m_.reserve(config_.output.max_burst_samples);
  stream_.clear();
  stream_.reserve(config_.stream_capacity);
  stream_read_ = 0;
  return DriverStatus::success();
}

void SimBackend::close() {
  if (users_ > 0 && --users_ == 0) {
    running_ = false;
    xi_cmd_m_ = 0.0;
  }
}

DriverStatus SimBackend::check_connected() const {
  return faults_.disconnected ? disconnected_error() : DriverStatus::success();
}

DriverStatus SimBackend::check_timeout() {
  if (!faults_.timeouts) return DriverStatus::success();
  // Not slept: the caller learns at once (a real device would keep it waiting timeout_s).
  return DriverStatus::failure(DriverError::Timeout, "no answer from the simulated device within " +
                                                         model::format_number(config_.timeout_s) +
                                                         " s (injected timeout)");
}

void SimBackend::sync() {
  if (config_.clock != ClockMode::Wall) return;
  // A plant that cannot keep up with the wall clock (the compliant actuator on a loaded machine,
  // or under a sanitizer) would fall ever further behind, and every call, a stop and the last one
  // at shutdown included, would wait for all of it to be simulated. It runs slow instead: never
  // more than kMaxLagS behind; the wall time beyond that is dropped (wall_time_dropped_s()).
  const double behind_s = monotonic_s() - epoch_s_ - t_s_;
  if (behind_s > kMaxLagS) {
    epoch_s_ += behind_s - kMaxLagS;
    dropped_s_ += behind_s - kMaxLagS;
  }
  advance_to(monotonic_s() - epoch_s_);
}

double SimBackend::command_at(double t_s) const {
  const std::size_t n = burst_t_s_.size();
  if (next_breakpoint_ >= n) return burst_xi_m_[n - 1];
  const std::size_t k = next_breakpoint_;
  const double ta = t0_s_ + burst_t_s_[k - 1], tb = t0_s_ + burst_t_s_[k];
  const double u = tb > ta ? (t_s - ta) / (tb - ta) : 1.0;
  return burst_xi_m_[k - 1] + (burst_xi_m_[k] - burst_xi_m_[k - 1]) * std::clamp(u, 0.0, 1.0);
}

void SimBackend::advance_to(double target_s) {
  const double before = stage_.position_m();
  advance_plant_to(target_s);
  if (crosstalk_) {
    const double moved = stage_.position_m() - before;
    if (moved != 0.0) crosstalk_->moved(this, moved);
  }
}

void SimBackend::advance_plant_to(double target_s) {
  while (t_s_ < target_s) {
    double t_next = target_s;
    if (running_) {
      if (next_breakpoint_ < burst_t_s_.size())
        t_next = std::min(t_next, t0_s_ + burst_t_s_[next_breakpoint_]);
      t_next =
          std::min(t_next, t0_s_ + static_cast<double>(next_capture_) / config_.stream_rate_hz);
      t_next = std::min(t_next, end_s_);
    }
    const double xi = running_ ? command_at(t_next) : xi_cmd_m_;
    if (t_next > t_s_) {
      stage_.step(t_next - t_s_, xi);
      check_mark();
    }
    t_s_ = t_next;
    xi_cmd_m_ = xi;
    if (!running_) continue;
    while (next_breakpoint_ < burst_t_s_.size() && t0_s_ + burst_t_s_[next_breakpoint_] <= t_s_)
      ++next_breakpoint_;
    const double t_capture = t0_s_ + static_cast<double>(next_capture_) / config_.stream_rate_hz;
    if (t_capture <= t_s_ && t_capture <= end_s_) {
      capture(t_capture - t0_s_);
      ++next_capture_;
    }
    if (t_s_ >= end_s_) running_ = false;
  }
}

int SimBackend::mark_side() const {
  const double mark = config_.sim.reference_mark_m;
  if (std::isnan(mark)) return 0;
  return stage_.position_m() >= mark ? 1 : -1;
}

void SimBackend::check_mark() {
  const int side = mark_side();
  if (side != mark_side_) {
    mark_side_ = side;
    mark_pending_ = true;
  }
}

std::uint64_t SimBackend::make_word() {
  check_mark();  // a push or another axis's crosstalk may have moved the slider
  std::int64_t count = encoder_.counts_from_m(stage_.measured_m());
  std::uint64_t status = position_word::kValid;
  if (mark_pending_) {
    status |= position_word::kReferenceMark;
    mark_pending_ = false;
  }
  if (faults_.beam_lost) status |= position_word::kMeasurementSignalLost;
  if (faults_.glitch_probability > 0 &&
      std::uniform_real_distribution<double>(0.0, 1.0)(fault_rng_) < faults_.glitch_probability) {
    const std::int64_t size = std::int64_t{1} << (20 + fault_rng_() % 5);
    count += (fault_rng_() & 1u) ? size : -size;
    if (faults_.glitch_flagged) status |= position_word::kGlitch;
  }
  return encoder_.encode_count(count, status);
}

void SimBackend::capture(double t_rel_s) {
  const std::uint64_t word = make_word();
  if (stream_.size() < stream_.capacity()) {
    stream_.push_back({t_rel_s, word});
  } else {
    ++stream_dropped_;
    if (!stream_.empty()) stream_.back().word |= position_word::kSampleOverrun;
    if ((word & position_word::kReferenceMark) != 0) mark_pending_ = true;  // for the next word
  }
}

void SimBackend::abort_burst() {
  if (!running_) return;
  running_ = false;
  // The output ramps from where it is to zero.
  stage_.step(config_.stop_ramp_s, 0.0);
  check_mark();
  t_s_ += config_.stop_ramp_s;
  xi_cmd_m_ = 0.0;
}

DriverStatus SimBackend::load_samples(const double* xi_m, std::size_t n, double rate_hz) {
  if (DriverStatus s = check_connected(); !s.ok()) return s;
  sync();
  if (running_)
    return DriverStatus::failure(DriverError::InvalidState, "a burst is playing; stop() it first");
  burst_t_s_.resize(n);
  burst_xi_m_.assign(xi_m, xi_m + n);
  for (std::size_t k = 0; k < n; ++k) burst_t_s_[k] = static_cast<double>(k) / rate_hz;
  return DriverStatus::success();
}

DriverStatus SimBackend::load_parameters(const model::TriangleWave& wave) {
  if (DriverStatus s = check_connected(); !s.ok()) return s;
  sync();
  if (running_)
    return DriverStatus::failure(DriverError::InvalidState, "a burst is playing; stop() it first");
  burst_t_s_.clear();
  burst_xi_m_.clear();
  burst_t_s_.push_back(0.0);
  burst_xi_m_.push_back(0.0);
  for (double t : wave.corner_times_s()) {
    if (t <= burst_t_s_.back()) continue;
    burst_t_s_.push_back(t);
    burst_xi_m_.push_back(wave.xi_m(t));
  }
  // The corner at the burst's end: the command is back at 0.
  burst_xi_m_.back() = 0.0;
  if (burst_t_s_.size() < 2) {
    burst_t_s_.push_back(0.0);
    burst_xi_m_.push_back(0.0);
  }
  return DriverStatus::success();
}

DriverStatus SimBackend::start() {
  if (DriverStatus s = check_connected(); !s.ok()) return s;
  sync();
  if (running_)
    return DriverStatus::failure(DriverError::InvalidState, "a burst is playing; stop() it first");
  if (burst_t_s_.size() < 2)
    return DriverStatus::failure(DriverError::InvalidState, "no burst loaded (write_burst first)");
  stream_.clear();
  stream_read_ = 0;
  stream_dropped_ = 0;
  running_ = true;
  t0_s_ = t_s_;
  end_s_ = t0_s_ + burst_t_s_.back() + config_.settle_s;
  next_breakpoint_ = 1;
  capture(0.0);
  next_capture_ = 1;
  if (config_.clock == ClockMode::Synthetic) advance_to(end_s_);
  return DriverStatus::success();
}

DriverStatus SimBackend::stop() {
  if (DriverStatus s = check_connected(); !s.ok()) return s;
  sync();
  abort_burst();
  return DriverStatus::success();
}

DriverStatus SimBackend::is_done(bool& done) {
  if (DriverStatus s = check_connected(); !s.ok()) return s;
  sync();
  done = !running_;
  return DriverStatus::success();
}

DriverStatus SimBackend::wait_done(double timeout_s) {
  if (DriverStatus s = check_connected(); !s.ok()) return s;
  sync();
  if (!running_) return DriverStatus::success();
  // Only the wall clock can be running here: sleep to the burst's end (or the deadline).
  const double now = monotonic_s();
  const double end_wall = epoch_s_ + end_s_;
  sleep_until_s(std::min(end_wall, now + timeout_s));
  sync();
  if (running_)
    return DriverStatus::failure(DriverError::Timeout,
                                 "the burst is not done after " + model::format_number(timeout_s) +
                                     " s (it ends " + model::format_number(end_s_ - t_s_) +
                                     " s later)");
  return DriverStatus::success();
}

DriverStatus SimBackend::latch(std::uint64_t& word) {
  if (DriverStatus s = check_connected(); !s.ok()) return s;
  if (DriverStatus s = check_timeout(); !s.ok()) return s;
  sync();
  word = make_word();
  return DriverStatus::success();
}

DriverStatus SimBackend::read_stream(TimedWord* out, std::size_t capacity, std::size_t& n) {
  n = 0;
  if (DriverStatus s = check_connected(); !s.ok()) return s;
  if (DriverStatus s = check_timeout(); !s.ok()) return s;
  sync();
  n = std::min(capacity, stream_.size() - stream_read_);
  std::copy_n(stream_.begin() + static_cast<std::ptrdiff_t>(stream_read_), n, out);
  stream_read_ += n;
  if (stream_read_ == stream_.size() && !running_) {
    stream_.clear();
    stream_read_ = 0;
  }
  return DriverStatus::success();
}

// ---- the two interfaces ----

SimOutput::SimOutput(std::shared_ptr<SimBackend> backend)
    : WaveformOutput(std::string("sim waveform output (") +
                     clock_mode_name(backend->config().clock) + " clock)"),
      backend_(std::move(backend)) {}

DriverStatus SimOutput::on_shutdown() {
  backend_->close();
  return DriverStatus::success();
}

SimInterferometer::SimInterferometer(std::shared_ptr<SimBackend> backend)
    : Interferometer("sim interferometer"), backend_(std::move(backend)) {
  caps_.word = word_of(backend_->config());
  caps_.stream_rate_hz = backend_->config().stream_rate_hz;
  caps_.stream_capacity = backend_->config().stream_capacity;
  caps_.reference_mark = !std::isnan(backend_->config().sim.reference_mark_m);
}

DriverStatus SimInterferometer::on_shutdown() {
  backend_->close();
  return DriverStatus::success();
}

Device make_sim_device(const SimDeviceConfig& config) {
  Device d;
  d.driver = "sim";
  d.sim = std::make_shared<SimBackend>(config);
  d.output = std::make_unique<SimOutput>(d.sim);
  d.interferometer = std::make_unique<SimInterferometer>(d.sim);
  return d;
}

Device make_sim_device(const YAML::Node& root, const std::string& file) {
  return make_sim_device(parse_sim_device_yaml(root, file));
}

}  // namespace idm::drivers::sim
