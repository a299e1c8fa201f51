#include "drivers/modbus/modbus_backend.h"

#include <modbus/modbus.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <sstream>

#include "model/yaml_util.h"

namespace idm::drivers::modbus {

using model::InputError;
using model::located;

namespace {

std::string hex16(std::uint16_t v) {
  std::ostringstream o;
  o << "0x" << std::hex << v;
  return o.str();
}

std::string registers_text(const char* op, std::uint16_t address, std::size_t n) {
  return std::string(op) + " " + std::to_string(n) + " register" + (n == 1 ? "" : "s") + " at " +
         std::to_string(address);
}

}  // namespace

const model::ParamTable<ModbusConfig>& modbus_params() {
  using C = ModbusConfig;
  static const model::ParamTable<C> table(model::join<C>({
      {
          model::text<C>(
              "host", "the device's address", [](auto& c) -> auto& { return c.host; },
              "a host name or address"),
          model::integer<C>(
              "port", "", 1, 65535, "its Modbus TCP port", [](auto& c) -> auto& { return c.port; }),
          model::integer<C>(
              "unit_id", "", 0, 255, "the unit of channel 0; channel k is unit_id + k (<= 247)",
              [](auto& c) -> auto& { return c.unit_id; }),
          model::real<C>(
              "timeout_s", "s", {1e-3, 60}, "response (and connect) timeout",
              [](auto& c) -> auto& { return c.timeout_s; }),
          model::real<C>(
              "poll_interval_s", "s", {1e-4, 10}, "a burst's status is polled this often",
              [](auto& c) -> auto& { return c.poll_interval_s; }),
          model::custom<C>("registers", "map", "drivers/modbus/README.md", "(the default map)",
                           "the register map: addresses, formats, scales, word order",
                           [](C& c, const YAML::Node& v, const std::string& file,
                              const std::string&) {
                             c.registers = parse_register_map(v, file, c.interferometer.word.width);
                           }),
      },
      model::lifted<C>(
          output_capability_params(), [](auto& c) -> auto& { return c.output; }),
  }));
  return table;
}

ModbusConfig parse_modbus_yaml(const YAML::Node& root, const std::string& file) {
  ModbusConfig c;
  c.output.mode = OutputMode::BurstParameters;
  c.interferometer = parse_interferometer_yaml(root, file);
  const YAML::Node node = detail::child(detail::child(root, "daq"), "modbus");
  modbus_params().read(node, file, "daq.modbus", c);
  try {
    validate(c.output, "daq.modbus");
  } catch (const InputError& e) {
    throw InputError(located(file, node, "daq.modbus", e.what()));
  }
  if (!detail::present(node) || !node["registers"])
    c.registers = parse_register_map(YAML::Node(YAML::NodeType::Undefined), file,
                                     c.interferometer.word.width);
  // The daemon's document for one axis names its channel on the card: channel k is unit
  // unit_id + k (a multi-channel Modbus device answers each channel as its own unit).
  if (const YAML::Node ch = detail::child(root, "channel"); detail::present(ch)) {
    const long channel = model::read_integer(ch, file, "channel", 0, 63);
    if (c.unit_id + channel > 247)
      throw InputError(located(file, ch, "channel", "unit_id + channel must be <= 247"));
    c.unit_id += static_cast<int>(channel);
  }
  return c;
}

// ---- ModbusLink ----

ModbusLink::ModbusLink(const ModbusConfig& config)
    : config_(config),
      endpoint_(config.host + ":" + std::to_string(config.port) + " unit " +
                std::to_string(config.unit_id)) {}

ModbusLink::~ModbusLink() {
  if (ctx_) {
    if (connected_) modbus_close(ctx_);
    modbus_free(ctx_);
  }
}

DriverStatus ModbusLink::open() {
  if (!ctx_) {
    ctx_ = modbus_new_tcp(config_.host.c_str(), config_.port);
    if (!ctx_)
      return DriverStatus::failure(
          DriverError::NoDevice,
          endpoint_ + ": cannot create a Modbus TCP context: " + modbus_strerror(errno));
    const double t = config_.timeout_s;
    const auto sec = static_cast<std::uint32_t>(std::floor(t));
    const auto usec = static_cast<std::uint32_t>(std::lround((t - sec) * 1e6));
    modbus_set_response_timeout(ctx_, sec, usec);
    if (modbus_set_slave(ctx_, config_.unit_id) != 0)
      return DriverStatus::failure(DriverError::InvalidArgument,
                                   endpoint_ + ": unit id: " + modbus_strerror(errno));
  }
  DriverStatus s = connect();
  if (s.ok()) ++users_;
  return s;
}

void ModbusLink::close() {
  if (users_ > 0 && --users_ == 0) drop();
}

DriverStatus ModbusLink::connect() {
  if (connected_) return DriverStatus::success();
  if (modbus_connect(ctx_) != 0) {
    const int e = errno;
    modbus_close(ctx_);
    if (e == ETIMEDOUT || e == EINPROGRESS)
      return DriverStatus::failure(DriverError::Timeout,
                                   "cannot connect to " + endpoint_ + ": no answer within " +
                                       model::format_number(config_.timeout_s) + " s");
    return DriverStatus::failure(DriverError::NoDevice,
                                 "cannot connect to " + endpoint_ + ": " + modbus_strerror(e));
  }
  connected_ = true;
  return DriverStatus::success();
}

void ModbusLink::drop() {
  if (connected_) modbus_close(ctx_);
  connected_ = false;
}

DriverStatus ModbusLink::failure(const std::string& what, int e) {
  const std::string where = endpoint_ + ": " + what + ": ";
  if (e >= EMBXILFUN && e <= EMBXGTAR)  // the device answered with an exception
    return DriverStatus::failure(DriverError::DeviceError,
                                 where + "exception response: " + modbus_strerror(e));
  drop();  // the stream of requests and answers can no longer be trusted
  if (e == ETIMEDOUT)
    return DriverStatus::failure(
        DriverError::Timeout,
        where + "no answer within " + model::format_number(config_.timeout_s) + " s");
  if (e >= EMBBADCRC && e <= EMBBADSLAVE)
    return DriverStatus::failure(DriverError::ProtocolError,
                                 where + "malformed answer: " + modbus_strerror(e));
  return DriverStatus::failure(DriverError::Disconnected,
                               where + "connection lost: " + modbus_strerror(e));
}

DriverStatus ModbusLink::read_once(std::uint16_t address, std::size_t n, std::uint16_t* out) {
  if (DriverStatus s = connect(); !s.ok()) return s;
  std::size_t done = 0;
  while (done < n) {
    const std::size_t k = std::min<std::size_t>(n - done, MODBUS_MAX_READ_REGISTERS);
    const auto at = static_cast<std::uint16_t>(address + done);
    const int got = modbus_read_registers(ctx_, at, static_cast<int>(k), out + done);
    if (got < 0) return failure(registers_text("read", at, k), errno);
    if (static_cast<std::size_t>(got) != k) return failure(registers_text("read", at, k), EMBMDATA);
    done += k;
  }
  return DriverStatus::success();
}

DriverStatus ModbusLink::write_once(std::uint16_t address, std::size_t n,
                                    const std::uint16_t* values) {
  if (DriverStatus s = connect(); !s.ok()) return s;
  std::size_t done = 0;
  while (done < n) {
    const std::size_t k = std::min<std::size_t>(n - done, MODBUS_MAX_WRITE_REGISTERS);
    const auto at = static_cast<std::uint16_t>(address + done);
    const int put = modbus_write_registers(ctx_, at, static_cast<int>(k), values + done);
    if (put < 0) return failure(registers_text("write", at, k), errno);
    done += k;
  }
  return DriverStatus::success();
}

DriverStatus ModbusLink::read(std::uint16_t address, std::size_t n, std::uint16_t* out) {
  const bool was_connected = connected_;
  DriverStatus s = read_once(address, n, out);
  if (s.error == DriverError::Disconnected && was_connected) s = read_once(address, n, out);
  return s;
}

DriverStatus ModbusLink::write(std::uint16_t address, std::size_t n, const std::uint16_t* values,
                               bool idempotent) {
  const bool was_connected = connected_;
  DriverStatus s = write_once(address, n, values);
  if (idempotent && s.error == DriverError::Disconnected && was_connected)
    s = write_once(address, n, values);
  return s;
}

// ---- ModbusOutput ----

ModbusOutput::ModbusOutput(std::shared_ptr<ModbusLink> link)
    : WaveformOutput("modbus waveform output (" + link->endpoint() + ")"), link_(std::move(link)) {}

DriverStatus ModbusOutput::on_configure() {
  if (DriverStatus s = link_->open(); !s.ok()) return s;
  std::uint16_t status = 0;
  DriverStatus s = read_status(status);
  if (!s.ok()) link_->close();
  return s;
}

DriverStatus ModbusOutput::on_shutdown() {
  link_->close();
  return DriverStatus::success();
}

DriverStatus ModbusOutput::read_status(std::uint16_t& status) {
  if (DriverStatus s = link_->read(link_->config().registers.status, 1, &status); !s.ok()) return s;
  if (status & status_bit::kFault)
    return DriverStatus::failure(
        DriverError::DeviceError,
        link_->endpoint() + ": the device reports a fault (status " + hex16(status) + ")");
  return DriverStatus::success();
}

DriverStatus ModbusOutput::do_write_burst(const double*, std::size_t, double) {
  return DriverStatus::failure(DriverError::Unsupported,
                               "a Modbus waveform generator takes burst parameters only");
}

DriverStatus ModbusOutput::do_write_burst_parameters(const model::TriangleWave& wave) {
  const RegisterMap& m = link_->config().registers;
  const struct {
    const char* name;
    const ScaledField& field;
    double value;
  } fields[] = {{"freq_hz", m.freq_hz, wave.freq_hz},
                {"duty", m.duty, wave.duty},
                {"stroke_m", m.stroke_m, wave.stroke_m},
                {"cycles", m.cycles, static_cast<double>(wave.cycles)}};
  for (const auto& f : fields) {
    std::uint16_t regs[2] = {0, 0};
    if (!encode_value(f.field, f.value, m.word_order, regs))
      return DriverStatus::failure(DriverError::InvalidArgument,
                                   std::string(f.name) + " " + model::format_number(f.value) +
                                       " does not fit register format " +
                                       value_format_name(f.field.format) + " at scale " +
                                       model::format_number(f.field.scale));
  }
  for (const auto& f : fields) {
    std::uint16_t regs[2] = {0, 0};
    encode_value(f.field, f.value, m.word_order, regs);
    if (DriverStatus s = link_->write(f.field.address, register_count(f.field.format), regs, true);
        !s.ok())
      return s;
  }
  return DriverStatus::success();
}

DriverStatus ModbusOutput::do_start() {
  const std::uint16_t start = command::kStart;
  if (DriverStatus s = link_->write(link_->config().registers.command, 1, &start, false); !s.ok())
    return s;
  std::uint16_t status = 0;
  if (DriverStatus s = read_status(status); !s.ok()) return s;
  if (status & status_bit::kParameterError)
    return DriverStatus::failure(DriverError::DeviceError,
                                 link_->endpoint() +
                                     ": the device rejected the burst parameters "
                                     "(status " +
                                     hex16(status) + ")");
  return DriverStatus::success();
}

DriverStatus ModbusOutput::do_stop() {
  const std::uint16_t stop = command::kStop;
  return link_->write(link_->config().registers.command, 1, &stop, true);
}

DriverStatus ModbusOutput::do_is_done(bool& done) {
  std::uint16_t status = 0;
  if (DriverStatus s = read_status(status); !s.ok()) return s;
  done = (status & status_bit::kRunning) == 0;
  return DriverStatus::success();
}

// ---- ModbusInterferometer ----

ModbusInterferometer::ModbusInterferometer(std::shared_ptr<ModbusLink> link)
    : Interferometer("modbus interferometer (" + link->endpoint() + ")"),
      link_(std::move(link)),
      record_registers_(
          RegisterMap::position_registers(link_->config().interferometer.word.width)) {
  caps_.word = link_->config().interferometer.word;
  caps_.stream_rate_hz = 1.0 / caps_.word.sample_interval_s;
  caps_.stream_capacity = link_->config().registers.capture_capacity;
  buffer_.resize(MODBUS_MAX_READ_REGISTERS);
}

DriverStatus ModbusInterferometer::on_configure() {
  if (DriverStatus s = link_->open(); !s.ok()) return s;
  const RegisterMap& m = link_->config().registers;
  std::uint16_t regs[2] = {0, 0};
  DriverStatus s =
      link_->read(m.capture_rate_hz.address, register_count(m.capture_rate_hz.format), regs);
  if (s.ok()) {
    const double rate = decode_value(m.capture_rate_hz, m.word_order, regs);
    if (!(std::isfinite(rate) && rate > 0 && rate <= 1e8)) {
      s = DriverStatus::failure(DriverError::ProtocolError,
                                link_->endpoint() + ": capture_rate_hz register reads " +
                                    model::format_number(rate) + ", allowed (0, 1e8]");
    } else {
      caps_.stream_rate_hz = rate;
      caps_.word.sample_interval_s = 1.0 / rate;
    }
  }
  if (!s.ok()) link_->close();
  return s;
}

DriverStatus ModbusInterferometer::on_shutdown() {
  link_->close();
  return DriverStatus::success();
}

DriverStatus ModbusInterferometer::do_count_epoch(std::uint64_t& epoch) {
  const RegisterMap& m = link_->config().registers;
  if (m.boot_id < 0)
    return DriverStatus::failure(
        DriverError::Unsupported,
        "the register map has no boot_id: a reconnect may have lost the count");
  std::uint16_t id = 0;
  if (DriverStatus s = link_->read(static_cast<std::uint16_t>(m.boot_id), 1, &id); !s.ok())
    return s;
  epoch = id;
  return DriverStatus::success();
}

DriverStatus ModbusInterferometer::do_latch(std::uint64_t& word) {
  const RegisterMap& m = link_->config().registers;
  std::uint16_t regs[4] = {0, 0, 0, 0};
  if (DriverStatus s = link_->read(m.position, record_registers_, regs); !s.ok()) return s;
  word = decode_position(regs, caps_.word.width, m.word_order);
  return DriverStatus::success();
}

DriverStatus ModbusInterferometer::do_read_stream(TimedWord* out, std::size_t capacity,
                                                  std::size_t& n) {
  n = 0;
  const RegisterMap& m = link_->config().registers;
  std::uint16_t id = 0;
  if (DriverStatus s = link_->read(m.burst_id, 1, &id); !s.ok()) return s;
  std::uint16_t count_regs[2] = {0, 0};
  if (DriverStatus s = link_->read(m.capture_count, 2, count_regs); !s.ok()) return s;
  const std::uint32_t count = m.word_order == WordOrder::HighFirst
                                  ? (std::uint32_t{count_regs[0]} << 16) | count_regs[1]
                                  : (std::uint32_t{count_regs[1]} << 16) | count_regs[0];
  if (count > m.capture_capacity)
    return DriverStatus::failure(DriverError::ProtocolError,
                                 link_->endpoint() + ": capture_count reads " +
                                     std::to_string(count) + ", more than the capacity " +
                                     std::to_string(m.capture_capacity));
  if (!have_burst_id_ || id != burst_id_ || count < next_record_) {
    have_burst_id_ = true;
    burst_id_ = id;
    next_record_ = 0;
  }
  const std::size_t per_request = buffer_.size() / record_registers_;
  while (n < capacity && next_record_ < count) {
    const std::size_t k = std::min({per_request, capacity - n, std::size_t{count - next_record_}});
    const auto at = static_cast<std::uint16_t>(m.capture_base + next_record_ * record_registers_);
    if (DriverStatus s = link_->read(at, k * record_registers_, buffer_.data()); !s.ok()) return s;
    for (std::size_t i = 0; i < k; ++i) {
      out[n].t_s = static_cast<double>(next_record_ + i) / caps_.stream_rate_hz;
      out[n].word =
          decode_position(buffer_.data() + i * record_registers_, caps_.word.width, m.word_order);
      ++n;
    }
    next_record_ += static_cast<std::uint32_t>(k);
  }
  return DriverStatus::success();
}

Device make_modbus_device(const ModbusConfig& config) {
  Device d;
  d.driver = "modbus";
  auto link = std::make_shared<ModbusLink>(config);
  d.output = std::make_unique<ModbusOutput>(link);
  d.interferometer = std::make_unique<ModbusInterferometer>(link);
  return d;
}

Device make_modbus_device(const YAML::Node& root, const std::string& file) {
  return make_modbus_device(parse_modbus_yaml(root, file));
}

}  // namespace idm::drivers::modbus
