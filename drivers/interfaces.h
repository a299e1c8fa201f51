// The hardware interfaces the daemon drives: WaveformOutput (the actuator's waveform) and
// Interferometer (the slider's position words), their lifecycle, and the Device bundle that the
// name->factory table in backends.h returns.
//
// Lifecycle (as in ros2_control's hardware components):
//
//   construct (parse the config, no I/O; a bad config throws model::InputError)
//     -> configure()   Unconfigured -> Inactive: open the device
//     -> activate()    Inactive -> Active: output enabled
//     -> deactivate()  Active -> Inactive: output to zero, disabled
//     -> shutdown()    any -> Finalized: close (deactivates first when active)
//     cleanup()        any but Finalized -> Unconfigured: close, to configure again (reconnect)
//
// Every step and every call returns a DriverStatus: ok, or an error code and a message that says
// which component, which call and what failed ("sim waveform output: start: no burst loaded").
// A failed step leaves the state as it was (shutdown always ends Finalized). Calls in the wrong
// state fail with DriverError::InvalidState. One owner per device: copy and move are deleted.
//
// The public calls are non-virtual: they check the state and the arguments (sample rate, burst
// length, output range, burst parameters) once for every backend, then call the backend's do_*.
// Not thread-safe: one thread drives a device.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>

#include "drivers/position_word.h"
#include "model/waveform.h"

namespace idm::drivers {

enum class DriverError : std::uint8_t {
  None = 0,
  InvalidState,      // the call is not allowed in the component's lifecycle state
  InvalidArgument,   // the caller's arguments are out of range (nothing was sent)
  Unsupported,       // the device cannot do this (see the capabilities)
  NoDevice,          // the device is not there (connection refused, not found)
  PermissionDenied,  // the device is there but may not be opened
  Disconnected,      // the device went away; later calls try to reconnect where they can
  Timeout,           // the device did not answer in time
  DeviceError,       // the device answered with an error (exception, fault flag)
  ProtocolError,     // the device's answer is malformed
};

// "invalid_state", "timeout", ...
const char* driver_error_name(DriverError error);

struct DriverStatus {
  DriverError error = DriverError::None;
  std::string message;  // empty when ok

  bool ok() const { return error == DriverError::None; }
  static DriverStatus success() { return {}; }
  static DriverStatus failure(DriverError error, std::string message);
};

enum class LifecycleState : std::uint8_t { Unconfigured, Inactive, Active, Finalized };
// "unconfigured", "inactive", "active", "finalized".
const char* lifecycle_state_name(LifecycleState state);

class HardwareComponent {
 public:
  virtual ~HardwareComponent() = default;
  HardwareComponent(const HardwareComponent&) = delete;
  HardwareComponent& operator=(const HardwareComponent&) = delete;
  HardwareComponent(HardwareComponent&&) = delete;
  HardwareComponent& operator=(HardwareComponent&&) = delete;

  DriverStatus configure();
  DriverStatus activate();
  DriverStatus deactivate();
  DriverStatus shutdown();
  // Back to Unconfigured from any state but Finalized (deactivates and closes first, failures
  // ignored): a lost device is cleaned up this way before it is configured again.
  void cleanup();

  LifecycleState state() const { return state_; }
  // What this is, for messages: "sim waveform output", "modbus interferometer (127.0.0.1:1502)".
  const std::string& name() const { return name_; }

 protected:
  explicit HardwareComponent(std::string name) : name_(std::move(name)) {}

  virtual DriverStatus on_configure() = 0;
  virtual DriverStatus on_activate() = 0;
  virtual DriverStatus on_deactivate() = 0;
  virtual DriverStatus on_shutdown() = 0;

  // InvalidState unless the state is one of the allowed ones.
  DriverStatus require_state(const char* call, bool allow_inactive) const;
  // Prefixes a backend's failure with "NAME: CALL: " (success passes through).
  DriverStatus tagged(const char* call, DriverStatus status) const;

 private:
  std::string name_;
  LifecycleState state_ = LifecycleState::Unconfigured;
};

// ---- Waveform output ----

enum class OutputMode : std::uint8_t {
  BufferedSamples,  // hardware-timed buffered output: takes the burst as samples (write_burst)
  BurstParameters,  // a function generator: takes f, duty, stroke, cycles (write_burst_parameters)
};
const char* output_mode_name(OutputMode mode);  // "samples", "parameters"

struct OutputCapabilities {
  OutputMode mode = OutputMode::BufferedSamples;
  double max_sample_rate_hz = 1e6;           // buffered: highest DAC clock
  std::size_t max_burst_samples = 1u << 20;  // buffered: largest burst
  unsigned resolution_bits = 16;             // DAC resolution
  double min_voltage_v = -10.0;              // output range
  double max_voltage_v = 10.0;
  double volts_per_m = 2.5e5;          // output volts per metre of actuator elongation
  double max_freq_hz = 1e5;            // parameters: highest burst frequency
  std::uint32_t max_cycles = 1000000;  // parameters: most cycles in one burst

  // The elongations the voltage range allows.
  double min_elongation_m() const { return min_voltage_v / volts_per_m; }
  double max_elongation_m() const { return max_voltage_v / volts_per_m; }
  // One DAC step in metres of elongation.
  double lsb_m() const;
};

// Throws model::InputError naming the key when a capability is out of range (backends call it
// on their parsed config).
void validate(const OutputCapabilities& caps, const std::string& where);

class WaveformOutput : public HardwareComponent {
 public:
  virtual const OutputCapabilities& capabilities() const = 0;

  // Buffered devices: loads a whole burst, the commanded actuator elongation xi_m[k] played at
  // t = k / sample_rate_hz after start(). The burst must start and end at 0 (within one DAC step),
  // every sample must lie in the output range, n >= 2, n <= max_burst_samples and
  // 0 < sample_rate_hz <= max_sample_rate_hz. Active only.
  DriverStatus write_burst(const double* xi_m, std::size_t n, double sample_rate_hz);
  // Parameter devices: loads a burst of wave.cycles triangle cycles (model/waveform.h). The
  // stroke must lie in the output range, 0 < freq <= max_freq_hz, 1 <= cycles <= max_cycles.
  // Active only.
  DriverStatus write_burst_parameters(const model::TriangleWave& wave);
  // Plays the loaded burst from its start. Active only.
  DriverStatus start();
  // Ends any burst at once and brings the output to zero (the safe state). Inactive or active.
  DriverStatus stop();
  // done: no burst is playing (the last one finished, was stopped, or none was started).
  DriverStatus is_done(bool& done);
  // Blocks until done or timeout_s has passed (Timeout), sleeping with clock_nanosleep on
  // absolute deadlines. For tools and tests; the real-time loop polls is_done().
  DriverStatus wait_done(double timeout_s);

 protected:
  using HardwareComponent::HardwareComponent;
  virtual DriverStatus do_write_burst(const double* xi_m, std::size_t n, double sample_rate_hz) = 0;
  virtual DriverStatus do_write_burst_parameters(const model::TriangleWave& wave) = 0;
  virtual DriverStatus do_start() = 0;
  virtual DriverStatus do_stop() = 0;
  virtual DriverStatus do_is_done(bool& done) = 0;
  // Default: polls do_is_done every poll_interval_s() until done or the deadline.
  virtual DriverStatus do_wait_done(double timeout_s);
  virtual double poll_interval_s() const { return 1e-3; }
};

// ---- Interferometer ----

// One sample of the stream captured during a burst: t_s on the device's clock, seconds from the
// burst's first output sample; word in the raw layout of position_word.h.
struct TimedWord {
  double t_s = 0.0;
  std::uint64_t word = 0;
};

struct InterferometerCapabilities {
  // The words' format: width, optics, wavelength, air index, and sample_interval_s = the stream's
  // sample interval (a decoder for the stream is PositionDecoder(word)).
  PositionWordConfig word;
  double stream_rate_hz = 1e5;             // rate of the burst stream
  std::size_t stream_capacity = 1u << 20;  // samples the device keeps until they are read
  // The scale has an index mark: words carry position_word::kReferenceMark on crossing it
  // (REFerence MARK needs it). Only the simulated device has one (sim.reference_mark_m).
  bool reference_mark = false;
};

class Interferometer : public HardwareComponent {
 public:
  virtual const InterferometerCapabilities& capabilities() const = 0;

  // Latches the position now and reads the raw word. Inactive or active.
  DriverStatus latch(std::uint64_t& word);
  // Moves the samples captured since the last read (oldest first) into out[0..n), n <= capacity.
  // The stream restarts at every start() of the device's output; n = 0 when nothing is waiting.
  // On an error, out[0..n) still holds the samples moved before it. Inactive or active.
  DriverStatus read_stream(TimedWord* out, std::size_t capacity, std::size_t& n);
  // An identifier of the device's position count that changes whenever the device may have lost
  // it (a power cycle, a counter reset): equal before and after a reconnect means the count went
  // on. Unsupported when the device cannot tell (then a reconnect is taken as having lost it).
  // Inactive or active.
  DriverStatus count_epoch(std::uint64_t& epoch);

 protected:
  using HardwareComponent::HardwareComponent;
  virtual DriverStatus do_latch(std::uint64_t& word) = 0;
  virtual DriverStatus do_read_stream(TimedWord* out, std::size_t capacity, std::size_t& n) = 0;
  virtual DriverStatus do_count_epoch(std::uint64_t& epoch);
};

// ---- One device: both interfaces, one owner ----

namespace sim {
class SimBackend;
}

// The two interfaces of one device. They share the device's connection (held by both through a
// shared owner inside the backend); the bundle owns both. Movable, not copyable.
struct Device {
  std::string driver;  // "sim", "modbus", "usb"
  std::unique_ptr<WaveformOutput> output;
  std::unique_ptr<Interferometer> interferometer;
  // The simulated stage behind a `sim` device (fault injection, synthetic time); null otherwise.
  std::shared_ptr<sim::SimBackend> sim;

  // Lifecycle of both, stopping at the first failure: the interferometer is configured and
  // activated first and deactivated last, so that positions are readable while the output moves.
  DriverStatus configure();
  DriverStatus activate();
  DriverStatus deactivate();
  DriverStatus shutdown();  // both, always; the first failure is returned
  void cleanup();           // both back to unconfigured (to reconnect)
};

}  // namespace idm::drivers
