// The USB bridge's reply decoders (drivers/usb/protocol.h, transport.h): a bulk IN transfer of
// position packets through parse_position_transfer (what UsbTransport::receive_positions does with
// each transfer), the control replies (GET_STATUS, GET_INFO, LATCH) and, for the bridge's side,
// waveform blocks and CONFIGURE.
//
// Input: byte 0 bits 0..2 choose the decoder (0, 1: position transfer, 2: waveform blocks,
// 3: status, 4: info, 5: latch, 6: configure, 7: header), bit 3 asks the harness to write the
// right CRC into every packet whose header decodes (to get past the checksum to the fields);
// bytes 1..4 the sequence number the tracker expects first; the rest is the reply.
//
// Invariants: a decoder either succeeds or returns an error with a message (and, for packets,
// consumes nothing); what a decoder accepts, the matching encoder writes back byte for byte; a
// position transfer yields exactly the samples of its packets, less the repeated ones.
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <span>
#include <vector>

#include "drivers/usb/protocol.h"
#include "drivers/usb/transport.h"

using namespace idm::drivers::usb;
using Bytes = std::span<const std::uint8_t>;

namespace {

[[noreturn]] void fail(const char* what, const CodecStatus& status = {}) {
  std::fprintf(stderr, "fuzz_usb_protocol: %s (%s: %s)\n", what, codec_error_name(status.error),
               status.message.c_str());
  std::abort();
}

void check_error(const CodecStatus& s) {
  if (!s.ok() && s.message.empty()) fail("an error without a message", s);
}

bool equal(Bytes a, const std::vector<std::uint8_t>& b) {
  return a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin());
}

// Writes the right CRC into every packet whose header decodes, walking packet by packet.
void fix_crcs(std::vector<std::uint8_t>& bytes) {
  std::size_t at = 0;
  PacketHeader h;
  while (at < bytes.size() && decode_header(Bytes(bytes).subspan(at), h).ok()) {
    const std::size_t body = h.packet_bytes() - kCrcBytes;
    const std::uint32_t crc = crc32(Bytes(bytes).subspan(at, body));
    for (std::size_t i = 0; i < kCrcBytes; ++i)
      bytes[at + body + i] = static_cast<std::uint8_t>(crc >> (8 * i));
    at += h.packet_bytes();
  }
}

void position_transfer(Bytes bytes, std::uint32_t first_sequence) {
  SequenceTracker tracker(first_sequence);
  std::vector<PositionRecord> records;
  PositionTransfer info;
  const CodecStatus s = parse_position_transfer(bytes, tracker, records, info);
  check_error(s);
  // Walk it again packet by packet: each accepted packet re-encodes to its bytes, and the
  // records are those of the packets the tracker did not see before.
  SequenceTracker again(first_sequence);
  std::size_t at = 0, expected_records = 0, packets = 0;
  while (at < bytes.size()) {
    PositionPacket packet;
    std::size_t consumed = 0;
    const CodecStatus p = decode_position_packet(bytes.subspan(at), packet, consumed);
    check_error(p);
    if (!p.ok()) {
      if (consumed != 0) fail("a refused packet consumed bytes", p);
      if (s.ok()) fail("the transfer was accepted with a bad packet in it", p);
      break;
    }
    std::vector<std::uint8_t> encoded;
    if (!encode_position_packet(packet, encoded).ok() ||
        !equal(bytes.subspan(at, consumed), encoded))
      fail("an accepted position packet does not re-encode to its bytes");
    if (again.check(packet.sequence).error != CodecError::SequenceRepeat) {
      expected_records += packet.samples.size();
      ++packets;
    }
    at += consumed;
  }
  if (records.size() != expected_records || info.packets != packets)
    fail("the transfer's records are not its packets' samples", s);
}

void waveform_blocks(Bytes bytes) {
  std::size_t at = 0;
  while (at < bytes.size()) {
    WaveformBlock block;
    std::size_t consumed = 0;
    const CodecStatus s = decode_waveform_block(bytes.subspan(at), block, consumed);
    check_error(s);
    if (!s.ok()) {
      if (consumed != 0) fail("a refused block consumed bytes", s);
      return;
    }
    std::vector<std::uint8_t> encoded;
    const CodecStatus e = encode_waveform_block(block, encoded);
    if (!e.ok() || !equal(bytes.subspan(at, consumed), encoded))
      fail("an accepted waveform block does not re-encode to its bytes", e);
    at += consumed;
  }
}

// A control reply: decoded, then encoded back.
template <typename T>
void control_reply(Bytes bytes, CodecStatus (*decode)(Bytes, T&),
                   CodecStatus (*encode)(const T&, std::vector<std::uint8_t>&)) {
  T value{};
  const CodecStatus s = decode(bytes, value);
  check_error(s);
  if (!s.ok()) return;
  std::vector<std::uint8_t> encoded;
  const CodecStatus e = encode(value, encoded);
  if (!e.ok() || !equal(bytes, encoded))
    fail("an accepted reply does not re-encode to its bytes", e);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 5) return 0;
  const std::uint32_t first_sequence =
      static_cast<std::uint32_t>(data[1]) | static_cast<std::uint32_t>(data[2]) << 8 |
      static_cast<std::uint32_t>(data[3]) << 16 | static_cast<std::uint32_t>(data[4]) << 24;
  std::vector<std::uint8_t> bytes(data + 5, data + size);
  if (data[0] & 8) fix_crcs(bytes);
  switch (data[0] & 7) {
    case 0:
    case 1:
      position_transfer(bytes, first_sequence);
      break;
    case 2:
      waveform_blocks(bytes);
      break;
    case 3:
      control_reply<BridgeStatus>(bytes, &decode_status, &encode_status);
      break;
    case 4:
      control_reply<BridgeInfo>(bytes, &decode_info, &encode_info);
      break;
    case 5:
      control_reply<PositionRecord>(bytes, &decode_latch, &encode_latch);
      break;
    case 6:
      control_reply<BridgeConfig>(bytes, &decode_config, &encode_config);
      break;
    case 7: {
      PacketHeader h;
      const CodecStatus s = decode_header(bytes, h);
      check_error(s);
      if (s.ok() && h.packet_bytes() > bytes.size())
        fail("a header whose packet leaves the buffer");
      break;
    }
  }
  return 0;
}
