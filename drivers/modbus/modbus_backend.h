// `daq.driver: modbus`: a libmodbus (Modbus TCP) client for a waveform generator with a position
// counter, described by a register map (register_map.h). The output takes burst parameters
// (frequency, duty, stroke, cycles); the interferometer reads the latched position record and
// the records the device captured during the burst.
//
// Errors: a refused connection is no_device, no answer within timeout_s is timeout, an exception
// response is device_error with the exception's name, a malformed answer protocol_error, a
// dropped connection disconnected. After a timeout, a malformed answer or a dropped connection
// the socket is closed and the next call reconnects; reads and idempotent writes (parameters,
// STOP) reconnect and retry once at once when the connection was found dropped, START never.
#pragma once

#include <yaml-cpp/yaml.h>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "drivers/config.h"
#include "drivers/interfaces.h"
#include "drivers/modbus/register_map.h"

typedef struct _modbus modbus_t;

namespace idm::drivers::modbus {

struct ModbusConfig {
  std::string host = "127.0.0.1";
  int port = 502;
  int unit_id = 1;                // of channel 0; channel k of a card is unit unit_id + k
  double timeout_s = 0.5;         // response (and connect) timeout
  double poll_interval_s = 2e-3;  // wait_done polls the status this often
  RegisterMap registers;
  OutputCapabilities output;  // mode is always parameters
  InterferometerConfig interferometer;
};

// The keys of `daq.modbus:` (with the output capability keys).
const model::ParamTable<ModbusConfig>& modbus_params();

// `interferometer:` and `daq.modbus:` of root (host, port, unit_id, timeout_s, poll_interval_s,
// registers, and the output capability keys). Unknown keys: errors with file:line.
ModbusConfig parse_modbus_yaml(const YAML::Node& root, const std::string& file);

// The one TCP connection both interfaces share. Opened by the first configure(), closed by the
// last shutdown().
class ModbusLink {
 public:
  explicit ModbusLink(const ModbusConfig& config);
  ~ModbusLink();
  ModbusLink(const ModbusLink&) = delete;
  ModbusLink& operator=(const ModbusLink&) = delete;

  DriverStatus open();
  void close();
  // Holding registers [address, address + n), any n (split into requests of at most 125).
  DriverStatus read(std::uint16_t address, std::size_t n, std::uint16_t* out);
  // idempotent: may be retried once after a dropped connection.
  DriverStatus write(std::uint16_t address, std::size_t n, const std::uint16_t* values,
                     bool idempotent);
  const ModbusConfig& config() const { return config_; }
  const std::string& endpoint() const { return endpoint_; }  // "HOST:PORT unit N"
  bool connected() const { return connected_; }

 private:
  DriverStatus connect();
  void drop();
  DriverStatus failure(const std::string& what, int error_number);
  DriverStatus read_once(std::uint16_t address, std::size_t n, std::uint16_t* out);
  DriverStatus write_once(std::uint16_t address, std::size_t n, const std::uint16_t* values);

  ModbusConfig config_;
  std::string endpoint_;
  modbus_t* ctx_ = nullptr;
  bool connected_ = false;
  int users_ = 0;
};

class ModbusOutput final : public WaveformOutput {
 public:
  explicit ModbusOutput(std::shared_ptr<ModbusLink> link);
  const OutputCapabilities& capabilities() const override { return link_->config().output; }

 private:
  DriverStatus on_configure() override;
  DriverStatus on_activate() override { return do_stop(); }
  DriverStatus on_deactivate() override { return do_stop(); }
  DriverStatus on_shutdown() override;
  DriverStatus do_write_burst(const double* xi_m, std::size_t n, double rate_hz) override;
  DriverStatus do_write_burst_parameters(const model::TriangleWave& wave) override;
  DriverStatus do_start() override;
  DriverStatus do_stop() override;
  DriverStatus do_is_done(bool& done) override;
  double poll_interval_s() const override { return link_->config().poll_interval_s; }
  DriverStatus read_status(std::uint16_t& status);

  std::shared_ptr<ModbusLink> link_;
};

class ModbusInterferometer final : public Interferometer {
 public:
  explicit ModbusInterferometer(std::shared_ptr<ModbusLink> link);
  const InterferometerCapabilities& capabilities() const override { return caps_; }

 private:
  DriverStatus on_configure() override;  // reads the device's capture rate
  DriverStatus on_activate() override { return DriverStatus::success(); }
  DriverStatus on_deactivate() override { return DriverStatus::success(); }
  DriverStatus on_shutdown() override;
  DriverStatus do_latch(std::uint64_t& word) override;
  DriverStatus do_read_stream(TimedWord* out, std::size_t capacity, std::size_t& n) override;
  DriverStatus do_count_epoch(std::uint64_t& epoch) override;  // the boot_id register

  std::shared_ptr<ModbusLink> link_;
  InterferometerCapabilities caps_;
  std::size_t record_registers_;
  std::vector<std::uint16_t> buffer_;  // one request's records
  bool have_burst_id_ = false;
  std::uint16_t burst_id_ = 0;
  std::uint32_t next_record_ = 0;
};

Device make_modbus_device(const ModbusConfig& config);
Device make_modbus_device(const YAML::Node& root, const std::string& file);

}  // namespace idm::drivers::modbus
