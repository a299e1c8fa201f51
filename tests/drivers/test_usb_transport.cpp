// The USB bridge transport and backend without a device: libusb error mapping, burst packetizing,
// parsing of bulk IN transfers (sequence gaps, repeats, dropped flags, corrupt packets), the
// config, and the errors of opening a bridge that is not there.
#include <gtest/gtest.h>
#include <libusb-1.0/libusb.h>

#include <cmath>
#include <numeric>
#include <string>
#include <vector>

#include "drivers/backends.h"
#include "drivers/usb/transport.h"
#include "drivers/usb/usb_backend.h"
#include "model/stage.h"

using namespace idm::drivers;
using namespace idm::drivers::usb;

namespace {

std::vector<std::uint8_t> position_packet(std::uint32_t sequence, std::uint8_t flags, std::size_t n,
                                          std::uint64_t first_tick) {
  PositionPacket p;
  p.sequence = sequence;
  p.flags = flags;
  for (std::size_t i = 0; i < n; ++i)
    p.samples.push_back(
        {first_tick + i, encode_position_word(static_cast<std::int64_t>(i), WordWidth::Bits32)});
  std::vector<std::uint8_t> bytes;
  EXPECT_TRUE(encode_position_packet(p, bytes).ok());
  return bytes;
}

}  // namespace

TEST(UsbTransport, LibusbErrorsBecomeClearStatuses) {
  const std::string dev = "1209:4944";
  struct Case {
    int code;
    DriverError error;
    const char* words;
  } cases[] = {
      {LIBUSB_ERROR_NO_DEVICE, DriverError::Disconnected, "unplugged"},
      {LIBUSB_ERROR_ACCESS, DriverError::PermissionDenied, "udev rule"},
      {LIBUSB_ERROR_TIMEOUT, DriverError::Timeout, "did not answer in time"},
      {LIBUSB_ERROR_NOT_FOUND, DriverError::NoDevice, "not found"},
      {LIBUSB_ERROR_BUSY, DriverError::DeviceError, "claimed by another"},
      {LIBUSB_ERROR_PIPE, DriverError::DeviceError, "stalled the request"},
      {LIBUSB_ERROR_OVERFLOW, DriverError::ProtocolError, "more data than asked"},
      {LIBUSB_ERROR_IO, DriverError::DeviceError, "LIBUSB_ERROR_IO"},
  };
  for (const Case& c : cases) {
    const DriverStatus s = usb_status(c.code, "start", dev);
    EXPECT_EQ(s.error, c.error) << libusb_error_name(c.code);
    EXPECT_NE(s.message.find(c.words), std::string::npos) << s.message;
    EXPECT_EQ(s.message.rfind("start: ", 0), 0u) << s.message;
    EXPECT_NE(s.message.find(dev), std::string::npos) << s.message;
  }
  EXPECT_TRUE(usb_status(0, "start", dev).ok());
  EXPECT_TRUE(usb_status(12, "bulk", dev).ok());
}

TEST(UsbTransport, ABurstIsSplitIntoSequencedBlocksWithFirstAndLast) {
  std::vector<std::int32_t> codes(20000);
  std::iota(codes.begin(), codes.end(), -10000);
  std::vector<std::vector<std::uint8_t>> transfers;
  ASSERT_TRUE(build_waveform_blocks(codes, SampleFormat::DacInt16, 7, transfers).ok());
  ASSERT_EQ(transfers.size(), 3u);  // 8192 + 8192 + 3616
  std::vector<std::int32_t> back;
  for (std::size_t p = 0; p < transfers.size(); ++p) {
    WaveformBlock b;
    std::size_t consumed = 0;
    ASSERT_TRUE(decode_waveform_block(transfers[p], b, consumed).ok());
    EXPECT_EQ(consumed, transfers[p].size());
    EXPECT_EQ(b.sequence, 7 + p);
    EXPECT_EQ((b.flags & packet_flag::kFirst) != 0, p == 0);
    EXPECT_EQ((b.flags & packet_flag::kLast) != 0, p == 2);
    back.insert(back.end(), b.dac_codes.begin(), b.dac_codes.end());
  }
  EXPECT_EQ(back, codes);

  transfers.clear();
  ASSERT_TRUE(build_waveform_blocks({}, SampleFormat::DacInt32, 0, transfers).ok());
  ASSERT_EQ(transfers.size(), 1u);
  std::vector<std::int32_t> too_big = {70000};
  transfers.clear();
  const CodecStatus s = build_waveform_blocks(too_big, SampleFormat::DacInt16, 0, transfers);
  EXPECT_FALSE(s.ok());
  EXPECT_TRUE(transfers.empty());
  EXPECT_EQ(build_waveform_blocks(codes, SampleFormat::PositionRecord, 0, transfers).error,
            CodecError::BadSampleFormat);
}

TEST(UsbTransport, PositionTransfersAreParsedWithSequenceChecks) {
  std::vector<std::uint8_t> bytes = position_packet(0, packet_flag::kFirst, 3, 100);
  const auto second = position_packet(1, 0, 2, 103);
  const auto third = position_packet(2, packet_flag::kLast, 1, 105);
  bytes.insert(bytes.end(), second.begin(), second.end());
  bytes.insert(bytes.end(), third.begin(), third.end());
  SequenceTracker tracker;
  std::vector<PositionRecord> records;
  PositionTransfer info;
  ASSERT_TRUE(parse_position_transfer(bytes, tracker, records, info).ok());
  EXPECT_EQ(info.packets, 3u);
  EXPECT_TRUE(info.last);
  EXPECT_FALSE(info.lost);
  ASSERT_EQ(records.size(), 6u);
  EXPECT_EQ(records[5].timestamp_ticks, 105u);

  // a gap: samples lost; a repeat: dropped; the DROPPED flag: samples lost
  records.clear();
  info = {};
  std::vector<std::uint8_t> more = position_packet(5, 0, 2, 200);
  const auto repeat = position_packet(5, 0, 2, 200);
  more.insert(more.end(), repeat.begin(), repeat.end());
  ASSERT_TRUE(parse_position_transfer(more, tracker, records, info).ok());
  EXPECT_TRUE(info.lost);
  EXPECT_EQ(records.size(), 2u);
  EXPECT_EQ(info.packets, 1u);
  info = {};
  ASSERT_TRUE(parse_position_transfer(position_packet(6, packet_flag::kDropped, 1, 300), tracker,
                                      records, info)
                  .ok());
  EXPECT_TRUE(info.lost);

  // corrupt and truncated packets: an error that says where; the records before it are kept
  std::vector<std::uint8_t> corrupt = position_packet(7, 0, 2, 400);
  const auto bad = position_packet(8, 0, 2, 402);
  corrupt.insert(corrupt.end(), bad.begin(), bad.end());
  corrupt[corrupt.size() - 10] ^= 0x40;
  records.clear();
  info = {};
  CodecStatus s = parse_position_transfer(corrupt, tracker, records, info);
  EXPECT_EQ(s.error, CodecError::CrcMismatch);
  EXPECT_NE(s.message.find("packet at byte " + std::to_string(bad.size())), std::string::npos)
      << s.message;
  EXPECT_EQ(records.size(), 2u);
  std::vector<std::uint8_t> truncated = position_packet(9, 0, 4, 500);
  truncated.resize(truncated.size() - 5);
  s = parse_position_transfer(truncated, tracker, records, info);
  EXPECT_EQ(s.error, CodecError::LengthExceedsBuffer);
}

TEST(UsbTransport, ConfigReadsHexIdsAndRejectsUnknownKeys) {
  const UsbTransportConfig c = parse_usb_yaml(
      YAML::Load("daq:\n  usb:\n    vendor_id: 0x1209\n    product_id: 18756\n    serial: B12\n"),
      "u.yaml");
  EXPECT_EQ(c.vendor_id, 0x1209);
  EXPECT_EQ(c.product_id, 0x4944);
  EXPECT_EQ(device_text(c), "1209:4944 serial B12");
  try {
    parse_usb_yaml(YAML::Load("daq:\n  usb:\n    vendor_id: 0x12345\n"), "u.yaml");
    ADD_FAILURE() << "no error";
  } catch (const idm::model::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("u.yaml:3: daq.usb.vendor_id"), std::string::npos)
        << e.what();
  }
  try {
    parse_usb_yaml(YAML::Load("daq:\n  usb:\n    pid: 3\n"), "u.yaml");
    ADD_FAILURE() << "no error";
  } catch (const idm::model::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("u.yaml:3: daq.usb.pid: unknown key"), std::string::npos)
        << e.what();
  }
}

TEST(UsbTransport, NoBridgeIsAClearErrorAndNothingRunsUnopened) {
  UsbTransportConfig c;
  c.vendor_id = 0xFFFE;  // no real device carries this id
  c.product_id = 0x0001;
  c.serial = "none";
  UsbTransport t(c);
  EXPECT_FALSE(t.is_open());
  const DriverStatus s = t.open();
  EXPECT_EQ(s.error, DriverError::NoDevice) << s.message;
  EXPECT_NE(s.message.find("no USB device fffe:0001 serial none"), std::string::npos) << s.message;
  EXPECT_FALSE(t.is_open());
  BridgeStatus status;
  EXPECT_EQ(t.get_status(status).error, DriverError::InvalidState);
  EXPECT_EQ(t.start().error, DriverError::InvalidState);
  std::vector<std::int32_t> codes = {0, 1, 0};
  const DriverStatus w = t.send_waveform(codes, SampleFormat::DacInt16);
  EXPECT_EQ(w.error, DriverError::InvalidState);
  EXPECT_NE(w.message.find("not open"), std::string::npos) << w.message;
}

// ---- the usb backend without a device ----

TEST(UsbBackend, DacCodesAndStreamTimes) {
  OutputCapabilities caps;  // +-10 V, 16 bits, 2.5e5 V/m: one code is 20/65536 V = 1.22 nm
  EXPECT_EQ(dac_code(0.0, caps), 0);
  EXPECT_EQ(dac_code(1e-6, caps), static_cast<std::int32_t>(std::lround(0.25 / (20.0 / 65536))));
  EXPECT_EQ(dac_code(-1e-6, caps), -dac_code(1e-6, caps));
  EXPECT_EQ(dac_code(caps.max_elongation_m(), caps), 32767);  // the top code is one LSB below
  EXPECT_EQ(dac_code(caps.min_elongation_m(), caps), -32768);
  const PositionRecord records[3] = {{1000, 1}, {1010, 2}, {1020, 3}};
  TimedWord out[3];
  records_to_stream(records, 3, 1000, 1e6, true, out);
  EXPECT_DOUBLE_EQ(out[0].t_s, 0.0);
  EXPECT_DOUBLE_EQ(out[2].t_s, 20e-6);
  EXPECT_EQ(out[0].word, 1u | position_word::kSampleOverrun);
  EXPECT_EQ(out[1].word, 2u);
}

TEST(UsbBackend, ConfigAndNoBridgeThroughTheTable) {
  try {
    make_backend("usb", YAML::Load("daq:\n  usb:\n    tail: 3\n"), "u.yaml");
    ADD_FAILURE() << "no error";
  } catch (const idm::model::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("u.yaml:3: daq.usb.tail: unknown key"), std::string::npos)
        << e.what();
  }
  Device d = make_backend(
      "usb", YAML::Load("daq: {usb: {vendor_id: 0xfffe, product_id: 2, position_rate_hz: 5e4}}"),
      "u.yaml");
  EXPECT_EQ(d.driver, "usb");
  EXPECT_EQ(d.output->capabilities().mode, OutputMode::BufferedSamples);
  EXPECT_DOUBLE_EQ(d.interferometer->capabilities().stream_rate_hz, 5e4);
  const DriverStatus s = d.configure();
  EXPECT_EQ(s.error, DriverError::NoDevice);
  EXPECT_NE(s.message.find("usb interferometer (fffe:0002): configure: open: no USB device"),
            std::string::npos)
      << s.message;
  EXPECT_EQ(d.interferometer->state(), LifecycleState::Unconfigured);
  EXPECT_TRUE(d.shutdown().ok());
}
