#include "drivers/usb/protocol.h"

#include <array>
#include <limits>
#include <sstream>

namespace idm::drivers::usb {

namespace {

// ---- little-endian primitives ----

void put_u8(std::vector<std::uint8_t>& out, std::uint8_t v) {
  out.push_back(v);
}

void put_u16(std::vector<std::uint8_t>& out, std::uint16_t v) {
  out.push_back(static_cast<std::uint8_t>(v & 0xFFu));
  out.push_back(static_cast<std::uint8_t>(v >> 8));
}

void put_u32(std::vector<std::uint8_t>& out, std::uint32_t v) {
  for (int shift = 0; shift < 32; shift += 8) out.push_back(static_cast<std::uint8_t>(v >> shift));
}

void put_u64(std::vector<std::uint8_t>& out, std::uint64_t v) {
  for (int shift = 0; shift < 64; shift += 8) out.push_back(static_cast<std::uint8_t>(v >> shift));
}

std::uint16_t get_u16(std::span<const std::uint8_t> b, std::size_t at) {
  return static_cast<std::uint16_t>(b[at] | (b[at + 1] << 8));
}

std::uint32_t get_u32(std::span<const std::uint8_t> b, std::size_t at) {
  std::uint32_t v = 0;
  for (int i = 3; i >= 0; --i) v = (v << 8) | b[at + static_cast<std::size_t>(i)];
  return v;
}

std::uint64_t get_u64(std::span<const std::uint8_t> b, std::size_t at) {
  std::uint64_t v = 0;
  for (int i = 7; i >= 0; --i) v = (v << 8) | b[at + static_cast<std::size_t>(i)];
  return v;
}

CodecStatus fail(CodecError error, const std::string& message) {
  return CodecStatus{error, std::string(codec_error_name(error)) + ": " + message};
}

template <typename T>
std::string hex(T v, int digits = 2) {
  std::ostringstream s;
  s << "0x";
  s.width(digits);
  s.fill('0');
  s << std::hex << static_cast<std::uint64_t>(v);
  return s.str();
}

// ---- CRC-32 ----

constexpr std::array<std::uint32_t, 256> make_crc_table() {
  std::array<std::uint32_t, 256> table{};
  for (std::uint32_t i = 0; i < 256; ++i) {
    std::uint32_t c = i;
    for (int k = 0; k < 8; ++k) c = (c & 1u) ? (0xEDB88320u ^ (c >> 1)) : (c >> 1);
    table[i] = c;
  }
  return table;
}

constexpr std::array<std::uint32_t, 256> kCrcTable = make_crc_table();

// ---- packets ----

bool known_format(std::uint8_t v) {
  return v == static_cast<std::uint8_t>(SampleFormat::DacInt16) ||
         v == static_cast<std::uint8_t>(SampleFormat::DacInt32) ||
         v == static_cast<std::uint8_t>(SampleFormat::PositionRecord);
}

bool format_allowed(PacketType type, SampleFormat format) {
  if (type == PacketType::WaveformBlock)
    return format == SampleFormat::DacInt16 || format == SampleFormat::DacInt32;
  return format == SampleFormat::PositionRecord;
}

std::uint8_t flag_mask(PacketType type) {
  return type == PacketType::WaveformBlock ? packet_flag::kWaveformMask
                                           : packet_flag::kPositionMask;
}

const char* type_name(PacketType type) {
  return type == PacketType::WaveformBlock ? "waveform block" : "position samples";
}

// Checks the fields an encoder is given, the same rules decode_header applies to bytes.
CodecStatus check_header_fields(const PacketHeader& h, std::size_t samples) {
  if (!format_allowed(h.type, h.format))
    return fail(CodecError::BadSampleFormat, std::string("sample format ") + hex(h.format) +
                                                 " is not allowed in a " + type_name(h.type) +
                                                 " packet");
  if ((h.flags & ~flag_mask(h.type)) != 0)
    return fail(CodecError::ReservedNotZero, "flags " + hex(h.flags) +
                                                 " set reserved bits (allowed mask " +
                                                 hex(flag_mask(h.type)) + ")");
  if (samples > max_samples(h.format))
    return fail(CodecError::TooLarge, std::to_string(samples) + " samples, at most " +
                                          std::to_string(max_samples(h.format)) +
                                          " per packet in this format");
  return {};
}

void put_header(std::vector<std::uint8_t>& out, const PacketHeader& h) {
  for (std::uint8_t m : kMagic) put_u8(out, m);
  put_u8(out, kProtocolVersion);
  put_u8(out, static_cast<std::uint8_t>(h.type));
  put_u8(out, static_cast<std::uint8_t>(h.format));
  put_u8(out, h.flags);
  put_u32(out, h.sequence);
  put_u16(out, h.sample_count);
  put_u16(out, 0);  // reserved
}

void put_crc(std::vector<std::uint8_t>& out, std::size_t packet_start) {
  const std::span<const std::uint8_t> packet(out.data() + packet_start, out.size() - packet_start);
  put_u32(out, crc32(packet));
}

// Header and CRC of a packet of the expected type; on success `header` describes it.
CodecStatus check_packet(std::span<const std::uint8_t> bytes, PacketType expected,
                         PacketHeader& header) {
  CodecStatus status = decode_header(bytes, header);
  if (!status.ok()) return status;
  if (header.type != expected)
    return fail(CodecError::WrongPacketType, std::string("expected a ") + type_name(expected) +
                                                 " packet, got a " + type_name(header.type) +
                                                 " packet");
  const std::size_t crc_at = header.packet_bytes() - kCrcBytes;
  const std::uint32_t stored = get_u32(bytes, crc_at);
  const std::uint32_t computed = crc32(bytes.first(crc_at));
  if (stored != computed)
    return fail(CodecError::CrcMismatch, "packet sequence " + std::to_string(header.sequence) +
                                             ": stored CRC-32 " + hex(stored, 8) + ", computed " +
                                             hex(computed, 8));
  return {};
}

// ---- control payloads ----

CodecStatus check_length(std::span<const std::uint8_t> bytes, std::size_t expected,
                         const char* what) {
  if (bytes.size() == expected) return {};
  return fail(CodecError::BadLength, std::string(what) + " payload is " +
                                         std::to_string(bytes.size()) + " bytes, expected " +
                                         std::to_string(expected));
}

CodecStatus check_at_least_one(std::uint64_t value, const char* field) {
  if (value >= 1) return {};
  return fail(CodecError::BadValue, std::string(field) + ": 0, allowed >= 1");
}

CodecStatus check_config(const BridgeConfig& c) {
  for (auto [value, field] : {std::pair{c.dac_sample_rate_hz, "dac_sample_rate_hz"},
                              std::pair{c.burst_samples, "burst_samples"},
                              std::pair{c.position_sample_rate_hz, "position_sample_rate_hz"}}) {
    CodecStatus s = check_at_least_one(value, field);
    if (!s.ok()) return s;
  }
  if (c.dac_format != SampleFormat::DacInt16 && c.dac_format != SampleFormat::DacInt32)
    return fail(CodecError::BadSampleFormat,
                "dac_format " + hex(c.dac_format) + ", allowed 0x01 (int16) or 0x02 (int32)");
  return {};
}

CodecStatus check_status(const BridgeStatus& s) {
  if (static_cast<std::uint8_t>(s.state) > static_cast<std::uint8_t>(BridgeState::Fault))
    return fail(CodecError::BadValue,
                "state " + std::to_string(static_cast<unsigned>(s.state)) + ", allowed 0..4");
  if ((s.fault_flags & ~fault_flag::kMask) != 0)
    return fail(CodecError::ReservedNotZero, "fault_flags " + hex(s.fault_flags, 4) +
                                                 " set reserved bits (allowed mask " +
                                                 hex(fault_flag::kMask, 4) + ")");
  return {};
}

CodecStatus check_info(const BridgeInfo& i) {
  if (i.protocol_version != kProtocolVersion)
    return fail(CodecError::UnsupportedVersion,
                "bridge speaks protocol version " + std::to_string(i.protocol_version) +
                    ", this host speaks " + std::to_string(kProtocolVersion));
  if (i.dac_bits < 1 || i.dac_bits > 32)
    return fail(CodecError::BadValue, "dac_bits " + std::to_string(i.dac_bits) + ", allowed 1..32");
  if (i.position_word_bits != 32 && i.position_word_bits != 36)
    return fail(CodecError::BadValue, "position_word_bits " + std::to_string(i.position_word_bits) +
                                          ", allowed 32 or 36");
  for (auto [value, field] :
       {std::pair{i.tick_hz, "tick_hz"}, std::pair{i.max_dac_rate_hz, "max_dac_rate_hz"},
        std::pair{i.max_position_rate_hz, "max_position_rate_hz"}}) {
    CodecStatus s = check_at_least_one(value, field);
    if (!s.ok()) return s;
  }
  return {};
}

}  // namespace

const char* codec_error_name(CodecError error) {
  switch (error) {
    case CodecError::None:
      return "none";
    case CodecError::Truncated:
      return "truncated";
    case CodecError::BadMagic:
      return "bad magic";
    case CodecError::UnsupportedVersion:
      return "unsupported version";
    case CodecError::UnknownPacketType:
      return "unknown packet type";
    case CodecError::WrongPacketType:
      return "wrong packet type";
    case CodecError::BadSampleFormat:
      return "bad sample format";
    case CodecError::ReservedNotZero:
      return "reserved not zero";
    case CodecError::LengthExceedsBuffer:
      return "length exceeds buffer";
    case CodecError::TooLarge:
      return "too large";
    case CodecError::CrcMismatch:
      return "CRC mismatch";
    case CodecError::SequenceGap:
      return "sequence gap";
    case CodecError::SequenceRepeat:
      return "sequence repeat";
    case CodecError::BadLength:
      return "bad length";
    case CodecError::BadValue:
      return "bad value";
  }
  return "unknown error";
}

std::size_t sample_bytes(SampleFormat format) {
  switch (format) {
    case SampleFormat::DacInt16:
      return 2;
    case SampleFormat::DacInt32:
      return 4;
    case SampleFormat::PositionRecord:
      return 16;
  }
  return 0;
}

std::size_t max_samples(SampleFormat format) {
  const std::size_t bytes = sample_bytes(format);
  return bytes == 0 ? 0 : kMaxPayloadBytes / bytes;
}

std::uint32_t crc32(std::span<const std::uint8_t> bytes) {
  std::uint32_t c = 0xFFFFFFFFu;
  for (std::uint8_t b : bytes) c = kCrcTable[(c ^ b) & 0xFFu] ^ (c >> 8);
  return c ^ 0xFFFFFFFFu;
}

std::size_t PacketHeader::packet_bytes() const {
  return kHeaderBytes + sample_count * sample_bytes(format) + kCrcBytes;
}

CodecStatus encode_waveform_block(const WaveformBlock& block, std::vector<std::uint8_t>& out) {
  const PacketHeader h{PacketType::WaveformBlock, block.format, block.flags, block.sequence,
                       static_cast<std::uint16_t>(block.dac_codes.size())};
  CodecStatus status = check_header_fields(h, block.dac_codes.size());
  if (!status.ok()) return status;
  if (block.format == SampleFormat::DacInt16) {
    for (std::size_t i = 0; i < block.dac_codes.size(); ++i) {
      const std::int32_t code = block.dac_codes[i];
      if (code < std::numeric_limits<std::int16_t>::min() ||
          code > std::numeric_limits<std::int16_t>::max())
        return fail(CodecError::BadValue, "dac_codes[" + std::to_string(i) +
                                              "] = " + std::to_string(code) +
                                              " does not fit int16 (-32768..32767)");
    }
  }
  const std::size_t start = out.size();
  out.reserve(start + h.packet_bytes());
  put_header(out, h);
  for (std::int32_t code : block.dac_codes) {
    if (block.format == SampleFormat::DacInt16)
      put_u16(out, static_cast<std::uint16_t>(code));
    else
      put_u32(out, static_cast<std::uint32_t>(code));
  }
  put_crc(out, start);
  return {};
}

CodecStatus encode_position_packet(const PositionPacket& packet, std::vector<std::uint8_t>& out) {
  const PacketHeader h{PacketType::PositionSamples, SampleFormat::PositionRecord, packet.flags,
                       packet.sequence, static_cast<std::uint16_t>(packet.samples.size())};
  CodecStatus status = check_header_fields(h, packet.samples.size());
  if (!status.ok()) return status;
  const std::size_t start = out.size();
  out.reserve(start + h.packet_bytes());
  put_header(out, h);
  for (const PositionRecord& r : packet.samples) {
    put_u64(out, r.timestamp_ticks);
    put_u64(out, r.position_word);
  }
  put_crc(out, start);
  return {};
}

CodecStatus decode_header(std::span<const std::uint8_t> bytes, PacketHeader& header) {
  if (bytes.size() < kHeaderBytes)
    return fail(CodecError::Truncated, std::to_string(bytes.size()) +
                                           " bytes, a packet header needs " +
                                           std::to_string(kHeaderBytes));
  for (std::size_t i = 0; i < 4; ++i) {
    if (bytes[i] != kMagic[i])
      return fail(CodecError::BadMagic, "bytes 0..3 are " + hex(bytes[0]) + " " + hex(bytes[1]) +
                                            " " + hex(bytes[2]) + " " + hex(bytes[3]) +
                                            ", expected 0x49 0x44 0x4d 0x42 (\"IDMB\")");
  }
  if (bytes[4] != kProtocolVersion)
    return fail(CodecError::UnsupportedVersion, "version " + std::to_string(bytes[4]) +
                                                    ", this host speaks " +
                                                    std::to_string(kProtocolVersion));
  const std::uint8_t type = bytes[5];
  if (type != static_cast<std::uint8_t>(PacketType::WaveformBlock) &&
      type != static_cast<std::uint8_t>(PacketType::PositionSamples))
    return fail(CodecError::UnknownPacketType,
                "type " + hex(type) + ", known 0x01 (waveform block), 0x02 (position samples)");
  if (!known_format(bytes[6]))
    return fail(CodecError::BadSampleFormat,
                "sample format " + hex(bytes[6]) + ", known 0x01, 0x02, 0x03");
  PacketHeader h;
  h.type = static_cast<PacketType>(type);
  h.format = static_cast<SampleFormat>(bytes[6]);
  h.flags = bytes[7];
  h.sequence = get_u32(bytes, 8);
  h.sample_count = get_u16(bytes, 12);
  const std::uint16_t reserved = get_u16(bytes, 14);
  CodecStatus status = check_header_fields(h, h.sample_count);
  if (!status.ok()) return status;
  if (reserved != 0)
    return fail(CodecError::ReservedNotZero,
                "header bytes 14..15 are " + hex(reserved, 4) + ", must be 0");
  if (h.packet_bytes() > bytes.size())
    return fail(CodecError::LengthExceedsBuffer,
                std::to_string(h.sample_count) + " samples make a " +
                    std::to_string(h.packet_bytes()) + "-byte packet, the buffer holds " +
                    std::to_string(bytes.size()) + " bytes");
  header = h;
  return {};
}

CodecStatus decode_waveform_block(std::span<const std::uint8_t> bytes, WaveformBlock& out,
                                  std::size_t& consumed) {
  consumed = 0;
  PacketHeader h;
  CodecStatus status = check_packet(bytes, PacketType::WaveformBlock, h);
  if (!status.ok()) return status;
  out.sequence = h.sequence;
  out.flags = h.flags;
  out.format = h.format;
  out.dac_codes.resize(h.sample_count);
  std::size_t at = kHeaderBytes;
  for (std::int32_t& code : out.dac_codes) {
    if (h.format == SampleFormat::DacInt16) {
      code = static_cast<std::int16_t>(get_u16(bytes, at));
      at += 2;
    } else {
      code = static_cast<std::int32_t>(get_u32(bytes, at));
      at += 4;
    }
  }
  consumed = h.packet_bytes();
  return {};
}

CodecStatus decode_position_packet(std::span<const std::uint8_t> bytes, PositionPacket& out,
                                   std::size_t& consumed) {
  consumed = 0;
  PacketHeader h;
  CodecStatus status = check_packet(bytes, PacketType::PositionSamples, h);
  if (!status.ok()) return status;
  out.sequence = h.sequence;
  out.flags = h.flags;
  out.samples.resize(h.sample_count);
  std::size_t at = kHeaderBytes;
  for (PositionRecord& r : out.samples) {
    r.timestamp_ticks = get_u64(bytes, at);
    r.position_word = get_u64(bytes, at + 8);
    at += 16;
  }
  consumed = h.packet_bytes();
  return {};
}

CodecStatus SequenceTracker::check(std::uint32_t sequence) {
  const std::uint32_t ahead = sequence - expected_;  // modulo 2^32
  if (ahead == 0) {
    expected_ = sequence + 1;
    return {};
  }
  if (ahead < 0x80000000u) {
    lost_packets_ += ahead;
    CodecStatus s = fail(CodecError::SequenceGap, "expected sequence " + std::to_string(expected_) +
                                                      ", got " + std::to_string(sequence) + " (" +
                                                      std::to_string(ahead) + " packets lost)");
    expected_ = sequence + 1;
    return s;
  }
  return fail(CodecError::SequenceRepeat, "expected sequence " + std::to_string(expected_) +
                                              ", got " + std::to_string(sequence) +
                                              " (repeated or older)");
}

ControlSetup control_setup(Request request, std::uint16_t interface_number) {
  ControlSetup s;
  s.request = static_cast<std::uint8_t>(request);
  s.index = interface_number;
  switch (request) {
    case Request::Start:
    case Request::Stop:
      s.request_type = kRequestTypeOut;
      break;
    case Request::Configure:
      s.request_type = kRequestTypeOut;
      s.length = kConfigureBytes;
      break;
    case Request::GetStatus:
      s.request_type = kRequestTypeIn;
      s.length = kStatusBytes;
      break;
    case Request::GetInfo:
      s.request_type = kRequestTypeIn;
      s.length = kInfoBytes;
      break;
    case Request::Latch:
      s.request_type = kRequestTypeIn;
      s.length = kLatchBytes;
      break;
  }
  return s;
}

CodecStatus encode_config(const BridgeConfig& c, std::vector<std::uint8_t>& out) {
  CodecStatus status = check_config(c);
  if (!status.ok()) return status;
  put_u32(out, c.dac_sample_rate_hz);
  put_u32(out, c.burst_samples);
  put_u32(out, c.position_sample_rate_hz);
  put_u32(out, c.tail_samples);
  put_u8(out, static_cast<std::uint8_t>(c.dac_format));
  for (int i = 0; i < 3; ++i) put_u8(out, 0);
  return {};
}

CodecStatus decode_config(std::span<const std::uint8_t> bytes, BridgeConfig& out) {
  CodecStatus status = check_length(bytes, kConfigureBytes, "CONFIGURE");
  if (!status.ok()) return status;
  BridgeConfig c;
  c.dac_sample_rate_hz = get_u32(bytes, 0);
  c.burst_samples = get_u32(bytes, 4);
  c.position_sample_rate_hz = get_u32(bytes, 8);
  c.tail_samples = get_u32(bytes, 12);
  c.dac_format = static_cast<SampleFormat>(bytes[16]);
  if (bytes[17] != 0 || bytes[18] != 0 || bytes[19] != 0)
    return fail(CodecError::ReservedNotZero, "CONFIGURE bytes 17..19 must be 0");
  status = check_config(c);
  if (!status.ok()) return status;
  out = c;
  return {};
}

CodecStatus encode_status(const BridgeStatus& s, std::vector<std::uint8_t>& out) {
  CodecStatus status = check_status(s);
  if (!status.ok()) return status;
  put_u8(out, static_cast<std::uint8_t>(s.state));
  put_u8(out, 0);
  put_u16(out, s.fault_flags);
  put_u32(out, s.dac_samples_played);
  put_u32(out, s.positions_latched);
  put_u32(out, s.next_waveform_sequence);
  put_u32(out, s.buffer_free_samples);
  put_u64(out, s.device_time_ticks);
  return {};
}

CodecStatus decode_status(std::span<const std::uint8_t> bytes, BridgeStatus& out) {
  CodecStatus status = check_length(bytes, kStatusBytes, "GET_STATUS");
  if (!status.ok()) return status;
  if (bytes[1] != 0) return fail(CodecError::ReservedNotZero, "GET_STATUS byte 1 must be 0");
  BridgeStatus s;
  s.state = static_cast<BridgeState>(bytes[0]);
  s.fault_flags = get_u16(bytes, 2);
  s.dac_samples_played = get_u32(bytes, 4);
  s.positions_latched = get_u32(bytes, 8);
  s.next_waveform_sequence = get_u32(bytes, 12);
  s.buffer_free_samples = get_u32(bytes, 16);
  s.device_time_ticks = get_u64(bytes, 20);
  status = check_status(s);
  if (!status.ok()) return status;
  out = s;
  return {};
}

CodecStatus encode_info(const BridgeInfo& i, std::vector<std::uint8_t>& out) {
  CodecStatus status = check_info(i);
  if (!status.ok()) return status;
  put_u8(out, i.protocol_version);
  put_u8(out, i.dac_bits);
  put_u8(out, i.position_word_bits);
  put_u8(out, 0);
  put_u32(out, i.tick_hz);
  put_u32(out, i.max_dac_rate_hz);
  put_u32(out, i.buffer_capacity_samples);
  put_u32(out, i.max_position_rate_hz);
  return {};
}

CodecStatus decode_info(std::span<const std::uint8_t> bytes, BridgeInfo& out) {
  CodecStatus status = check_length(bytes, kInfoBytes, "GET_INFO");
  if (!status.ok()) return status;
  if (bytes[3] != 0) return fail(CodecError::ReservedNotZero, "GET_INFO byte 3 must be 0");
  BridgeInfo i;
  i.protocol_version = bytes[0];
  i.dac_bits = bytes[1];
  i.position_word_bits = bytes[2];
  i.tick_hz = get_u32(bytes, 4);
  i.max_dac_rate_hz = get_u32(bytes, 8);
  i.buffer_capacity_samples = get_u32(bytes, 12);
  i.max_position_rate_hz = get_u32(bytes, 16);
  status = check_info(i);
  if (!status.ok()) return status;
  out = i;
  return {};
}

CodecStatus encode_latch(const PositionRecord& r, std::vector<std::uint8_t>& out) {
  put_u64(out, r.timestamp_ticks);
  put_u64(out, r.position_word);
  return {};
}

CodecStatus decode_latch(std::span<const std::uint8_t> bytes, PositionRecord& out) {
  CodecStatus status = check_length(bytes, kLatchBytes, "LATCH");
  if (!status.ok()) return status;
  out.timestamp_ticks = get_u64(bytes, 0);
  out.position_word = get_u64(bytes, 8);
  return {};
}

}  // namespace idm::drivers::usb
