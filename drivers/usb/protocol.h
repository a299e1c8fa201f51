// The byte protocol of the USB bridge (a microcontroller or FPGA board that plays DAC samples and
// latches the axis board's position words). drivers/usb/README.md is the specification; this is
// its codec: explicit little-endian byte-by-byte encoding and decoding, no struct casts, and a
// CodecError with a message for every malformed input (never a crash, never a partial result
// reported as success).
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

namespace idm::drivers::usb {

inline constexpr std::uint8_t kProtocolVersion = 1;
inline constexpr std::uint8_t kMagic[4] = {'I', 'D', 'M', 'B'};

inline constexpr std::size_t kHeaderBytes = 16;
inline constexpr std::size_t kCrcBytes = 4;
inline constexpr std::size_t kMaxPayloadBytes = 16384;
inline constexpr std::size_t kMaxPacketBytes = kHeaderBytes + kMaxPayloadBytes + kCrcBytes;

enum class PacketType : std::uint8_t {
  WaveformBlock = 0x01,    // bulk OUT, host -> bridge
  PositionSamples = 0x02,  // bulk IN, bridge -> host
};

enum class SampleFormat : std::uint8_t {
  DacInt16 = 0x01,        // DAC code, int16, 2 bytes
  DacInt32 = 0x02,        // DAC code, int32, 4 bytes
  PositionRecord = 0x03,  // u64 timestamp in device ticks + u64 raw position word, 16 bytes
};

// Bytes per sample of a format; 0 for an unknown value.
std::size_t sample_bytes(SampleFormat format);
// Most samples of a format in one packet (kMaxPayloadBytes / sample_bytes).
std::size_t max_samples(SampleFormat format);

// Packet flag bits (header byte 7). Bits not listed for a packet type must be zero.
namespace packet_flag {
inline constexpr std::uint8_t kFirst = 1u << 0;    // first packet of a burst
inline constexpr std::uint8_t kLast = 1u << 1;     // last packet of a burst
inline constexpr std::uint8_t kDropped = 1u << 2;  // position samples only: the bridge's FIFO
                                                   // overflowed before this packet
inline constexpr std::uint8_t kWaveformMask = kFirst | kLast;
inline constexpr std::uint8_t kPositionMask = kFirst | kLast | kDropped;
}  // namespace packet_flag

enum class CodecError : std::uint8_t {
  None = 0,
  Truncated,            // fewer bytes than a header (or a control payload) needs
  BadMagic,             // bytes 0..3 are not "IDMB"
  UnsupportedVersion,   // version byte is not kProtocolVersion
  UnknownPacketType,    // type byte is not a PacketType
  WrongPacketType,      // a valid type, but not the one the caller decodes
  BadSampleFormat,      // format unknown or not allowed for the packet type
  ReservedNotZero,      // a reserved byte or flag bit is set
  LengthExceedsBuffer,  // the sample count needs more bytes than the buffer holds
  TooLarge,             // the sample count exceeds the per-packet maximum
  CrcMismatch,          // CRC-32 over the packet does not match
  SequenceGap,          // packets were lost between the last one and this one
  SequenceRepeat,       // a sequence number that was already seen (or older)
  BadLength,            // a control payload of the wrong length
  BadValue,             // a field value out of its allowed range
};

const char* codec_error_name(CodecError error);

// The outcome of one encode or decode: None, or the error and a message that says what was wrong
// with which byte or field.
struct CodecStatus {
  CodecError error = CodecError::None;
  std::string message;

  bool ok() const { return error == CodecError::None; }
};

// CRC-32 (IEEE 802.3: reflected polynomial 0xEDB88320, initial value and final XOR 0xFFFFFFFF);
// "123456789" gives 0xCBF43926.
std::uint32_t crc32(std::span<const std::uint8_t> bytes);

struct PacketHeader {
  PacketType type = PacketType::WaveformBlock;
  SampleFormat format = SampleFormat::DacInt16;
  std::uint8_t flags = 0;
  std::uint32_t sequence = 0;
  std::uint16_t sample_count = 0;

  // Header + payload + CRC.
  std::size_t packet_bytes() const;
};

struct WaveformBlock {
  std::uint32_t sequence = 0;
  std::uint8_t flags = 0;                        // packet_flag::kWaveformMask bits
  SampleFormat format = SampleFormat::DacInt16;  // DacInt16 or DacInt32
  std::vector<std::int32_t> dac_codes;           // in range of the format
};

struct PositionRecord {
  std::uint64_t timestamp_ticks = 0;  // device clock (BridgeInfo::tick_hz)
  std::uint64_t position_word = 0;    // raw layout of drivers/position_word.h
};

struct PositionPacket {
  std::uint32_t sequence = 0;
  std::uint8_t flags = 0;  // packet_flag::kPositionMask bits
  std::vector<PositionRecord> samples;
};

// Encoders append one packet to `out`. On an error nothing is appended.
CodecStatus encode_waveform_block(const WaveformBlock& block, std::vector<std::uint8_t>& out);
CodecStatus encode_position_packet(const PositionPacket& packet, std::vector<std::uint8_t>& out);

// Reads and checks the 16-byte header at the start of `bytes` (magic, version, type, format,
// reserved, count limits and that the whole packet fits in `bytes`); the CRC is not checked.
CodecStatus decode_header(std::span<const std::uint8_t> bytes, PacketHeader& header);

// Decodes the packet at the start of `bytes` (which may hold more packets after it) with every
// check, CRC included. `consumed` is set to the packet's size on success and to 0 on error.
// `out` is overwritten on success only (its vector keeps its capacity: no allocation in steady
// state).
CodecStatus decode_waveform_block(std::span<const std::uint8_t> bytes, WaveformBlock& out,
                                  std::size_t& consumed);
CodecStatus decode_position_packet(std::span<const std::uint8_t> bytes, PositionPacket& out,
                                   std::size_t& consumed);

// Checks the sequence numbers of one direction: after reset(first) the next packet must carry
// `first`, then every packet the previous + 1 (mod 2^32). A gap is reported once (the tracker
// then follows the new number); a repeated or older number is reported and not followed.
class SequenceTracker {
 public:
  explicit SequenceTracker(std::uint32_t first = 0) : expected_(first) {}
  void reset(std::uint32_t first = 0) { expected_ = first; }
  CodecStatus check(std::uint32_t sequence);
  std::uint32_t expected() const { return expected_; }
  std::uint64_t lost_packets() const { return lost_packets_; }

 private:
  std::uint32_t expected_;
  std::uint64_t lost_packets_ = 0;
};

// ---- Vendor control requests (endpoint 0) ----

inline constexpr std::uint8_t kRequestTypeOut = 0x41;  // host-to-device | vendor | interface
inline constexpr std::uint8_t kRequestTypeIn = 0xC1;   // device-to-host | vendor | interface

enum class Request : std::uint8_t {
  Start = 0x01,      // OUT, no data: begin the configured burst
  Stop = 0x02,       // OUT, no data: output to the zero code now, flush, end the burst
  Configure = 0x03,  // OUT, 20 bytes: BridgeConfig
  GetStatus = 0x04,  // IN, 28 bytes: BridgeStatus
  GetInfo = 0x05,    // IN, 20 bytes: BridgeInfo
  Latch = 0x06,      // IN, 16 bytes: one position record latched now (LatchReply)
};

// The setup packet fields of a request (wValue 0, wIndex = interface number, wLength = the
// payload size of the request).
struct ControlSetup {
  std::uint8_t request_type = 0;
  std::uint8_t request = 0;
  std::uint16_t value = 0;
  std::uint16_t index = 0;
  std::uint16_t length = 0;
};
ControlSetup control_setup(Request request, std::uint16_t interface_number = 0);

inline constexpr std::size_t kConfigureBytes = 20;
inline constexpr std::size_t kStatusBytes = 28;
inline constexpr std::size_t kInfoBytes = 20;
inline constexpr std::size_t kLatchBytes = 16;

struct BridgeConfig {
  std::uint32_t dac_sample_rate_hz = 100000;         // >= 1
  std::uint32_t burst_samples = 0;                   // DAC samples in the burst, >= 1
  std::uint32_t position_sample_rate_hz = 100000;    // >= 1
  std::uint32_t tail_samples = 0;                    // position samples latched after the burst
  SampleFormat dac_format = SampleFormat::DacInt16;  // DacInt16 or DacInt32
};

enum class BridgeState : std::uint8_t {
  Idle = 0,
  Configured = 1,
  Running = 2,
  Finished = 3,
  Fault = 4
};

namespace fault_flag {
inline constexpr std::uint16_t kUnderrun = 1u << 0;          // DAC buffer ran dry mid-burst
inline constexpr std::uint16_t kPositionOverflow = 1u << 1;  // position FIFO overflowed
inline constexpr std::uint16_t kCrcError = 1u << 2;          // a waveform block failed its CRC
inline constexpr std::uint16_t kSequenceError = 1u << 3;     // a waveform block out of sequence
inline constexpr std::uint16_t kBadConfig = 1u << 4;         // CONFIGURE rejected
inline constexpr std::uint16_t kAxisError = 1u << 5;         // the axis board reports an error
inline constexpr std::uint16_t kMask = 0x3F;
}  // namespace fault_flag

struct BridgeStatus {
  BridgeState state = BridgeState::Idle;
  std::uint16_t fault_flags = 0;
  std::uint32_t dac_samples_played = 0;
  std::uint32_t positions_latched = 0;
  std::uint32_t next_waveform_sequence = 0;  // the sequence number the bridge expects next
  std::uint32_t buffer_free_samples = 0;
  std::uint64_t device_time_ticks = 0;
};

struct BridgeInfo {
  std::uint8_t protocol_version = kProtocolVersion;
  std::uint8_t dac_bits = 16;            // 1..32
  std::uint8_t position_word_bits = 32;  // 32 or 36
  std::uint32_t tick_hz = 0;             // >= 1
  std::uint32_t max_dac_rate_hz = 0;     // >= 1
  std::uint32_t buffer_capacity_samples = 0;
  std::uint32_t max_position_rate_hz = 0;  // >= 1
};

// Encoders append exactly k*Bytes bytes to `out` (nothing, and BadValue, on an out-of-range field).
CodecStatus encode_config(const BridgeConfig& config, std::vector<std::uint8_t>& out);
CodecStatus encode_status(const BridgeStatus& status, std::vector<std::uint8_t>& out);
CodecStatus encode_info(const BridgeInfo& info, std::vector<std::uint8_t>& out);
// Decoders require exactly k*Bytes bytes (BadLength otherwise) and check every field.
CodecStatus decode_config(std::span<const std::uint8_t> bytes, BridgeConfig& out);
CodecStatus decode_status(std::span<const std::uint8_t> bytes, BridgeStatus& out);
CodecStatus decode_info(std::span<const std::uint8_t> bytes, BridgeInfo& out);
// LATCH: the position record the bridge latched when it received the request (the same 16 bytes
// as a record in a position packet: u64 device ticks, u64 raw position word).
CodecStatus encode_latch(const PositionRecord& record, std::vector<std::uint8_t>& out);
CodecStatus decode_latch(std::span<const std::uint8_t> bytes, PositionRecord& out);

}  // namespace idm::drivers::usb
