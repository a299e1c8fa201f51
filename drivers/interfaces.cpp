#include "drivers/interfaces.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "drivers/clock.h"
#include "model/range.h"
#include "model/stage.h"
#include "model/yaml_util.h"

namespace idm::drivers {

namespace {
DriverStatus invalid(std::string message) {
  return DriverStatus::failure(DriverError::InvalidArgument, std::move(message));
}
}  // namespace

const char* driver_error_name(DriverError error) {
  switch (error) {
    case DriverError::None:
      return "none";
    case DriverError::InvalidState:
      return "invalid_state";
    case DriverError::InvalidArgument:
      return "invalid_argument";
    case DriverError::Unsupported:
      return "unsupported";
    case DriverError::NoDevice:
      return "no_device";
    case DriverError::PermissionDenied:
      return "permission_denied";
    case DriverError::Disconnected:
      return "disconnected";
    case DriverError::Timeout:
      return "timeout";
    case DriverError::DeviceError:
      return "device_error";
    case DriverError::ProtocolError:
      return "protocol_error";
  }
  return "?";
}

DriverStatus DriverStatus::failure(DriverError error, std::string message) {
  DriverStatus s;
  s.error = error == DriverError::None ? DriverError::DeviceError : error;
  s.message = std::move(message);
  return s;
}

const char* lifecycle_state_name(LifecycleState state) {
  switch (state) {
    case LifecycleState::Unconfigured:
      return "unconfigured";
    case LifecycleState::Inactive:
      return "inactive";
    case LifecycleState::Active:
      return "active";
    case LifecycleState::Finalized:
      return "finalized";
  }
  return "?";
}

// ---- HardwareComponent ----

DriverStatus HardwareComponent::tagged(const char* call, DriverStatus status) const {
  if (!status.ok()) status.message = name_ + ": " + call + ": " + status.message;
  return status;
}

DriverStatus HardwareComponent::require_state(const char* call, bool allow_inactive) const {
  if (state_ == LifecycleState::Active) return DriverStatus::success();
  if (allow_inactive && state_ == LifecycleState::Inactive) return DriverStatus::success();
  return tagged(call,
                DriverStatus::failure(
                    DriverError::InvalidState,
                    std::string("not allowed in state ") + lifecycle_state_name(state_) +
                        (allow_inactive ? " (needs inactive or active)" : " (needs active)")));
}

DriverStatus HardwareComponent::configure() {
  if (state_ != LifecycleState::Unconfigured)
    return tagged("configure", DriverStatus::failure(DriverError::InvalidState,
                                                     std::string("not allowed in state ") +
                                                         lifecycle_state_name(state_) +
                                                         " (needs unconfigured)"));
  DriverStatus s = on_configure();
  if (s.ok()) state_ = LifecycleState::Inactive;
  return tagged("configure", std::move(s));
}

DriverStatus HardwareComponent::activate() {
  if (state_ != LifecycleState::Inactive)
    return tagged("activate",
                  DriverStatus::failure(DriverError::InvalidState,
                                        std::string("not allowed in state ") +
                                            lifecycle_state_name(state_) + " (needs inactive)"));
  DriverStatus s = on_activate();
  if (s.ok()) state_ = LifecycleState::Active;
  return tagged("activate", std::move(s));
}

DriverStatus HardwareComponent::deactivate() {
  if (state_ != LifecycleState::Active)
    return tagged("deactivate",
                  DriverStatus::failure(DriverError::InvalidState,
                                        std::string("not allowed in state ") +
                                            lifecycle_state_name(state_) + " (needs active)"));
  DriverStatus s = on_deactivate();
  if (s.ok()) state_ = LifecycleState::Inactive;
  return tagged("deactivate", std::move(s));
}

DriverStatus HardwareComponent::shutdown() {
  DriverStatus first;
  if (state_ == LifecycleState::Finalized) return first;
  if (state_ == LifecycleState::Active) first = tagged("shutdown", on_deactivate());
  if (state_ != LifecycleState::Unconfigured) {
    DriverStatus s = tagged("shutdown", on_shutdown());
    if (first.ok()) first = std::move(s);
  }
  state_ = LifecycleState::Finalized;
  return first;
}

void HardwareComponent::cleanup() {
  if (state_ == LifecycleState::Finalized || state_ == LifecycleState::Unconfigured) return;
  if (state_ == LifecycleState::Active) on_deactivate();
  on_shutdown();
  state_ = LifecycleState::Unconfigured;
}

// ---- Capabilities ----

const char* output_mode_name(OutputMode mode) {
  return mode == OutputMode::BufferedSamples ? "samples" : "parameters";
}

double OutputCapabilities::lsb_m() const {
  return (max_voltage_v - min_voltage_v) / std::ldexp(1.0, static_cast<int>(resolution_bits)) /
         volts_per_m;
}

void validate(const OutputCapabilities& c, const std::string& where) {
  using model::check_range;
  check_range(c.max_sample_rate_hz > 0 && c.max_sample_rate_hz <= 1e9, where, "max_sample_rate_hz",
              c.max_sample_rate_hz, "(0, 1e9]");
  check_range(c.max_burst_samples >= 2 && c.max_burst_samples <= (std::size_t{1} << 28), where,
              "max_burst_samples", static_cast<double>(c.max_burst_samples), "[2, 268435456]");
  check_range(c.resolution_bits >= 1 && c.resolution_bits <= 32, where, "resolution_bits",
              c.resolution_bits, "[1, 32]");
  check_range(c.min_voltage_v <= 0 && c.min_voltage_v >= -1000, where, "min_voltage_v",
              c.min_voltage_v, "[-1000, 0]");
  check_range(c.max_voltage_v > 0 && c.max_voltage_v <= 1000, where, "max_voltage_v",
              c.max_voltage_v, "(0, 1000]");
  check_range(c.volts_per_m > 0 && c.volts_per_m <= 1e12, where, "volts_per_m", c.volts_per_m,
              "(0, 1e12]");
  check_range(c.max_freq_hz > 0 && c.max_freq_hz <= 1e7, where, "max_freq_hz", c.max_freq_hz,
              "(0, 1e7]");
  check_range(c.max_cycles >= 1, where, "max_cycles", c.max_cycles, "[1, 4294967295]");
}

// ---- WaveformOutput ----

DriverStatus WaveformOutput::write_burst(const double* xi_m, std::size_t n, double rate_hz) {
  const char* call = "write_burst";
  if (DriverStatus s = require_state(call, false); !s.ok()) return s;
  const OutputCapabilities& c = capabilities();
  if (c.mode != OutputMode::BufferedSamples)
    return tagged(call, DriverStatus::failure(DriverError::Unsupported,
                                              "this output takes burst parameters only "
                                              "(capabilities: parameters); use "
                                              "write_burst_parameters"));
  if (xi_m == nullptr || n < 2 || n > c.max_burst_samples)
    return tagged(call, invalid(std::to_string(n) + " samples, allowed [2, " +
                                std::to_string(c.max_burst_samples) + "]"));
  if (!(std::isfinite(rate_hz) && rate_hz > 0 && rate_hz <= c.max_sample_rate_hz))
    return tagged(call, invalid("sample_rate_hz " + model::format_number(rate_hz) +
                                " is out of range, allowed (0, " +
                                model::format_number(c.max_sample_rate_hz) + "]"));
  const double lo = c.min_elongation_m(), hi = c.max_elongation_m(), lsb = c.lsb_m();
  for (std::size_t k = 0; k < n; ++k) {
    if (!std::isfinite(xi_m[k]) || xi_m[k] < lo - 1e-3 * lsb || xi_m[k] > hi + 1e-3 * lsb)
      return tagged(
          call, invalid("sample " + std::to_string(k) + ": " + model::format_number(xi_m[k]) +
                        " m is outside the output range [" + model::format_number(lo) + ", " +
                        model::format_number(hi) + "] m (" + model::format_number(c.min_voltage_v) +
                        " .. " + model::format_number(c.max_voltage_v) + " V at " +
                        model::format_number(c.volts_per_m) + " V/m)"));
  }
  if (std::fabs(xi_m[0]) > lsb || std::fabs(xi_m[n - 1]) > lsb)
    return tagged(
        call, invalid("the burst must start and end at 0 (first " + model::format_number(xi_m[0]) +
                      " m, last " + model::format_number(xi_m[n - 1]) + " m, one DAC step " +
                      model::format_number(lsb) + " m)"));
  return tagged(call, do_write_burst(xi_m, n, rate_hz));
}

DriverStatus WaveformOutput::write_burst_parameters(const model::TriangleWave& wave) {
  const char* call = "write_burst_parameters";
  if (DriverStatus s = require_state(call, false); !s.ok()) return s;
  const OutputCapabilities& c = capabilities();
  if (c.mode != OutputMode::BurstParameters)
    return tagged(call, DriverStatus::failure(DriverError::Unsupported,
                                              "this output takes buffered samples only "
                                              "(capabilities: samples); use write_burst"));
  try {
    model::validate(wave);
  } catch (const model::InputError& e) {
    return tagged(call, invalid(e.what()));
  }
  if (wave.freq_hz > c.max_freq_hz)
    return tagged(call, invalid("freq_hz " + model::format_number(wave.freq_hz) +
                                " is out of range, allowed (0, " +
                                model::format_number(c.max_freq_hz) + "]"));
  if (wave.cycles < 1 || static_cast<std::uint64_t>(wave.cycles) > c.max_cycles)
    return tagged(
        call, invalid("cycles " + std::to_string(wave.cycles) + " is out of range, allowed [1, " +
                      std::to_string(c.max_cycles) + "]"));
  if (wave.stroke_m > c.max_elongation_m() * (1 + 1e-12))
    return tagged(call, invalid("stroke_m " + model::format_number(wave.stroke_m) +
                                " is outside the output range, allowed (0, " +
                                model::format_number(c.max_elongation_m()) + "]"));
  return tagged(call, do_write_burst_parameters(wave));
}

DriverStatus WaveformOutput::start() {
  if (DriverStatus s = require_state("start", false); !s.ok()) return s;
  return tagged("start", do_start());
}

DriverStatus WaveformOutput::stop() {
  if (DriverStatus s = require_state("stop", true); !s.ok()) return s;
  return tagged("stop", do_stop());
}

DriverStatus WaveformOutput::is_done(bool& done) {
  if (DriverStatus s = require_state("is_done", true); !s.ok()) return s;
  return tagged("is_done", do_is_done(done));
}

DriverStatus WaveformOutput::wait_done(double timeout_s) {
  if (DriverStatus s = require_state("wait_done", true); !s.ok()) return s;
  if (!(std::isfinite(timeout_s) && timeout_s >= 0))
    return tagged("wait_done", invalid("timeout_s " + model::format_number(timeout_s) +
                                       " must be finite and >= 0"));
  return tagged("wait_done", do_wait_done(timeout_s));
}

DriverStatus WaveformOutput::do_wait_done(double timeout_s) {
  const double deadline = monotonic_s() + timeout_s;
  for (;;) {
    bool done = false;
    if (DriverStatus s = do_is_done(done); !s.ok()) return s;
    if (done) return DriverStatus::success();
    const double now = monotonic_s();
    if (now >= deadline)
      return DriverStatus::failure(
          DriverError::Timeout,
          "the burst is not done after " + model::format_number(timeout_s) + " s");
    sleep_until_s(std::min(now + poll_interval_s(), deadline));
  }
}

// ---- Interferometer ----

DriverStatus Interferometer::latch(std::uint64_t& word) {
  if (DriverStatus s = require_state("latch", true); !s.ok()) return s;
  return tagged("latch", do_latch(word));
}

DriverStatus Interferometer::read_stream(TimedWord* out, std::size_t capacity, std::size_t& n) {
  n = 0;
  if (DriverStatus s = require_state("read_stream", true); !s.ok()) return s;
  if (out == nullptr && capacity > 0)
    return tagged("read_stream", invalid("null buffer with capacity " + std::to_string(capacity)));
  return tagged("read_stream", do_read_stream(out, capacity, n));
}

DriverStatus Interferometer::count_epoch(std::uint64_t& epoch) {
  if (DriverStatus s = require_state("count_epoch", true); !s.ok()) return s;
  return tagged("count_epoch", do_count_epoch(epoch));
}

DriverStatus Interferometer::do_count_epoch(std::uint64_t&) {
  return DriverStatus::failure(DriverError::Unsupported,
                               "the device cannot tell whether it kept its position count");
}

// ---- Device ----

namespace {
bool both(const Device& d) {
  return d.output && d.interferometer;
}
DriverStatus missing(const Device& d) {
  return DriverStatus::failure(DriverError::InvalidState,
                               "device '" + d.driver + "' is missing an interface");
}
}  // namespace

DriverStatus Device::configure() {
  if (!both(*this)) return missing(*this);
  if (DriverStatus s = interferometer->configure(); !s.ok()) return s;
  return output->configure();
}

DriverStatus Device::activate() {
  if (!both(*this)) return missing(*this);
  if (DriverStatus s = interferometer->activate(); !s.ok()) return s;
  return output->activate();
}

DriverStatus Device::deactivate() {
  if (!both(*this)) return missing(*this);
  if (DriverStatus s = output->deactivate(); !s.ok()) return s;
  return interferometer->deactivate();
}

void Device::cleanup() {
  if (output) output->cleanup();
  if (interferometer) interferometer->cleanup();
}

DriverStatus Device::shutdown() {
  DriverStatus first;
  if (output) first = output->shutdown();
  if (interferometer) {
    DriverStatus s = interferometer->shutdown();
    if (first.ok()) first = std::move(s);
  }
  return first;
}

}  // namespace idm::drivers
