// The libusb transport of the USB bridge (protocol in README.md beside this file, codec in
// protocol.h): opens the bridge by vendor id, product id and serial, claims its interface, and
// moves control requests and bulk packets. Every libusb failure becomes a DriverStatus that says
// what happened in words: no device, no permission (with the udev hint), unplugged, timeout,
// stalled request, busy interface.
//
// The pieces that need no device are plain functions and tested on their own: the libusb error
// mapping, the packetizing of a burst into waveform blocks, and the parsing of a bulk IN transfer
// into position records with sequence checks.
#pragma once

#include <yaml-cpp/yaml.h>

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "drivers/interfaces.h"
#include "drivers/usb/protocol.h"
#include "model/param_table.h"

struct libusb_context;
struct libusb_device_handle;

namespace idm::drivers::usb {

struct UsbTransportConfig {
  std::uint16_t vendor_id = 0x1209;   // pid.codes open-hardware vendor id
  std::uint16_t product_id = 0x4944;  // "ID"
  std::string serial;                 // empty: the only matching device
  int interface_number = 0;
  std::uint8_t endpoint_out = 0x01;
  std::uint8_t endpoint_in = 0x81;
  double timeout_s = 0.5;  // per transfer
};

// `daq.usb:` of root: vendor_id, product_id (integers or "0x1209" strings), serial,
// interface_number, timeout_s. Unknown keys: errors with file:line.
UsbTransportConfig parse_usb_yaml(const YAML::Node& root, const std::string& file);
// Those keys' table (the device's parser lifts them into its own).
const model::ParamTable<UsbTransportConfig>& usb_transport_params();

// "1209:4944" or "1209:4944 serial ABC".
std::string device_text(const UsbTransportConfig& config);

// A libusb error code (LIBUSB_ERROR_*) as a DriverStatus: "WHAT: MEANING (LIBUSB_ERROR_X)".
// NO_DEVICE -> disconnected (unplugged), ACCESS -> permission_denied (with the udev hint),
// TIMEOUT -> timeout, NOT_FOUND -> no_device, BUSY -> device_error (interface claimed elsewhere),
// PIPE -> device_error (the bridge stalled the request), OVERFLOW -> protocol_error, others ->
// device_error. 0 and positive values are success.
DriverStatus usb_status(int libusb_error, const std::string& what, const std::string& device);

// The waveform blocks of one burst: codes split into packets of at most max_samples(format),
// sequence numbers from first_sequence, FIRST on the first and LAST on the last (an empty burst
// is one LAST packet with no samples). Appends each packet's bytes to `transfers`.
CodecStatus build_waveform_blocks(std::span<const std::int32_t> codes, SampleFormat format,
                                  std::uint32_t first_sequence,
                                  std::vector<std::vector<std::uint8_t>>& transfers);

// Position packets of one bulk IN transfer, decoded in order and appended to `records`, each
// packet's sequence checked by `tracker`. `last` is set when a packet has LAST; `lost` is set
// when a packet has DROPPED or a sequence gap was seen (samples are missing: the caller marks
// the stream). A malformed packet stops the parse with its codec error (the records of the
// packets before it are kept).
struct PositionTransfer {
  bool last = false;
  bool lost = false;
  std::size_t packets = 0;
};
CodecStatus parse_position_transfer(std::span<const std::uint8_t> bytes, SequenceTracker& tracker,
                                    std::vector<PositionRecord>& records, PositionTransfer& info);

class UsbTransport {
 public:
  explicit UsbTransport(const UsbTransportConfig& config);  // no I/O
  ~UsbTransport();
  UsbTransport(const UsbTransport&) = delete;
  UsbTransport& operator=(const UsbTransport&) = delete;

  // Finds the bridge, opens it, claims the interface (detaching a kernel driver), reads GET_INFO
  // and checks its protocol version.
  DriverStatus open();
  void close();
  bool is_open() const { return handle_ != nullptr; }
  const BridgeInfo& info() const { return info_; }
  const UsbTransportConfig& config() const { return config_; }

  // Vendor control requests.
  DriverStatus start();
  DriverStatus stop();
  DriverStatus configure(const BridgeConfig& config);  // resets both sequence counters
  DriverStatus get_status(BridgeStatus& status);
  DriverStatus get_info(BridgeInfo& info);
  // LATCH: one position record latched now. A bridge without LATCH stalls it: `unsupported`.
  DriverStatus latch(PositionRecord& record);

  // A whole burst's DAC codes as waveform blocks on bulk OUT.
  DriverStatus send_waveform(std::span<const std::int32_t> codes, SampleFormat format);
  // One bulk IN transfer of position packets (see parse_position_transfer).
  DriverStatus receive_positions(std::vector<PositionRecord>& records, PositionTransfer& info);

 private:
  DriverStatus not_open(const char* what) const;
  DriverStatus control(Request request, std::span<std::uint8_t> data, const char* what);
  DriverStatus transfer_failed(int code, const std::string& what);
  unsigned timeout_ms() const;

  UsbTransportConfig config_;
  std::string device_;
  libusb_context* context_ = nullptr;
  libusb_device_handle* handle_ = nullptr;
  BridgeInfo info_;
  std::uint32_t out_sequence_ = 0;
  SequenceTracker in_sequence_;
  std::vector<std::vector<std::uint8_t>> out_packets_;
  std::vector<std::uint8_t> in_buffer_;
};

}  // namespace idm::drivers::usb
