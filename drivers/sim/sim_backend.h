// The simulated stage as a full backend (`daq.driver: sim`): model::SimulatedStage behind both
// interfaces. The output plays the daemon's burst through the plant (samples at the burst's rate,
// the command linear between samples; or burst parameters with exact corners); the interferometer
// produces raw words with the PositionEncoder from the model's sensor reading (noise, then one
// count of quantization), read back by the caller through the same PositionDecoder as real words.
//
// Clocks: synthetic (start() plays the whole burst at once, as fast as it runs; time moves only
// through bursts and advance_s) or wall (the simulation catches up with CLOCK_MONOTONIC at every
// call, so the burst plays in real time; wait_done sleeps with clock_nanosleep to the burst's end).
// Seeded and deterministic: the same config and calls give the same words.
//
// Reference mark (sim.reference_mark_m): the words report crossing it with bit 45 (see
// check_mark below and drivers/README.md).
//
// Faults, from the config (`daq.sim.faults`) or at run time: beam loss, glitches, a stalled
// slider, a friction jump, a disconnected device, timeouts. Not thread-safe (one caller thread).
#pragma once

#include <yaml-cpp/yaml.h>

#include <cstdint>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "drivers/config.h"
#include "drivers/interfaces.h"
#include "model/simulation.h"

namespace idm::drivers::sim {

enum class ClockMode : std::uint8_t { Synthetic, Wall };
const char* clock_mode_name(ClockMode mode);  // "synthetic", "wall"

struct SimFaults {
  bool beam_lost = false;           // every word carries measurement-signal-lost
  double glitch_probability = 0.0;  // per word: a wild count (off by 2^20 .. 2^24 counts)
  bool glitch_flagged = true;       // a glitch word carries the board's glitch bit
  bool slider_stalled = false;      // the slider is held (plant().set_slider_held)
  double friction_scale = 1.0;      // kinetic friction coefficient times this
  bool disconnected = false;        // every call fails (Disconnected) until reconnect
  bool timeouts = false;            // latch and read_stream time out
};

struct SimDeviceConfig {
  model::StageParams stage;
  model::SimConfig sim;  // plant, effects, seed, noise_m (the `sim:` section)
  InterferometerConfig interferometer;
  ClockMode clock = ClockMode::Synthetic;
  OutputCapabilities output;    // mode and limits the simulated output reports
  double stream_rate_hz = 1e5;  // burst stream sample rate
  std::size_t stream_capacity = 1u << 20;
  double settle_s = 2e-3;     // the plant runs (and the stream records) this long after
                              // the burst's last sample before the burst is done
  double stop_ramp_s = 1e-4;  // stop(): the output ramps to zero over this time
  double timeout_s = 0.1;     // an injected timeout waits this long (wall clock only)
  SimFaults faults;
};

// The keys of `daq.sim:` (with the output capability keys) and of its `faults:` map.
const model::ParamTable<SimDeviceConfig>& sim_device_params();
const model::ParamTable<SimFaults>& sim_fault_params();

// Reads `stage:`, `interferometer:`, `sim:` (model::parse_sim_yaml) and `daq.sim:` of root.
// Unknown keys and out-of-range values throw InputError with file:line.
SimDeviceConfig parse_sim_device_yaml(const YAML::Node& root, const std::string& file);

class SimOutput;
class SimInterferometer;
class SimBackend;

// Stacked stages couple: a step of one axis's slider displaces the sliders of the others by
// `fraction` of it (the devices of one simulated card share one group). Not thread-safe: the
// group's backends are driven from one thread (the card's I/O thread).
class SimCrosstalk {
 public:
  explicit SimCrosstalk(double fraction) : fraction_(fraction) {}
  void add(SimBackend* backend) { members_.push_back(backend); }
  double fraction() const { return fraction_; }
  // `source` moved by dx_m: the others are displaced by fraction dx_m.
  void moved(const SimBackend* source, double dx_m);

 private:
  double fraction_;
  std::vector<SimBackend*> members_;
};

// The device behind both interfaces. Tests and tools reach it through Device::sim for fault
// injection and time; the interfaces reach it for everything else.
class SimBackend {
 public:
  explicit SimBackend(const SimDeviceConfig& config);  // validates; no I/O
  SimBackend(const SimBackend&) = delete;
  SimBackend& operator=(const SimBackend&) = delete;

  // ---- fault injection at run time ----
  void set_beam_lost(bool lost) { faults_.beam_lost = lost; }
  void set_glitch_probability(double probability, bool flagged = true);  // [0, 1]
  void set_slider_stalled(bool stalled);
  void set_friction_scale(double scale);  // (0, 100]
  // Aborts a running burst (the output ramps to zero), then every call fails until reconnect().
  // The device keeps its state (a cable pulled): after reconnect its count goes on.
  void disconnect();
  void reconnect() { faults_.disconnected = false; }
  // A power cycle: disconnected like disconnect(), and once reconnected it starts over (slider
  // at sim.start_position_m, the count from there) with a new count_epoch.
  void power_cycle();
  std::uint64_t count_epoch() const { return count_epoch_; }
  static std::uint64_t fresh_count_epoch();
  // An external push (SIMulation:PUSH): the slider moves by dx_m at once, stops permitting.
  void push(double dx_m);
  // Crosstalk (stacked stages): every move of this slider displaces the others of the group.
  void set_crosstalk(std::shared_ptr<class SimCrosstalk> group) { crosstalk_ = std::move(group); }
  void set_timeouts(bool on) { faults_.timeouts = on; }
  const SimFaults& faults() const { return faults_; }

  // ---- time and truth ----
  // Simulated seconds since the device was opened (configure).
  double now_s() const { return t_s_; }
  // Lets dt_s pass with the output as it is (a running burst goes on). Synthetic clock only.
  void advance_s(double dt_s);
  double true_position_m() const { return stage_.position_m(); }
  double commanded_elongation_m() const { return xi_cmd_m_; }
  model::SimulatedStage& stage() { return stage_; }
  const SimDeviceConfig& config() const { return config_; }
  bool running() const { return running_; }
  // Stream samples dropped because the buffer was full since the last start().
  std::uint64_t stream_dropped() const { return stream_dropped_; }
  // Wall clock: how far the simulation may fall behind it before it runs slow, and the wall time
  // it has dropped so far (0 while it keeps up).
  static constexpr double kMaxLagS = 0.1;
  double wall_time_dropped_s() const { return dropped_s_; }

 private:
  friend class SimOutput;
  friend class SimInterferometer;

  DriverStatus open();
  void close();
  DriverStatus check_connected() const;
  DriverStatus check_timeout();
  void sync();                  // wall clock: catch up with CLOCK_MONOTONIC
  void advance_to(double t_s);  // the plant, then the crosstalk of what it moved
  void advance_plant_to(double t_s);
  double command_at(double t_s) const;
  void capture(double t_rel_s);
  std::uint64_t make_word();
  void abort_burst();
  // The reference mark: the side of sim.reference_mark_m the slider is on, checked after every
  // plant step and at every word; a change arms the mark bit of the next word produced.
  int mark_side() const;
  void check_mark();

  DriverStatus load_samples(const double* xi_m, std::size_t n, double sample_rate_hz);
  DriverStatus load_parameters(const model::TriangleWave& wave);
  DriverStatus start();
  DriverStatus stop();
  DriverStatus is_done(bool& done);
  DriverStatus wait_done(double timeout_s);
  DriverStatus latch(std::uint64_t& word);
  DriverStatus read_stream(TimedWord* out, std::size_t capacity, std::size_t& n);

  SimDeviceConfig config_;
  model::SimulatedStage stage_;
  PositionEncoder encoder_;
  double base_kinetic_friction_;
  SimFaults faults_;
  std::mt19937_64 fault_rng_;

  int users_ = 0;         // open interfaces
  bool powered_ = false;  // opened since construction or the last power cycle
  // Drawn at construction: the simulated device lives inside its process, so a restarted idmd's
  // device counts afresh and must not look like the one an earlier run saved a reference with.
  std::uint64_t count_epoch_ = fresh_count_epoch();
  std::shared_ptr<class SimCrosstalk> crosstalk_;
  double epoch_s_ = 0.0;  // CLOCK_MONOTONIC at open (wall clock), plus the time dropped
  double dropped_s_ = 0.0;
  double t_s_ = 0.0;       // simulated time
  double xi_cmd_m_ = 0.0;  // output now

  // The loaded burst as breakpoints of a piecewise-linear command, times from the burst start.
  std::vector<double> burst_t_s_, burst_xi_m_;
  bool running_ = false;
  double t0_s_ = 0.0, end_s_ = 0.0;
  std::size_t next_breakpoint_ = 0;
  std::uint64_t next_capture_ = 0;
  int mark_side_ = 0;          // -1 below the mark, +1 at or above it; 0 without a mark
  bool mark_pending_ = false;  // crossed since the last word: the next word carries the mark

  std::vector<TimedWord> stream_;
  std::size_t stream_read_ = 0;
  std::uint64_t stream_dropped_ = 0;
};

class SimOutput final : public WaveformOutput {
 public:
  explicit SimOutput(std::shared_ptr<SimBackend> backend);
  const OutputCapabilities& capabilities() const override { return backend_->config_.output; }

 private:
  DriverStatus on_configure() override { return backend_->open(); }
  DriverStatus on_activate() override { return backend_->check_connected(); }
  DriverStatus on_deactivate() override { return backend_->stop(); }
  DriverStatus on_shutdown() override;
  DriverStatus do_write_burst(const double* xi_m, std::size_t n, double rate_hz) override {
    return backend_->load_samples(xi_m, n, rate_hz);
  }
  DriverStatus do_write_burst_parameters(const model::TriangleWave& wave) override {
    return backend_->load_parameters(wave);
  }
  DriverStatus do_start() override { return backend_->start(); }
  DriverStatus do_stop() override { return backend_->stop(); }
  DriverStatus do_is_done(bool& done) override { return backend_->is_done(done); }
  DriverStatus do_wait_done(double timeout_s) override { return backend_->wait_done(timeout_s); }
  std::shared_ptr<SimBackend> backend_;
};

class SimInterferometer final : public Interferometer {
 public:
  explicit SimInterferometer(std::shared_ptr<SimBackend> backend);
  const InterferometerCapabilities& capabilities() const override { return caps_; }

 private:
  DriverStatus on_configure() override { return backend_->open(); }
  DriverStatus on_activate() override { return backend_->check_connected(); }
  DriverStatus on_deactivate() override { return DriverStatus::success(); }
  DriverStatus on_shutdown() override;
  DriverStatus do_latch(std::uint64_t& word) override { return backend_->latch(word); }
  DriverStatus do_count_epoch(std::uint64_t& epoch) override {
    if (DriverStatus s = backend_->check_connected(); !s.ok()) return s;
    epoch = backend_->count_epoch();
    return DriverStatus::success();
  }
  DriverStatus do_read_stream(TimedWord* out, std::size_t capacity, std::size_t& n) override {
    return backend_->read_stream(out, capacity, n);
  }
  std::shared_ptr<SimBackend> backend_;
  InterferometerCapabilities caps_;
};

// Both interfaces over one SimBackend (Device::sim is set).
Device make_sim_device(const SimDeviceConfig& config);
// The factory of the `sim` entry: make_sim_device(parse_sim_device_yaml(root, file)).
Device make_sim_device(const YAML::Node& root, const std::string& file);

}  // namespace idm::drivers::sim
