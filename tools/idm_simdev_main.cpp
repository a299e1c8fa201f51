// idm-simdev: a simulated Modbus TCP waveform generator with a position counter.
//
//   idm-simdev --port N [--host ADDR] [--config FILE] [--channels N]
//
// The simulated stage of drivers/sim (stage:, interferometer:, sim:, daq.sim: of FILE; wall clock
// and burst parameters unless FILE says otherwise) behind the register map of
// drivers/modbus/register_map.h (daq.modbus.registers of FILE, defaults in
// drivers/modbus/README.md), served with libmodbus's server side. Writing START (1) to the
// command register plays a burst with the parameters in the registers; STOP (2) ends it; any
// other command value is an ILLEGAL_DATA_VALUE exception. Before every answer the position
// record, the status and the capture records are brought up to date, so every read sees the
// stage as it is now. Several clients may be connected at once. With --channels N it is a card of
// N channels, each a simulated stage of its own (the sim seed + channel) answering as Modbus unit
// unit_id + channel. The boot_id register holds a random value chosen at start (a restarted
// device has a new one, and lost its position count).
//
// --port 0 picks a free port. Once listening it prints "idm-simdev: listening on ADDR:PORT" on
// stdout. SIGTERM or SIGINT: the output is brought to zero and it exits 0. Bad arguments or
// config: one line on stderr, exit status 2.
#include <arpa/inet.h>
#include <modbus/modbus.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/select.h>
#include <sys/signalfd.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <memory>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "drivers/modbus/modbus_backend.h"
#include "drivers/modbus/register_map.h"
#include "drivers/sim/sim_backend.h"
#include "model/yaml_util.h"
#include "tools/cli.h"

using namespace idm;
using namespace idm::drivers;
namespace mb = idm::drivers::modbus;

namespace {

const char* kUsage = "usage: idm-simdev --port N [--host ADDR] [--config FILE] [--channels N]\n";

// SIGTERM and SIGINT arrive as a readable signalfd among the sockets (as in idmd), not through a
// handler and a flag: nothing to miss between the flag's check and select, and nothing held back
// by ThreadSanitizer, which runs a handler only at the process's next intercepted call (a select
// that blocks makes none, so a SIGTERM was never seen there).
int stop_signal_fd() {
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGINT);
  if (sigprocmask(SIG_BLOCK, &signals, nullptr) != 0) return -1;
  return signalfd(-1, &signals, SFD_CLOEXEC);
}

class SimModbusDevice {
 public:
  SimModbusDevice(const sim::SimDeviceConfig& sim_config, const mb::ModbusConfig& modbus_config,
                  std::uint16_t boot_id)
      : map_(modbus_config.registers),
        width_(sim_config.interferometer.word.width),
        record_(mb::RegisterMap::position_registers(width_)),
        device_(sim::make_sim_device(sim_config)),
        stream_buffer_(4096) {
    mapping_ = modbus_mapping_new(0, 0, static_cast<int>(map_.register_span(width_)), 0);
    if (!mapping_)
      throw model::InputError(std::string("cannot allocate the register map: ") +
                              modbus_strerror(errno));
    std::uint16_t* r = mapping_->tab_registers;
    mb::encode_value(map_.capture_rate_hz, sim_config.stream_rate_hz, map_.word_order,
                     r + map_.capture_rate_hz.address);
    if (map_.boot_id >= 0) r[map_.boot_id] = boot_id;
  }
  SimModbusDevice(const SimModbusDevice&) = delete;
  SimModbusDevice& operator=(const SimModbusDevice&) = delete;
  ~SimModbusDevice() {
    device_.shutdown();
    modbus_mapping_free(mapping_);
  }

  DriverStatus bring_up() {
    if (DriverStatus s = device_.configure(); !s.ok()) return s;
    return device_.activate();
  }
  modbus_mapping_t* mapping() { return mapping_; }
  sim::SimBackend& sim() { return *device_.sim; }

  // Position, status and capture registers as they are now.
  void refresh() {
    std::uint16_t* r = mapping_->tab_registers;
    bool fault = false;
    std::uint64_t word = 0;
    if (device_.interferometer->latch(word).ok())
      mb::encode_position(word, width_, map_.word_order, r + map_.position);
    else
      fault = true;
    bool done = true;
    if (!device_.output->is_done(done).ok()) fault = true;
    for (;;) {
      std::size_t n = 0;
      if (!device_.interferometer->read_stream(stream_buffer_.data(), stream_buffer_.size(), n)
               .ok()) {
        fault = true;
        break;
      }
      if (n == 0) break;
      for (std::size_t i = 0; i < n; ++i) {
        if (captured_ < map_.capture_capacity) {
          mb::encode_position(stream_buffer_[i].word, width_, map_.word_order,
                              r + map_.capture_base + captured_ * record_);
          ++captured_;
        } else {
          overrun_ = true;
        }
      }
    }
    if (sim().stream_dropped() > 0) overrun_ = true;
    const std::uint32_t count = captured_;
    r[map_.capture_count] = static_cast<std::uint16_t>(
        map_.word_order == mb::WordOrder::HighFirst ? count >> 16 : count & 0xFFFF);
    r[map_.capture_count + 1] = static_cast<std::uint16_t>(
        map_.word_order == mb::WordOrder::HighFirst ? count & 0xFFFF : count >> 16);
    std::uint16_t status = 0;
    if (!done) status |= mb::status_bit::kRunning;
    if (done && started_ && !parameter_error_) status |= mb::status_bit::kDone;
    if (parameter_error_) status |= mb::status_bit::kParameterError;
    if (fault) status |= mb::status_bit::kFault;
    if (overrun_) status |= mb::status_bit::kCaptureOverrun;
    r[map_.status] = status;
    r[map_.burst_id] = burst_id_;
  }

  void execute(std::uint16_t cmd) {
    mapping_->tab_registers[map_.command] = 0;  // a command register reads 0 once taken
    if (cmd == mb::command::kStop) {
      if (DriverStatus s = device_.output->stop(); !s.ok()) std::cerr << s.message << "\n";
      return;
    }
    // START: a running burst is ended first, as on a function generator.
    bool done = true;
    if (device_.output->is_done(done).ok() && !done) device_.output->stop();
    const std::uint16_t* r = mapping_->tab_registers;
    model::TriangleWave w;
    w.freq_hz = mb::decode_value(map_.freq_hz, map_.word_order, r + map_.freq_hz.address);
    w.duty = mb::decode_value(map_.duty, map_.word_order, r + map_.duty.address);
    w.stroke_m = mb::decode_value(map_.stroke_m, map_.word_order, r + map_.stroke_m.address);
    const double cycles = mb::decode_value(map_.cycles, map_.word_order, r + map_.cycles.address);
    w.cycles = cycles >= 0 && cycles <= 1e8 ? static_cast<int>(std::lround(cycles)) : -1;
    DriverStatus s = device_.output->write_burst_parameters(w);
    if (s.ok()) s = device_.output->start();
    parameter_error_ = !s.ok();
    started_ = true;
    captured_ = 0;
    overrun_ = false;
    ++burst_id_;
    if (!s.ok()) std::cerr << "idm-simdev: START rejected: " << s.message << "\n";
  }

  // The command value a write request puts in the command register, or -1 when it does not
  // touch it (fc 6 and 16; the request layout of the Modbus application protocol).
  int command_written(const std::uint8_t* query, int header_length) const {
    const std::uint8_t* p = query + header_length;
    const int fc = p[0];
    const int address = (p[1] << 8) | p[2];
    if (fc == MODBUS_FC_WRITE_SINGLE_REGISTER)
      return address == map_.command ? (p[3] << 8) | p[4] : -1;
    if (fc == MODBUS_FC_WRITE_MULTIPLE_REGISTERS) {
      const int count = (p[3] << 8) | p[4];
      if (map_.command < address || map_.command >= address + count) return -1;
      const std::uint8_t* v = p + 6 + std::ptrdiff_t{2} * (map_.command - address);
      return (v[0] << 8) | v[1];
    }
    return -1;
  }

 private:
  mb::RegisterMap map_;
  WordWidth width_;
  std::size_t record_;
  Device device_;
  modbus_mapping_t* mapping_ = nullptr;
  std::vector<TimedWord> stream_buffer_;
  std::uint32_t captured_ = 0;
  std::uint16_t burst_id_ = 0;
  bool started_ = false, parameter_error_ = false, overrun_ = false;
};

// Answers one request of rc bytes (received on ctx) from the channel it addresses.
void answer(modbus_t* ctx, const std::uint8_t* query, int rc, int header_length,
            std::vector<std::unique_ptr<SimModbusDevice>>& devices, int unit_id) {
  // The unit addressed (the MBAP header's last byte): one channel of the card.
  const int unit = query[header_length - 1] - unit_id;
  if (unit < 0 || static_cast<std::size_t>(unit) >= devices.size()) {
    modbus_reply_exception(ctx, query, MODBUS_EXCEPTION_GATEWAY_TARGET);
    return;
  }
  SimModbusDevice& device = *devices[static_cast<std::size_t>(unit)];
  if (device.sim().faults().timeouts) return;  // injected fault: no answer at all
  device.refresh();
  const int cmd = device.command_written(query, header_length);
  if (cmd >= 0 && cmd != mb::command::kStart && cmd != mb::command::kStop) {
    modbus_reply_exception(ctx, query, MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE);
    return;
  }
  modbus_reply(ctx, query, rc, device.mapping());
  if (cmd >= 0) {
    device.execute(static_cast<std::uint16_t>(cmd));
    device.refresh();
  }
}

int serve(const std::string& host, int port, std::vector<std::unique_ptr<SimModbusDevice>>& devices,
          int unit_id, int stop_fd) {
  modbus_t* ctx = modbus_new_tcp(host.c_str(), port);
  if (!ctx) {
    std::cerr << "idm-simdev: " << modbus_strerror(errno) << "\n";
    return 1;
  }
  modbus_set_slave(ctx, unit_id);
  const int listen_fd = modbus_tcp_listen(ctx, 16);
  if (listen_fd < 0) {
    std::cerr << "idm-simdev: cannot listen on " << host << ":" << port << ": "
              << modbus_strerror(errno) << "\n";
    modbus_free(ctx);
    return 1;
  }
  sockaddr_in bound{};
  socklen_t len = sizeof bound;
  getsockname(listen_fd, reinterpret_cast<sockaddr*>(&bound), &len);
  std::cout << "idm-simdev: listening on " << host << ":" << ntohs(bound.sin_port) << std::endl;

  std::set<int> clients;
  std::vector<std::uint8_t> query(MODBUS_TCP_MAX_ADU_LENGTH);
  const int header_length = modbus_get_header_length(ctx);
  for (;;) {
    fd_set read_set;
    FD_ZERO(&read_set);
    FD_SET(listen_fd, &read_set);
    FD_SET(stop_fd, &read_set);
    int max_fd = std::max(listen_fd, stop_fd);
    for (int fd : clients) {
      FD_SET(fd, &read_set);
      max_fd = std::max(max_fd, fd);
    }
    if (select(max_fd + 1, &read_set, nullptr, nullptr, nullptr) < 0) {
      if (errno == EINTR) continue;
      std::cerr << "idm-simdev: select: " << std::strerror(errno) << "\n";
      break;
    }
    if (FD_ISSET(stop_fd, &read_set)) break;  // SIGTERM or SIGINT
    if (FD_ISSET(listen_fd, &read_set)) {
      const int fd = accept(listen_fd, nullptr, nullptr);
      if (fd >= 0) clients.insert(fd);
    }
    for (auto it = clients.begin(); it != clients.end();) {
      const int fd = *it;
      if (!FD_ISSET(fd, &read_set)) {
        ++it;
        continue;
      }
      modbus_set_socket(ctx, fd);
      const int rc = modbus_receive(ctx, query.data());
      if (rc < 0) {  // the client closed the connection or sent garbage
        close(fd);
        it = clients.erase(it);
        continue;
      }
      ++it;
      if (rc > 0) answer(ctx, query.data(), rc, header_length, devices, unit_id);  // 0: not for us
    }
  }
  for (int fd : clients) close(fd);
  close(listen_fd);
  modbus_free(ctx);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  for (int i = 1; i < argc; ++i)
    if (std::string(argv[i]) == "--help" || std::string(argv[i]) == "-h") {
      std::cout << kUsage;
      return 0;
    }
  try {
    const tools::Flags flags(argc, argv, 1, {"port", "host", "config", "channels"});
    const int channels =
        flags.has("channels") ? static_cast<int>(flags.integer("channels", 1, 64)) : 1;
    const int port = static_cast<int>(flags.integer("port", 0, 65535));
    const std::string host = flags.has("host") ? flags.text("host") : "127.0.0.1";
    std::string file = "(defaults)";
    YAML::Node root(YAML::NodeType::Map);
    if (flags.has("config")) {
      file = flags.text("config");
      root = model::load_yaml_file(file);
    }
    sim::SimDeviceConfig sim_config = sim::parse_sim_device_yaml(root, file);
    const YAML::Node sim_section = detail::child(detail::child(root, "daq"), "sim");
    if (!detail::present(detail::child(sim_section, "clock")))
      sim_config.clock = sim::ClockMode::Wall;
    if (detail::present(detail::child(sim_section, "output")) &&
        sim_config.output.mode != OutputMode::BurstParameters)
      throw model::InputError(file +
                              ": daq.sim.output: idm-simdev plays burst parameters; set "
                              "it to parameters or leave it out");
    sim_config.output.mode = OutputMode::BurstParameters;
    const mb::ModbusConfig modbus_config = mb::parse_modbus_yaml(root, file);
    sim_config.stream_capacity = modbus_config.registers.capture_capacity;

    std::random_device entropy;
    const auto boot_id = static_cast<std::uint16_t>(1 + entropy() % 65535);
    std::vector<std::unique_ptr<SimModbusDevice>> devices;
    for (int k = 0; k < channels; ++k) {
      sim::SimDeviceConfig channel = sim_config;
      channel.sim.seed += static_cast<std::uint64_t>(k);
      devices.push_back(std::make_unique<SimModbusDevice>(channel, modbus_config, boot_id));
      if (DriverStatus s = devices.back()->bring_up(); !s.ok()) {
        std::cerr << "idm-simdev: " << s.message << "\n";
        return 1;
      }
    }
    const int stop_fd = stop_signal_fd();
    if (stop_fd < 0) {
      std::cerr << "idm-simdev: signalfd: " << std::strerror(errno) << "\n";
      return 1;
    }
    signal(SIGPIPE, SIG_IGN);
    return serve(host, port, devices, modbus_config.unit_id, stop_fd);
  } catch (const model::InputError& e) {
    std::cerr << "idm-simdev: " << e.what() << "\n" << kUsage;
    return 2;
  } catch (const std::exception& e) {  // anything else (a failed allocation, a system error)
    std::cerr << "idm-simdev: " << e.what() << "\n";
    return 1;
  }
}
