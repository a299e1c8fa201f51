#include "drivers/usb/transport.h"

#include <libusb-1.0/libusb.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "drivers/config.h"
#include "model/stage.h"
#include "model/yaml_util.h"

namespace idm::drivers::usb {

using model::InputError;
using model::located;

namespace {

std::string hex4(unsigned v) {
  char text[8];
  std::snprintf(text, sizeof text, "%04x", v & 0xFFFFu);
  return text;
}

std::uint16_t read_id(const YAML::Node& v, const std::string& file, const std::string& key) {
  if (!v.IsScalar()) throw InputError(located(file, v, key, "expected an integer 0..0xffff"));
  const std::string& text = v.Scalar();
  try {
    std::size_t used = 0;
    const unsigned long value = std::stoul(text, &used, 0);  // "0x1209" or "4617"
    if (used == text.size() && value <= 0xFFFF) return static_cast<std::uint16_t>(value);
  } catch (const std::exception&) {
  }
  throw InputError(located(file, v, key, "'" + text + "' is not an integer in [0, 0xffff]"));
}

DriverStatus codec_failure(const CodecStatus& c, const std::string& what) {
  return DriverStatus::failure(DriverError::ProtocolError,
                               what + ": " + codec_error_name(c.error) + ": " + c.message);
}

}  // namespace

const model::ParamTable<UsbTransportConfig>& usb_transport_params() {
  using C = UsbTransportConfig;
  const auto id = [](std::uint16_t C::*member) {
    return [member](C& c, const YAML::Node& v, const std::string& file, const std::string& key) {
      c.*member = read_id(v, file, key);
    };
  };
  static const model::ParamTable<C> table({
      model::custom<C>("vendor_id", "", "[0, 0xffff], e.g. 0x1209", "0x1209",
                       "the bridge's USB vendor id", id(&C::vendor_id)),
      model::custom<C>("product_id", "", "[0, 0xffff], e.g. 0x4944", "0x4944",
                       "the bridge's USB product id", id(&C::product_id)),
      model::text<C>(
          "serial", "its serial number; \"\": the only matching device",
          [](auto& c) -> auto& { return c.serial; }),
      model::integer<C>(
          "interface_number", "", 0, 255, "the USB interface it claims",
          [](auto& c) -> auto& { return c.interface_number; }),
      model::real<C>(
          "timeout_s", "s", {1e-3, 60}, "per transfer",
          [](auto& c) -> auto& { return c.timeout_s; }),
  });
  return table;
}

UsbTransportConfig parse_usb_yaml(const YAML::Node& root, const std::string& file) {
  UsbTransportConfig c;
  usb_transport_params().read(detail::child(detail::child(root, "daq"), "usb"), file, "daq.usb", c);
  return c;
}

std::string device_text(const UsbTransportConfig& c) {
  std::string out = hex4(c.vendor_id) + ":" + hex4(c.product_id);
  if (!c.serial.empty()) out += " serial " + c.serial;
  return out;
}

DriverStatus usb_status(int code, const std::string& what, const std::string& device) {
  if (code >= 0) return DriverStatus::success();
  const std::string name = libusb_error_name(code);
  const std::string head = what + ": ";
  switch (code) {
    case LIBUSB_ERROR_NO_DEVICE:
      return DriverStatus::failure(
          DriverError::Disconnected,
          head + "the USB device " + device + " is gone (unplugged?) (" + name + ")");
    case LIBUSB_ERROR_ACCESS:
      return DriverStatus::failure(
          DriverError::PermissionDenied,
          head + "no permission to open the USB device " + device +
              ": give the daemon's user access with a udev rule (see drivers/usb/README.md) (" +
              name + ")");
    case LIBUSB_ERROR_TIMEOUT:
      return DriverStatus::failure(
          DriverError::Timeout,
          head + "the USB device " + device + " did not answer in time (" + name + ")");
    case LIBUSB_ERROR_NOT_FOUND:
      return DriverStatus::failure(DriverError::NoDevice, head + "the USB device " + device +
                                                              " or its interface was not "
                                                              "found (" +
                                                              name + ")");
    case LIBUSB_ERROR_BUSY:
      return DriverStatus::failure(DriverError::DeviceError,
                                   head + "the interface of " + device +
                                       " is claimed by another program or driver (" + name + ")");
    case LIBUSB_ERROR_PIPE:
      return DriverStatus::failure(DriverError::DeviceError,
                                   head + "the bridge " + device +
                                       " stalled the request (unknown request, wrong length, or "
                                       "not allowed in its state) (" +
                                       name + ")");
    case LIBUSB_ERROR_OVERFLOW:
      return DriverStatus::failure(
          DriverError::ProtocolError,
          head + "the bridge " + device + " sent more data than asked (" + name + ")");
    default:
      return DriverStatus::failure(DriverError::DeviceError,
                                   head + "USB error on " + device + ": " +
                                       libusb_strerror(static_cast<libusb_error>(code)) + " (" +
                                       name + ")");
  }
}

CodecStatus build_waveform_blocks(std::span<const std::int32_t> codes, SampleFormat format,
                                  std::uint32_t first_sequence,
                                  std::vector<std::vector<std::uint8_t>>& transfers) {
  const std::size_t per_packet = max_samples(format);
  if (per_packet == 0) return {CodecError::BadSampleFormat, "waveform format is not a DAC format"};
  WaveformBlock block;
  block.format = format;
  const std::size_t packets =
      std::max<std::size_t>(1, (codes.size() + per_packet - 1) / per_packet);
  for (std::size_t p = 0; p < packets; ++p) {
    const std::size_t begin = p * per_packet;
    const std::size_t end = std::min(codes.size(), begin + per_packet);
    block.sequence = first_sequence + static_cast<std::uint32_t>(p);
    block.flags = static_cast<std::uint8_t>((p == 0 ? packet_flag::kFirst : 0) |
                                            (p + 1 == packets ? packet_flag::kLast : 0));
    block.dac_codes.assign(codes.begin() + static_cast<std::ptrdiff_t>(std::min(begin, end)),
                           codes.begin() + static_cast<std::ptrdiff_t>(end));
    std::vector<std::uint8_t> bytes;
    CodecStatus s = encode_waveform_block(block, bytes);
    if (!s.ok()) {
      s.message = "waveform block " + std::to_string(p) + ": " + s.message;
      return s;
    }
    transfers.push_back(std::move(bytes));
  }
  return {};
}

CodecStatus parse_position_transfer(std::span<const std::uint8_t> bytes, SequenceTracker& tracker,
                                    std::vector<PositionRecord>& records, PositionTransfer& info) {
  PositionPacket packet;
  std::size_t offset = 0;
  while (offset < bytes.size()) {
    std::size_t consumed = 0;
    CodecStatus s = decode_position_packet(bytes.subspan(offset), packet, consumed);
    if (!s.ok()) {
      s.message = "packet at byte " + std::to_string(offset) + ": " + s.message;
      return s;
    }
    offset += consumed;
    const CodecStatus seq = tracker.check(packet.sequence);
    if (seq.error == CodecError::SequenceRepeat) continue;  // already had it: dropped
    if (seq.error == CodecError::SequenceGap) info.lost = true;
    if (packet.flags & packet_flag::kDropped) info.lost = true;
    if (packet.flags & packet_flag::kLast) info.last = true;
    records.insert(records.end(), packet.samples.begin(), packet.samples.end());
    ++info.packets;
  }
  return {};
}

// ---- UsbTransport ----

UsbTransport::UsbTransport(const UsbTransportConfig& config)
    : config_(config), device_(device_text(config)) {}

UsbTransport::~UsbTransport() {
  close();
  if (context_) libusb_exit(context_);
}

unsigned UsbTransport::timeout_ms() const {
  return static_cast<unsigned>(std::max(1.0, std::round(config_.timeout_s * 1e3)));
}

DriverStatus UsbTransport::not_open(const char* what) const {
  return DriverStatus::failure(DriverError::InvalidState,
                               std::string(what) + ": the USB device " + device_ + " is not open");
}

DriverStatus UsbTransport::transfer_failed(int code, const std::string& what) {
  DriverStatus s = usb_status(code, what, device_);
  if (code == LIBUSB_ERROR_NO_DEVICE) close();  // unplugged: the handle is dead
  return s;
}

DriverStatus UsbTransport::open() {
  if (handle_) return DriverStatus::success();
  if (!context_) {
    const int rc = libusb_init(&context_);
    if (rc != 0) {
      context_ = nullptr;
      return usb_status(rc, "open: libusb_init", device_);
    }
  }
  libusb_device** list = nullptr;
  const ssize_t n = libusb_get_device_list(context_, &list);
  if (n < 0) return usb_status(static_cast<int>(n), "open: listing USB devices", device_);
  int matching = 0;
  std::string serials_seen;
  int open_error = 0;
  for (ssize_t i = 0; i < n && !handle_; ++i) {
    libusb_device_descriptor d{};
    if (libusb_get_device_descriptor(list[i], &d) != 0) continue;
    if (d.idVendor != config_.vendor_id || d.idProduct != config_.product_id) continue;
    ++matching;
    libusb_device_handle* h = nullptr;
    const int rc = libusb_open(list[i], &h);
    if (rc != 0) {
      open_error = rc;
      continue;
    }
    std::string serial;
    if (d.iSerialNumber != 0) {
      unsigned char text[256] = {0};
      const int len = libusb_get_string_descriptor_ascii(h, d.iSerialNumber, text, sizeof text);
      if (len > 0)
        serial.assign(reinterpret_cast<const char*>(text), static_cast<std::size_t>(len));
    }
    if (!config_.serial.empty() && serial != config_.serial) {
      serials_seen += (serials_seen.empty() ? "" : ", ") + (serial.empty() ? "(none)" : serial);
      libusb_close(h);
      continue;
    }
    handle_ = h;
  }
  libusb_free_device_list(list, 1);
  if (!handle_) {
    if (open_error != 0) return usb_status(open_error, "open", device_);
    std::string msg = "open: no USB device " + device_;
    if (matching > 0 && !serials_seen.empty())
      msg += " (found serials: " + serials_seen + ")";
    else
      msg += " (" + std::to_string(n) + " USB devices present, none with that id)";
    return DriverStatus::failure(DriverError::NoDevice, msg);
  }
  libusb_set_auto_detach_kernel_driver(handle_, 1);
  if (const int rc = libusb_claim_interface(handle_, config_.interface_number); rc != 0) {
    DriverStatus s = usb_status(
        rc, "open: claiming interface " + std::to_string(config_.interface_number), device_);
    libusb_close(handle_);
    handle_ = nullptr;
    return s;
  }
  BridgeInfo info;
  if (DriverStatus s = get_info(info); !s.ok()) {
    close();
    return s;
  }
  info_ = info;
  in_buffer_.resize(kMaxPacketBytes * 4);
  return DriverStatus::success();
}

void UsbTransport::close() {
  if (!handle_) return;
  libusb_release_interface(handle_, config_.interface_number);
  libusb_close(handle_);
  handle_ = nullptr;
}

DriverStatus UsbTransport::control(Request request, std::span<std::uint8_t> data,
                                   const char* what) {
  if (!handle_) return not_open(what);
  const ControlSetup setup =
      control_setup(request, static_cast<std::uint16_t>(config_.interface_number));
  if (setup.length != data.size())
    return DriverStatus::failure(DriverError::InvalidArgument,
                                 std::string(what) + ": " + std::to_string(data.size()) +
                                     " bytes for a request of " + std::to_string(setup.length));
  const int rc =
      libusb_control_transfer(handle_, setup.request_type, setup.request, setup.value, setup.index,
                              data.empty() ? nullptr : data.data(), setup.length, timeout_ms());
  if (rc < 0) return transfer_failed(rc, what);
  if (static_cast<std::size_t>(rc) != data.size())
    return DriverStatus::failure(DriverError::ProtocolError,
                                 std::string(what) + ": " + std::to_string(rc) + " of " +
                                     std::to_string(data.size()) + " bytes transferred");
  return DriverStatus::success();
}

DriverStatus UsbTransport::start() {
  return control(Request::Start, {}, "start");
}

DriverStatus UsbTransport::stop() {
  return control(Request::Stop, {}, "stop");
}

DriverStatus UsbTransport::configure(const BridgeConfig& config) {
  std::vector<std::uint8_t> bytes;
  if (CodecStatus c = encode_config(config, bytes); !c.ok()) {
    return DriverStatus::failure(DriverError::InvalidArgument, "configure: " + c.message);
  }
  if (DriverStatus s = control(Request::Configure, bytes, "configure"); !s.ok()) return s;
  out_sequence_ = 0;
  in_sequence_.reset(0);
  return DriverStatus::success();
}

DriverStatus UsbTransport::get_status(BridgeStatus& status) {
  std::vector<std::uint8_t> bytes(kStatusBytes);
  if (DriverStatus s = control(Request::GetStatus, bytes, "get_status"); !s.ok()) return s;
  if (CodecStatus c = decode_status(bytes, status); !c.ok()) return codec_failure(c, "get_status");
  return DriverStatus::success();
}

DriverStatus UsbTransport::get_info(BridgeInfo& info) {
  std::vector<std::uint8_t> bytes(kInfoBytes);
  if (DriverStatus s = control(Request::GetInfo, bytes, "get_info"); !s.ok()) return s;
  if (CodecStatus c = decode_info(bytes, info); !c.ok()) return codec_failure(c, "get_info");
  return DriverStatus::success();
}

DriverStatus UsbTransport::latch(PositionRecord& record) {
  std::vector<std::uint8_t> bytes(kLatchBytes);
  if (!handle_) return not_open("latch");
  const ControlSetup setup =
      control_setup(Request::Latch, static_cast<std::uint16_t>(config_.interface_number));
  const int rc = libusb_control_transfer(handle_, setup.request_type, setup.request, setup.value,
                                         setup.index, bytes.data(), setup.length, timeout_ms());
  if (rc == LIBUSB_ERROR_PIPE)
    return DriverStatus::failure(DriverError::Unsupported,
                                 "latch: the bridge " + device_ +
                                     " stalled LATCH (firmware without the single latch request)");
  if (rc < 0) return transfer_failed(rc, "latch");
  if (static_cast<std::size_t>(rc) != bytes.size())
    return DriverStatus::failure(DriverError::ProtocolError,
                                 "latch: " + std::to_string(rc) + " of " +
                                     std::to_string(bytes.size()) + " bytes transferred");
  if (CodecStatus c = decode_latch(bytes, record); !c.ok()) return codec_failure(c, "latch");
  return DriverStatus::success();
}

DriverStatus UsbTransport::send_waveform(std::span<const std::int32_t> codes, SampleFormat format) {
  if (!handle_) return not_open("send_waveform");
  out_packets_.clear();
  if (CodecStatus c = build_waveform_blocks(codes, format, out_sequence_, out_packets_); !c.ok())
    return DriverStatus::failure(DriverError::InvalidArgument, "send_waveform: " + c.message);
  for (std::vector<std::uint8_t>& packet : out_packets_) {
    int sent = 0;
    const int rc = libusb_bulk_transfer(handle_, config_.endpoint_out, packet.data(),
                                        static_cast<int>(packet.size()), &sent, timeout_ms());
    if (rc != 0) return transfer_failed(rc, "send_waveform: bulk OUT");
    if (static_cast<std::size_t>(sent) != packet.size())
      return DriverStatus::failure(DriverError::Timeout,
                                   "send_waveform: bulk OUT: " + std::to_string(sent) + " of " +
                                       std::to_string(packet.size()) + " bytes accepted");
    ++out_sequence_;
  }
  return DriverStatus::success();
}

DriverStatus UsbTransport::receive_positions(std::vector<PositionRecord>& records,
                                             PositionTransfer& info) {
  if (!handle_) return not_open("receive_positions");
  int got = 0;
  const int rc = libusb_bulk_transfer(handle_, config_.endpoint_in, in_buffer_.data(),
                                      static_cast<int>(in_buffer_.size()), &got, timeout_ms());
  if (rc != 0) return transfer_failed(rc, "receive_positions: bulk IN");
  const CodecStatus c = parse_position_transfer(
      std::span<const std::uint8_t>(in_buffer_.data(), static_cast<std::size_t>(got)), in_sequence_,
      records, info);
  if (!c.ok()) return codec_failure(c, "receive_positions");
  return DriverStatus::success();
}

}  // namespace idm::drivers::usb
