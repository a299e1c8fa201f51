#include "drivers/usb/usb_backend.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "drivers/clock.h"
#include "model/range.h"
#include "model/yaml_util.h"

namespace idm::drivers::usb {

using model::InputError;
using model::located;

namespace {

std::string fault_names(std::uint16_t flags) {
  static constexpr const char* kNames[] = {"underrun",       "position_overflow", "crc_error",
                                           "sequence_error", "bad_config",        "axis_error"};
  std::string out;
  for (unsigned bit = 0; bit < 6; ++bit)
    if (flags & (1u << bit)) out += (out.empty() ? "" : "+") + std::string(kNames[bit]);
  return out.empty() ? "none" : out;
}

}  // namespace

const model::ParamTable<UsbDeviceConfig>& usb_device_params() {
  using C = UsbDeviceConfig;
  static const model::ParamTable<C> table(model::join<C>({
      model::lifted<C>(
          usb_transport_params(), [](auto& c) -> auto& { return c.transport; }),
      {
          model::real<C>(
              "position_rate_hz", "Hz", {1, 1e8}, "the bridge's position latch rate during a burst",
              [](auto& c) -> auto& { return c.position_rate_hz; }),
          model::real<C>(
              "tail_s", "s", {0, 10}, "positions latched after a burst's last sample",
              [](auto& c) -> auto& { return c.tail_s; }),
      },
      model::lifted<C>(
          output_capability_params(), [](auto& c) -> auto& { return c.output; }),
  }));
  return table;
}

UsbDeviceConfig parse_usb_device_yaml(const YAML::Node& root, const std::string& file) {
  UsbDeviceConfig c;
  c.interferometer = parse_interferometer_yaml(root, file);
  const YAML::Node node = detail::child(detail::child(root, "daq"), "usb");
  if (const YAML::Node ch = detail::child(root, "channel");
      detail::present(ch) && ch.as<std::string>() != "0")
    throw InputError(located(file, ch, "channel",
                             "the USB bridge has one channel (0); give each "
                             "axis on USB its own device"));
  usb_device_params().read(node, file, "daq.usb", c);
  try {
    validate(c.output, "daq.usb");
  } catch (const InputError& e) {
    throw InputError(located(file, node, "daq.usb", e.what()));
  }
  c.output.mode = OutputMode::BufferedSamples;
  return c;
}

std::int32_t dac_code(double xi_m, const OutputCapabilities& caps) {
  const double lsb_v = (caps.max_voltage_v - caps.min_voltage_v) /
                       std::ldexp(1.0, static_cast<int>(caps.resolution_bits));
  const double hi = std::ldexp(1.0, static_cast<int>(caps.resolution_bits) - 1) - 1;
  const double code = std::clamp(std::round(xi_m * caps.volts_per_m / lsb_v), -hi - 1, hi);
  return static_cast<std::int32_t>(code);
}

void records_to_stream(const PositionRecord* records, std::size_t n, std::uint64_t first_tick,
                       double tick_hz, bool lost, TimedWord* out) {
  for (std::size_t i = 0; i < n; ++i) {
    out[i].t_s = static_cast<double>(records[i].timestamp_ticks - first_tick) / tick_hz;
    out[i].word = records[i].position_word;
  }
  if (lost && n > 0) out[0].word |= position_word::kSampleOverrun;
}

DriverStatus UsbShared::open() {
  if (users == 0)
    if (DriverStatus s = transport.open(); !s.ok()) return s;
  ++users;
  return DriverStatus::success();
}

void UsbShared::close() {
  if (users > 0 && --users == 0) transport.close();
}

// ---- UsbOutput ----

UsbOutput::UsbOutput(std::shared_ptr<UsbShared> shared)
    : WaveformOutput("usb waveform output (" + device_text(shared->config.transport) + ")"),
      shared_(std::move(shared)),
      caps_(shared_->config.output) {}

DriverStatus UsbOutput::on_configure() {
  if (DriverStatus s = shared_->open(); !s.ok()) return s;
  const BridgeInfo& info = shared_->transport.info();
  caps_ = shared_->config.output;
  caps_.mode = OutputMode::BufferedSamples;
  caps_.max_sample_rate_hz = std::min(caps_.max_sample_rate_hz, double(info.max_dac_rate_hz));
  caps_.max_burst_samples =
      std::min<std::size_t>(caps_.max_burst_samples, info.buffer_capacity_samples);
  caps_.resolution_bits = info.dac_bits;
  if (caps_.max_burst_samples < 2) {
    shared_->close();
    return DriverStatus::failure(DriverError::DeviceError,
                                 "the bridge reports a buffer of " +
                                     std::to_string(info.buffer_capacity_samples) + " samples");
  }
  return DriverStatus::success();
}

DriverStatus UsbOutput::on_shutdown() {
  shared_->close();
  return DriverStatus::success();
}

DriverStatus UsbOutput::do_write_burst(const double* xi_m, std::size_t n, double rate_hz) {
  if (std::fabs(rate_hz - std::round(rate_hz)) > 1e-9 * rate_hz)
    return DriverStatus::failure(
        DriverError::InvalidArgument,
        "the bridge's DAC clock takes whole hertz, not " + model::format_number(rate_hz));
  codes_.resize(n);
  for (std::size_t k = 0; k < n; ++k) codes_[k] = dac_code(xi_m[k], caps_);
  rate_hz_ = rate_hz;
  return DriverStatus::success();
}

DriverStatus UsbOutput::do_write_burst_parameters(const model::TriangleWave&) {
  return DriverStatus::failure(DriverError::Unsupported,
                               "the USB bridge plays buffered samples only");
}

DriverStatus UsbOutput::do_start() {
  if (codes_.empty())
    return DriverStatus::failure(DriverError::InvalidState, "no burst loaded (write_burst first)");
  const UsbDeviceConfig& c = shared_->config;
  BridgeConfig bc;
  bc.dac_sample_rate_hz = static_cast<std::uint32_t>(std::lround(rate_hz_));
  bc.burst_samples = static_cast<std::uint32_t>(codes_.size());
  bc.position_sample_rate_hz = static_cast<std::uint32_t>(std::lround(c.position_rate_hz));
  bc.tail_samples = static_cast<std::uint32_t>(std::lround(c.tail_s * c.position_rate_hz));
  bc.dac_format = caps_.resolution_bits <= 16 ? SampleFormat::DacInt16 : SampleFormat::DacInt32;
  UsbTransport& t = shared_->transport;
  if (DriverStatus s = t.configure(bc); !s.ok()) return s;
  if (DriverStatus s = t.send_waveform(codes_, bc.dac_format); !s.ok()) return s;
  if (DriverStatus s = t.start(); !s.ok()) return s;
  ++shared_->bursts_started;
  return DriverStatus::success();
}

DriverStatus UsbOutput::do_is_done(bool& done) {
  BridgeStatus status;
  if (DriverStatus s = shared_->transport.get_status(status); !s.ok()) return s;
  if (status.state == BridgeState::Fault || status.fault_flags != 0)
    return DriverStatus::failure(DriverError::DeviceError,
                                 "the bridge reports a fault: " + fault_names(status.fault_flags));
  done = status.state != BridgeState::Running;
  return DriverStatus::success();
}

// ---- UsbInterferometer ----

UsbInterferometer::UsbInterferometer(std::shared_ptr<UsbShared> shared)
    : Interferometer("usb interferometer (" + device_text(shared->config.transport) + ")"),
      shared_(std::move(shared)) {
  caps_.word = shared_->config.interferometer.word;
  caps_.stream_rate_hz = shared_->config.position_rate_hz;
  caps_.word.sample_interval_s = 1.0 / caps_.stream_rate_hz;
  caps_.stream_capacity = std::size_t{1} << 20;
}

DriverStatus UsbInterferometer::on_configure() {
  if (DriverStatus s = shared_->open(); !s.ok()) return s;
  const BridgeInfo& info = shared_->transport.info();
  DriverStatus s;
  if (info.position_word_bits != static_cast<unsigned>(caps_.word.width))
    s = DriverStatus::failure(DriverError::InvalidArgument,
                              "the bridge sends " + std::to_string(info.position_word_bits) +
                                  "-bit words but interferometer.word_bits is " +
                                  std::to_string(static_cast<unsigned>(caps_.word.width)));
  else if (caps_.stream_rate_hz > info.max_position_rate_hz)
    s = DriverStatus::failure(
        DriverError::InvalidArgument,
        "daq.usb.position_rate_hz " + model::format_number(caps_.stream_rate_hz) +
            " exceeds the bridge's " + std::to_string(info.max_position_rate_hz) + " Hz");
  if (!s.ok()) shared_->close();
  return s;
}

DriverStatus UsbInterferometer::on_shutdown() {
  shared_->close();
  return DriverStatus::success();
}

DriverStatus UsbInterferometer::do_count_epoch(std::uint64_t& epoch) {
  BridgeStatus status;
  if (DriverStatus s = shared_->transport.get_status(status); !s.ok()) return s;
  const double tick_hz = static_cast<double>(shared_->transport.info().tick_hz);
  const double power_up = monotonic_s() - static_cast<double>(status.device_time_ticks) / tick_hz;
  // More than a second apart: the bridge's clock started over (drift and USB latency are far
  // below that). The epoch is the power-up's second on the host's CLOCK_MONOTONIC, so that a
  // restarted idmd finds the same one while the bridge kept running (unless its clock drifted
  // across a second's edge meanwhile: then the reference is not restored, never wrongly kept).
  if (!shared_->have_power_up || std::fabs(power_up - shared_->power_up_host_s) > 1.0)
    shared_->count_epoch = static_cast<std::uint64_t>(std::llround(power_up));
  shared_->have_power_up = true;
  shared_->power_up_host_s = power_up;
  epoch = shared_->count_epoch;
  return DriverStatus::success();
}

DriverStatus UsbInterferometer::do_latch(std::uint64_t& word) {
  PositionRecord record;
  if (DriverStatus s = shared_->transport.latch(record); !s.ok()) return s;
  word = record.position_word;
  return DriverStatus::success();
}

DriverStatus UsbInterferometer::do_read_stream(TimedWord* out, std::size_t capacity,
                                               std::size_t& n) {
  n = 0;
  if (shared_->bursts_started != burst_seen_) {
    burst_seen_ = shared_->bursts_started;
    stream_done_ = false;
    have_first_tick_ = false;
    lost_pending_ = false;
    pending_.clear();
    pending_read_ = 0;
  }
  const double tick_hz = static_cast<double>(shared_->transport.info().tick_hz);
  while (n < capacity) {
    if (pending_read_ < pending_.size()) {
      const std::size_t k = std::min(capacity - n, pending_.size() - pending_read_);
      if (!have_first_tick_) {
        first_tick_ = pending_[pending_read_].timestamp_ticks;
        have_first_tick_ = true;
      }
      records_to_stream(pending_.data() + pending_read_, k, first_tick_, tick_hz, lost_pending_,
                        out + n);
      lost_pending_ = false;
      pending_read_ += k;
      n += k;
      continue;
    }
    if (stream_done_) break;
    pending_.clear();
    pending_read_ = 0;
    PositionTransfer info;
    if (DriverStatus s = shared_->transport.receive_positions(pending_, info); !s.ok()) return s;
    lost_pending_ = lost_pending_ || info.lost;
    stream_done_ = info.last;
    if (pending_.empty() && !info.last) break;
  }
  return DriverStatus::success();
}

Device make_usb_device(const UsbDeviceConfig& config) {
  Device d;
  d.driver = "usb";
  auto shared = std::make_shared<UsbShared>(config);
  d.output = std::make_unique<UsbOutput>(shared);
  d.interferometer = std::make_unique<UsbInterferometer>(shared);
  return d;
}

Device make_usb_device(const YAML::Node& root, const std::string& file) {
  return make_usb_device(parse_usb_device_yaml(root, file));
}

}  // namespace idm::drivers::usb
