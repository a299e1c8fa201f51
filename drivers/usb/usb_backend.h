// `daq.driver: usb`: the USB bridge (README.md beside this file) behind both interfaces, over
// UsbTransport. The output is hardware-timed buffered output: a burst's samples become DAC codes,
// go out as waveform blocks, and START plays them; the interferometer's stream is the position
// records the bridge latches during the burst and its tail; latch() is the LATCH request (a
// bridge whose firmware stalls it gives `unsupported`).
#pragma once

#include <yaml-cpp/yaml.h>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "drivers/config.h"
#include "drivers/interfaces.h"
#include "drivers/usb/transport.h"

namespace idm::drivers::usb {

struct UsbDeviceConfig {
  UsbTransportConfig transport;
  OutputCapabilities output;  // buffered samples; limits narrowed by GET_INFO at configure
  InterferometerConfig interferometer;
  double position_rate_hz = 1e5;  // the bridge's position latch rate during a burst
  double tail_s = 2e-3;           // positions latched after the burst's last sample
};

// The keys of `daq.usb:` (the transport's, the bridge's and the output capability keys).
const model::ParamTable<UsbDeviceConfig>& usb_device_params();

// `interferometer:` and `daq.usb:` (the transport keys, position_rate_hz, tail_s and the output
// capability keys). Unknown keys: errors with file:line.
UsbDeviceConfig parse_usb_device_yaml(const YAML::Node& root, const std::string& file);

// DAC code of an elongation: round(xi * volts_per_m / lsb_V), lsb_V = (max - min) V / 2^bits,
// clamped to the signed range of `bits` (code 0 is 0 V).
std::int32_t dac_code(double xi_m, const OutputCapabilities& caps);
// The position records of a burst as stream samples: t from the first record, in ticks / tick_hz;
// `lost` marks the first record with sample-overrun (samples before it are missing).
void records_to_stream(const PositionRecord* records, std::size_t n, std::uint64_t first_tick,
                       double tick_hz, bool lost, TimedWord* out);

// The state both interfaces share: the transport and the burst bookkeeping.
struct UsbShared {
  explicit UsbShared(const UsbDeviceConfig& c) : config(c), transport(c.transport) {}
  UsbDeviceConfig config;
  UsbTransport transport;
  int users = 0;
  std::uint64_t bursts_started = 0;  // the stream restarts when this changes
  // The count epoch: the bridge's clock counts from its power-up, so the host time of that
  // power-up moves when (and only when) the bridge restarted (and its axis board with it).
  bool have_power_up = false;
  double power_up_host_s = 0;
  std::uint64_t count_epoch = 0;  // the power-up's second (as an unsigned of the signed value)
  DriverStatus open();
  void close();
};

class UsbOutput final : public WaveformOutput {
 public:
  explicit UsbOutput(std::shared_ptr<UsbShared> shared);
  const OutputCapabilities& capabilities() const override { return caps_; }

 private:
  DriverStatus on_configure() override;
  DriverStatus on_activate() override { return shared_->transport.stop(); }
  DriverStatus on_deactivate() override { return shared_->transport.stop(); }
  DriverStatus on_shutdown() override;
  DriverStatus do_write_burst(const double* xi_m, std::size_t n, double rate_hz) override;
  DriverStatus do_write_burst_parameters(const model::TriangleWave& wave) override;
  DriverStatus do_start() override;
  DriverStatus do_stop() override { return shared_->transport.stop(); }
  DriverStatus do_is_done(bool& done) override;

  std::shared_ptr<UsbShared> shared_;
  OutputCapabilities caps_;
  std::vector<std::int32_t> codes_;
  double rate_hz_ = 0.0;
};

class UsbInterferometer final : public Interferometer {
 public:
  explicit UsbInterferometer(std::shared_ptr<UsbShared> shared);
  const InterferometerCapabilities& capabilities() const override { return caps_; }

 private:
  DriverStatus on_configure() override;
  DriverStatus on_activate() override { return DriverStatus::success(); }
  DriverStatus on_deactivate() override { return DriverStatus::success(); }
  DriverStatus on_shutdown() override;
  DriverStatus do_latch(std::uint64_t& word) override;
  DriverStatus do_read_stream(TimedWord* out, std::size_t capacity, std::size_t& n) override;
  DriverStatus do_count_epoch(std::uint64_t& epoch) override;

  std::shared_ptr<UsbShared> shared_;
  InterferometerCapabilities caps_;
  std::uint64_t burst_seen_ = 0;
  bool stream_done_ = true;
  bool have_first_tick_ = false;
  std::uint64_t first_tick_ = 0;
  bool lost_pending_ = false;
  std::vector<PositionRecord> pending_;
  std::size_t pending_read_ = 0;
};

Device make_usb_device(const UsbDeviceConfig& config);
Device make_usb_device(const YAML::Node& root, const std::string& file);

}  // namespace idm::drivers::usb
