#include <gtest/gtest.h>

#include <cstdint>
#include <random>
#include <string>
#include <vector>

#include "drivers/position_word.h"
#include "drivers/usb/protocol.h"

using namespace idm::drivers::usb;
using Bytes = std::vector<std::uint8_t>;

namespace {

// Golden packets: bytes written out by hand from drivers/usb/README.md; the CRC-32 values were
// computed by an independent implementation (zlib's crc32) over the bytes before them.

// Waveform block, int16, sequence 0x01020304, flags FIRST, codes {0, 1, -1, 32767, -32768}.
const Bytes kWaveform16 = {
    0x49, 0x44, 0x4d, 0x42,                                      // magic "IDMB"
    0x01,                                                        // version
    0x01,                                                        // type: waveform block
    0x01,                                                        // format: int16
    0x01,                                                        // flags: FIRST
    0x04, 0x03, 0x02, 0x01,                                      // sequence
    0x05, 0x00,                                                  // sample count
    0x00, 0x00,                                                  // reserved
    0x00, 0x00, 0x01, 0x00, 0xff, 0xff, 0xff, 0x7f, 0x00, 0x80,  // codes
    0xd4, 0xf2, 0x9b, 0x3b,                                      // CRC-32
};

// Waveform block, int32, sequence 0xFFFFFFFF, no flags, codes {-2, 65536}.
const Bytes kWaveform32 = {
    0x49, 0x44, 0x4d, 0x42, 0x01, 0x01, 0x02, 0x00, 0xff, 0xff, 0xff, 0xff,
    0x02, 0x00, 0x00, 0x00, 0xfe, 0xff, 0xff, 0xff, 0x00, 0x00, 0x01, 0x00,  // codes
    0xc5, 0x84, 0x40, 0xfc,                                                  // CRC-32
};

// Position samples, sequence 7, flags LAST|DROPPED, two records.
const Bytes kPositions = {
    0x49, 0x44, 0x4d, 0x42, 0x01, 0x02, 0x03, 0x06, 0x07, 0x00, 0x00, 0x00, 0x02, 0x00, 0x00, 0x00,
    0x88, 0x77, 0x66, 0x55, 0x44, 0x33, 0x22, 0x11,  // timestamp
                                                     // 0x1122334455667788
    0x05, 0x00, 0x00, 0x00, 0x00, 0x01, 0x00, 0x00,  // word: valid, count 5
    0xe8, 0x03, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,  // timestamp 1000
    0xff, 0xff, 0xff, 0xff, 0x0f, 0x01, 0x00, 0x00,  // word: valid, 36-bit count -1
    0x6e, 0x8d, 0x83, 0x70,                          // CRC-32
};

// Position samples, sequence 8, flags LAST, no records (end of burst marker).
const Bytes kEmptyPositions = {
    0x49, 0x44, 0x4d, 0x42, 0x01, 0x02, 0x03, 0x02, 0x08, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0xbb, 0x73, 0x46, 0xa1,
};

const Bytes kConfigure = {
    0xa0, 0x86, 0x01, 0x00,  // dac_sample_rate_hz 100000
    0xc4, 0x09, 0x00, 0x00,  // burst_samples 2500
    0x50, 0xc3, 0x00, 0x00,  // position_sample_rate_hz 50000
    0xe8, 0x03, 0x00, 0x00,  // tail_samples 1000
    0x01, 0x00, 0x00, 0x00,  // dac_format int16, reserved
};

const Bytes kStatus = {
    0x02, 0x00, 0x21, 0x00,                          // running, reserved, UNDERRUN|AXIS_ERROR
    0xd2, 0x04, 0x00, 0x00,                          // dac_samples_played 1234
    0x37, 0x02, 0x00, 0x00,                          // positions_latched 567
    0x2a, 0x00, 0x00, 0x00,                          // next_waveform_sequence 42
    0x00, 0x10, 0x00, 0x00,                          // buffer_free_samples 4096
    0x08, 0x07, 0x06, 0x05, 0x04, 0x03, 0x02, 0x01,  // device_time_ticks
};

const Bytes kInfo = {
    0x01, 0x10, 0x24, 0x00,  // version 1, 16-bit DAC, 36-bit words, reserved
    0x00, 0x6c, 0xdc, 0x02,  // tick_hz 48e6
    0x40, 0x42, 0x0f, 0x00,  // max_dac_rate_hz 1e6
    0x00, 0x00, 0x01, 0x00,  // buffer_capacity_samples 65536
    0x40, 0x0d, 0x03, 0x00,  // max_position_rate_hz 200000
};

WaveformBlock waveform16() {
  WaveformBlock b;
  b.sequence = 0x01020304;
  b.flags = packet_flag::kFirst;
  b.format = SampleFormat::DacInt16;
  b.dac_codes = {0, 1, -1, 32767, -32768};
  return b;
}

PositionPacket positions() {
  PositionPacket p;
  p.sequence = 7;
  p.flags = packet_flag::kLast | packet_flag::kDropped;
  p.samples = {{0x1122334455667788ull, 0x0000010000000005ull},
               {1000, idm::drivers::encode_position_word(-1, idm::drivers::WordWidth::Bits36)}};
  return p;
}

CodecError decode_any_position(const Bytes& b) {
  PositionPacket p;
  std::size_t used = 99;
  const CodecStatus s = decode_position_packet(b, p, used);
  if (!s.ok()) {
    EXPECT_EQ(used, 0u);
    EXPECT_FALSE(s.message.empty());
  }
  return s.error;
}

CodecError decode_any_waveform(const Bytes& b) {
  WaveformBlock w;
  std::size_t used = 99;
  const CodecStatus s = decode_waveform_block(b, w, used);
  if (!s.ok()) {
    EXPECT_EQ(used, 0u);
    EXPECT_FALSE(s.message.empty());
  }
  return s.error;
}

// Re-seals a packet whose bytes were edited, so that a test reaches the check after the CRC.
void reseal(Bytes& b) {
  const std::size_t body = b.size() - kCrcBytes;
  const std::uint32_t crc = crc32(std::span<const std::uint8_t>(b.data(), body));
  for (std::size_t i = 0; i < 4; ++i) b[body + i] = static_cast<std::uint8_t>(crc >> (8 * i));
}

}  // namespace

TEST(UsbProtocol, Crc32CheckValue) {
  const std::string s = "123456789";
  EXPECT_EQ(crc32(std::span<const std::uint8_t>(reinterpret_cast<const std::uint8_t*>(s.data()),
                                                s.size())),
            0xCBF43926u);
  EXPECT_EQ(crc32({}), 0u);
}

TEST(UsbProtocol, EncodesGoldenPacketsByteForByte) {
  Bytes out;
  ASSERT_TRUE(encode_waveform_block(waveform16(), out).ok());
  EXPECT_EQ(out, kWaveform16);

  WaveformBlock w32;
  w32.sequence = 0xFFFFFFFFu;
  w32.format = SampleFormat::DacInt32;
  w32.dac_codes = {-2, 65536};
  out.clear();
  ASSERT_TRUE(encode_waveform_block(w32, out).ok());
  EXPECT_EQ(out, kWaveform32);

  out.clear();
  ASSERT_TRUE(encode_position_packet(positions(), out).ok());
  EXPECT_EQ(out, kPositions);

  PositionPacket empty;
  empty.sequence = 8;
  empty.flags = packet_flag::kLast;
  out.clear();
  ASSERT_TRUE(encode_position_packet(empty, out).ok());
  EXPECT_EQ(out, kEmptyPositions);

  // Encoders append.
  ASSERT_TRUE(encode_position_packet(positions(), out).ok());
  EXPECT_EQ(out.size(), kEmptyPositions.size() + kPositions.size());
}

TEST(UsbProtocol, DecodesGoldenPackets) {
  WaveformBlock w;
  std::size_t used = 0;
  CodecStatus s = decode_waveform_block(kWaveform16, w, used);
  ASSERT_TRUE(s.ok()) << s.message;
  EXPECT_EQ(used, kWaveform16.size());
  EXPECT_EQ(w.sequence, 0x01020304u);
  EXPECT_EQ(w.flags, packet_flag::kFirst);
  EXPECT_EQ(w.format, SampleFormat::DacInt16);
  EXPECT_EQ(w.dac_codes, (std::vector<std::int32_t>{0, 1, -1, 32767, -32768}));

  s = decode_waveform_block(kWaveform32, w, used);
  ASSERT_TRUE(s.ok()) << s.message;
  EXPECT_EQ(w.sequence, 0xFFFFFFFFu);
  EXPECT_EQ(w.dac_codes, (std::vector<std::int32_t>{-2, 65536}));

  PositionPacket p;
  s = decode_position_packet(kPositions, p, used);
  ASSERT_TRUE(s.ok()) << s.message;
  EXPECT_EQ(used, 52u);
  EXPECT_EQ(p.sequence, 7u);
  EXPECT_EQ(p.flags, packet_flag::kLast | packet_flag::kDropped);
  ASSERT_EQ(p.samples.size(), 2u);
  EXPECT_EQ(p.samples[0].timestamp_ticks, 0x1122334455667788ull);
  EXPECT_EQ(p.samples[0].position_word, 0x0000010000000005ull);
  EXPECT_EQ(p.samples[1].timestamp_ticks, 1000u);
  EXPECT_EQ(idm::drivers::word_count(p.samples[1].position_word, idm::drivers::WordWidth::Bits36),
            -1);

  PacketHeader h;
  ASSERT_TRUE(decode_header(kPositions, h).ok());
  EXPECT_EQ(h.type, PacketType::PositionSamples);
  EXPECT_EQ(h.format, SampleFormat::PositionRecord);
  EXPECT_EQ(h.sample_count, 2u);
  EXPECT_EQ(h.packet_bytes(), 52u);
}

TEST(UsbProtocol, SeveralPacketsInOneTransfer) {
  Bytes transfer = kEmptyPositions;
  transfer.insert(transfer.end(), kPositions.begin(), kPositions.end());
  transfer.insert(transfer.end(), kPositions.begin(), kPositions.end());
  std::span<const std::uint8_t> rest(transfer);
  PositionPacket p;
  std::vector<std::size_t> counts;
  while (!rest.empty()) {
    std::size_t used = 0;
    const CodecStatus s = decode_position_packet(rest, p, used);
    ASSERT_TRUE(s.ok()) << s.message;
    counts.push_back(p.samples.size());
    rest = rest.subspan(used);
  }
  EXPECT_EQ(counts, (std::vector<std::size_t>{0, 2, 2}));
}

TEST(UsbProtocol, RoundTripsRandomPackets) {
  std::mt19937_64 rng(7);
  for (int trial = 0; trial < 200; ++trial) {
    WaveformBlock w;
    w.sequence = static_cast<std::uint32_t>(rng());
    w.flags = static_cast<std::uint8_t>(rng() & packet_flag::kWaveformMask);
    w.format = (rng() & 1) ? SampleFormat::DacInt16 : SampleFormat::DacInt32;
    w.dac_codes.resize(rng() % (max_samples(w.format) + 1));
    for (auto& c : w.dac_codes) {
      c = static_cast<std::int32_t>(rng());
      if (w.format == SampleFormat::DacInt16) c = static_cast<std::int16_t>(c);
    }
    Bytes b;
    ASSERT_TRUE(encode_waveform_block(w, b).ok());
    ASSERT_EQ(b.size(), kHeaderBytes + w.dac_codes.size() * sample_bytes(w.format) + kCrcBytes);
    WaveformBlock back;
    std::size_t used = 0;
    ASSERT_TRUE(decode_waveform_block(b, back, used).ok());
    EXPECT_EQ(used, b.size());
    EXPECT_EQ(back.sequence, w.sequence);
    EXPECT_EQ(back.flags, w.flags);
    EXPECT_EQ(back.format, w.format);
    EXPECT_EQ(back.dac_codes, w.dac_codes);

    PositionPacket p;
    p.sequence = static_cast<std::uint32_t>(rng());
    p.flags = static_cast<std::uint8_t>(rng() & packet_flag::kPositionMask);
    p.samples.resize(rng() % (max_samples(SampleFormat::PositionRecord) + 1));
    for (auto& r : p.samples) r = {rng(), rng()};
    b.clear();
    ASSERT_TRUE(encode_position_packet(p, b).ok());
    PositionPacket pback;
    ASSERT_TRUE(decode_position_packet(b, pback, used).ok());
    EXPECT_EQ(pback.sequence, p.sequence);
    EXPECT_EQ(pback.flags, p.flags);
    ASSERT_EQ(pback.samples.size(), p.samples.size());
    for (std::size_t i = 0; i < p.samples.size(); ++i) {
      ASSERT_EQ(pback.samples[i].timestamp_ticks, p.samples[i].timestamp_ticks);
      ASSERT_EQ(pback.samples[i].position_word, p.samples[i].position_word);
    }
  }
}

TEST(UsbProtocol, EncoderRejectsWhatTheDecoderWould) {
  Bytes out;
  WaveformBlock w = waveform16();
  w.dac_codes[2] = 40000;
  CodecStatus s = encode_waveform_block(w, out);
  EXPECT_EQ(s.error, CodecError::BadValue);
  EXPECT_NE(s.message.find("dac_codes[2] = 40000"), std::string::npos) << s.message;
  EXPECT_TRUE(out.empty());
  w = waveform16();
  w.format = SampleFormat::PositionRecord;
  EXPECT_EQ(encode_waveform_block(w, out).error, CodecError::BadSampleFormat);
  w = waveform16();
  w.flags = packet_flag::kDropped;
  EXPECT_EQ(encode_waveform_block(w, out).error, CodecError::ReservedNotZero);
  w = waveform16();
  w.dac_codes.assign(max_samples(SampleFormat::DacInt16) + 1, 0);
  s = encode_waveform_block(w, out);
  EXPECT_EQ(s.error, CodecError::TooLarge);
  EXPECT_NE(s.message.find("8193 samples, at most 8192"), std::string::npos) << s.message;
  PositionPacket p;
  p.samples.resize(70000);  // more than a u16 count could even say
  EXPECT_EQ(encode_position_packet(p, out).error, CodecError::TooLarge);
  EXPECT_TRUE(out.empty());
}

TEST(UsbProtocol, MalformedPacketsGiveAClearError) {
  // Truncated below a header.
  for (std::size_t n = 0; n < kHeaderBytes; ++n) {
    const Bytes b(kPositions.begin(), kPositions.begin() + static_cast<std::ptrdiff_t>(n));
    EXPECT_EQ(decode_any_position(b), CodecError::Truncated) << n;
  }
  // Truncated after the header: the count says more than the buffer holds.
  for (std::size_t n = kHeaderBytes; n < kPositions.size(); ++n) {
    const Bytes b(kPositions.begin(), kPositions.begin() + static_cast<std::ptrdiff_t>(n));
    EXPECT_EQ(decode_any_position(b), CodecError::LengthExceedsBuffer) << n;
  }
  {
    Bytes b = kPositions;
    b[12] = 0x03;  // 3 samples, the buffer has 2
    PositionPacket p;
    std::size_t used = 0;
    const CodecStatus s = decode_position_packet(b, p, used);
    EXPECT_EQ(s.error, CodecError::LengthExceedsBuffer);
    EXPECT_NE(s.message.find("68-byte packet, the buffer holds 52 bytes"), std::string::npos)
        << s.message;
  }
  {
    Bytes b = kPositions;
    b[0] = 'X';
    PositionPacket p;
    std::size_t used = 0;
    const CodecStatus s = decode_position_packet(b, p, used);
    EXPECT_EQ(s.error, CodecError::BadMagic);
    EXPECT_NE(s.message.find("bad magic: bytes 0..3 are 0x58 0x44 0x4d 0x42"), std::string::npos)
        << s.message;
  }
  {
    Bytes b = kPositions;
    b[4] = 2;
    PositionPacket p;
    std::size_t used = 0;
    const CodecStatus s = decode_position_packet(b, p, used);
    EXPECT_EQ(s.error, CodecError::UnsupportedVersion);
    EXPECT_NE(s.message.find("version 2, this host speaks 1"), std::string::npos) << s.message;
  }
  {
    Bytes b = kPositions;
    b[5] = 0x09;
    EXPECT_EQ(decode_any_position(b), CodecError::UnknownPacketType);
  }
  // A valid waveform block handed to the position decoder and the other way round.
  EXPECT_EQ(decode_any_position(kWaveform16), CodecError::WrongPacketType);
  EXPECT_EQ(decode_any_waveform(kPositions), CodecError::WrongPacketType);
  {
    Bytes b = kPositions;
    b[6] = 0x01;  // int16 format in a position packet
    EXPECT_EQ(decode_any_position(b), CodecError::BadSampleFormat);
    b[6] = 0x00;
    EXPECT_EQ(decode_any_position(b), CodecError::BadSampleFormat);
  }
  {
    Bytes b = kPositions;
    b[7] |= 0x80;  // undefined flag
    EXPECT_EQ(decode_any_position(b), CodecError::ReservedNotZero);
    b = kPositions;
    b[15] = 1;  // reserved header byte
    EXPECT_EQ(decode_any_position(b), CodecError::ReservedNotZero);
  }
  {
    Bytes b = kWaveform16;
    b[12] = 0x01;
    b[13] = 0x20;  // 8193 int16 samples
    EXPECT_EQ(decode_any_waveform(b), CodecError::TooLarge);
  }
  {
    Bytes b = kPositions;
    b[20] ^= 0x01;  // a payload bit
    PositionPacket p;
    std::size_t used = 0;
    const CodecStatus s = decode_position_packet(b, p, used);
    EXPECT_EQ(s.error, CodecError::CrcMismatch);
    EXPECT_NE(s.message.find("stored CRC-32 0x70838d6e"), std::string::npos) << s.message;
    reseal(b);
    EXPECT_EQ(decode_any_position(b), CodecError::None);
  }
  // Every single-bit error anywhere in a packet is caught by some check.
  for (const Bytes* golden : {&kWaveform16, &kWaveform32, &kPositions, &kEmptyPositions}) {
    const bool is_waveform = (*golden)[5] == 0x01;
    for (std::size_t byte = 0; byte < golden->size(); ++byte) {
      for (int bit = 0; bit < 8; ++bit) {
        Bytes b = *golden;
        b[byte] ^= static_cast<std::uint8_t>(1u << bit);
        const CodecError e = is_waveform ? decode_any_waveform(b) : decode_any_position(b);
        ASSERT_NE(e, CodecError::None) << "byte " << byte << " bit " << bit;
      }
    }
  }
  // A failed decode leaves the output as it was.
  PositionPacket p = positions();
  std::size_t used = 0;
  Bytes b = kEmptyPositions;
  b.back() ^= 0xFF;
  EXPECT_FALSE(decode_position_packet(b, p, used).ok());
  EXPECT_EQ(p.samples.size(), 2u);
  EXPECT_EQ(p.sequence, 7u);
}

TEST(UsbProtocol, RandomBytesNeverCrash) {
  std::mt19937_64 rng(2024);
  std::size_t accepted = 0;
  for (int trial = 0; trial < 20000; ++trial) {
    Bytes b(rng() % 80);
    for (auto& x : b) x = static_cast<std::uint8_t>(rng());
    // Half the time start with a plausible header so the later checks are reached.
    if (trial % 2 == 0 && b.size() >= 8) {
      b[0] = 'I';
      b[1] = 'D';
      b[2] = 'M';
      b[3] = 'B';
      b[4] = 1;
      b[5] = static_cast<std::uint8_t>(1 + rng() % 2);
      b[6] = static_cast<std::uint8_t>(1 + rng() % 3);
      b[7] = static_cast<std::uint8_t>(rng() % 8);
      if (b.size() >= 16) {
        b[13] = 0;
        b[12] = static_cast<std::uint8_t>(rng() % 4);
        b[14] = 0;
        b[15] = 0;
      }
      if (trial % 4 == 0 && b.size() >= 20) {
        PacketHeader h;
        if (decode_header(b, h).ok()) {
          b.resize(h.packet_bytes());
          reseal(b);
        }
      }
    }
    const CodecError ew = decode_any_waveform(b);
    const CodecError ep = decode_any_position(b);
    accepted += (ew == CodecError::None) + (ep == CodecError::None);
    BridgeConfig c;
    BridgeStatus s;
    BridgeInfo i;
    (void)decode_config(b, c);
    (void)decode_status(b, s);
    (void)decode_info(b, i);
  }
  // The resealed ones must decode: the loop really reached the payload decoding.
  EXPECT_GT(accepted, 100u);
}

TEST(UsbProtocol, SequenceGapsAndRepeats) {
  SequenceTracker t;
  EXPECT_TRUE(t.check(0).ok());
  EXPECT_TRUE(t.check(1).ok());
  CodecStatus s = t.check(4);
  EXPECT_EQ(s.error, CodecError::SequenceGap);
  EXPECT_NE(s.message.find("expected sequence 2, got 4 (2 packets lost)"), std::string::npos)
      << s.message;
  EXPECT_EQ(t.lost_packets(), 2u);
  EXPECT_TRUE(t.check(5).ok());  // follows the new number
  s = t.check(5);
  EXPECT_EQ(s.error, CodecError::SequenceRepeat);
  EXPECT_EQ(t.check(3).error, CodecError::SequenceRepeat);
  EXPECT_TRUE(t.check(6).ok());
  // Across the 32-bit wrap.
  t.reset(0xFFFFFFFEu);
  EXPECT_TRUE(t.check(0xFFFFFFFEu).ok());
  EXPECT_TRUE(t.check(0xFFFFFFFFu).ok());
  EXPECT_TRUE(t.check(0).ok());
  EXPECT_EQ(t.check(0xFFFFFFFFu).error, CodecError::SequenceRepeat);
  EXPECT_EQ(t.check(3).error, CodecError::SequenceGap);
}

TEST(UsbProtocol, ControlRequests) {
  ControlSetup s = control_setup(Request::Start);
  EXPECT_EQ(s.request_type, 0x41);
  EXPECT_EQ(s.request, 0x01);
  EXPECT_EQ(s.length, 0);
  s = control_setup(Request::Stop, 2);
  EXPECT_EQ(s.request, 0x02);
  EXPECT_EQ(s.index, 2);
  s = control_setup(Request::Configure);
  EXPECT_EQ(s.request_type, 0x41);
  EXPECT_EQ(s.request, 0x03);
  EXPECT_EQ(s.length, 20);
  s = control_setup(Request::GetStatus);
  EXPECT_EQ(s.request_type, 0xC1);
  EXPECT_EQ(s.request, 0x04);
  EXPECT_EQ(s.length, 28);
  s = control_setup(Request::GetInfo);
  EXPECT_EQ(s.request_type, 0xC1);
  EXPECT_EQ(s.request, 0x05);
  EXPECT_EQ(s.length, 20);
  s = control_setup(Request::Latch, 1);
  EXPECT_EQ(s.request_type, 0xC1);
  EXPECT_EQ(s.request, 0x06);
  EXPECT_EQ(s.value, 0);
  EXPECT_EQ(s.index, 1);
  EXPECT_EQ(s.length, 16);
}

TEST(UsbProtocol, LatchPayloadByteForByte) {
  // u64 device ticks, then the u64 raw position word (valid bit 40, count 0x0000ABCD), LE.
  const Bytes kLatch = {0x08, 0x07, 0x06, 0x05, 0x04, 0x03, 0x02, 0x01,
                        0xCD, 0xAB, 0x00, 0x00, 0x00, 0x01, 0x00, 0x00};
  const PositionRecord record{0x0102030405060708ull, (1ull << 40) | 0xABCDu};
  Bytes out;
  ASSERT_TRUE(encode_latch(record, out).ok());
  EXPECT_EQ(out, kLatch);
  PositionRecord back;
  ASSERT_TRUE(decode_latch(kLatch, back).ok());
  EXPECT_EQ(back.timestamp_ticks, 0x0102030405060708ull);
  EXPECT_EQ(back.position_word, (1ull << 40) | 0xABCDu);
  for (std::size_t n : {std::size_t{0}, std::size_t{15}, std::size_t{17}}) {
    PositionRecord untouched{1, 2};
    const CodecStatus s = decode_latch(Bytes(n, 0), untouched);
    EXPECT_EQ(s.error, CodecError::BadLength) << n;
    EXPECT_NE(s.message.find("LATCH payload is " + std::to_string(n) + " bytes, expected 16"),
              std::string::npos)
        << s.message;
    EXPECT_EQ(untouched.timestamp_ticks, 1u);
    EXPECT_EQ(untouched.position_word, 2u);
  }
}

TEST(UsbProtocol, ControlPayloadsByteForByte) {
  BridgeConfig config{100000, 2500, 50000, 1000, SampleFormat::DacInt16};
  Bytes out;
  ASSERT_TRUE(encode_config(config, out).ok());
  EXPECT_EQ(out, kConfigure);
  BridgeConfig config_back;
  ASSERT_TRUE(decode_config(kConfigure, config_back).ok());
  EXPECT_EQ(config_back.dac_sample_rate_hz, 100000u);
  EXPECT_EQ(config_back.burst_samples, 2500u);
  EXPECT_EQ(config_back.position_sample_rate_hz, 50000u);
  EXPECT_EQ(config_back.tail_samples, 1000u);
  EXPECT_EQ(config_back.dac_format, SampleFormat::DacInt16);

  BridgeStatus status;
  status.state = BridgeState::Running;
  status.fault_flags = fault_flag::kUnderrun | fault_flag::kAxisError;
  status.dac_samples_played = 1234;
  status.positions_latched = 567;
  status.next_waveform_sequence = 42;
  status.buffer_free_samples = 4096;
  status.device_time_ticks = 0x0102030405060708ull;
  out.clear();
  ASSERT_TRUE(encode_status(status, out).ok());
  EXPECT_EQ(out, kStatus);
  BridgeStatus status_back;
  ASSERT_TRUE(decode_status(kStatus, status_back).ok());
  EXPECT_EQ(status_back.state, BridgeState::Running);
  EXPECT_EQ(status_back.fault_flags, 0x21);
  EXPECT_EQ(status_back.dac_samples_played, 1234u);
  EXPECT_EQ(status_back.positions_latched, 567u);
  EXPECT_EQ(status_back.next_waveform_sequence, 42u);
  EXPECT_EQ(status_back.buffer_free_samples, 4096u);
  EXPECT_EQ(status_back.device_time_ticks, 0x0102030405060708ull);

  BridgeInfo info;
  info.dac_bits = 16;
  info.position_word_bits = 36;
  info.tick_hz = 48000000;
  info.max_dac_rate_hz = 1000000;
  info.buffer_capacity_samples = 65536;
  info.max_position_rate_hz = 200000;
  out.clear();
  ASSERT_TRUE(encode_info(info, out).ok());
  EXPECT_EQ(out, kInfo);
  BridgeInfo info_back;
  ASSERT_TRUE(decode_info(kInfo, info_back).ok());
  EXPECT_EQ(info_back.tick_hz, 48000000u);
  EXPECT_EQ(info_back.position_word_bits, 36);
  EXPECT_EQ(info_back.buffer_capacity_samples, 65536u);
}

TEST(UsbProtocol, MalformedControlPayloads) {
  BridgeConfig c;
  for (std::size_t n : {std::size_t{0}, std::size_t{19}, std::size_t{21}}) {
    Bytes b(n, 0);
    const CodecStatus s = decode_config(b, c);
    EXPECT_EQ(s.error, CodecError::BadLength) << n;
    EXPECT_NE(s.message.find("CONFIGURE payload is " + std::to_string(n) + " bytes, expected 20"),
              std::string::npos)
        << s.message;
  }
  Bytes b = kConfigure;
  b[0] = b[1] = b[2] = b[3] = 0;
  CodecStatus s = decode_config(b, c);
  EXPECT_EQ(s.error, CodecError::BadValue);
  EXPECT_NE(s.message.find("dac_sample_rate_hz: 0, allowed >= 1"), std::string::npos) << s.message;
  b = kConfigure;
  b[16] = 0x03;
  EXPECT_EQ(decode_config(b, c).error, CodecError::BadSampleFormat);
  b = kConfigure;
  b[18] = 1;
  EXPECT_EQ(decode_config(b, c).error, CodecError::ReservedNotZero);
  EXPECT_EQ(encode_config(BridgeConfig{}, b).error, CodecError::BadValue);  // burst_samples 0

  BridgeStatus st;
  b = kStatus;
  b[0] = 5;
  EXPECT_EQ(decode_status(b, st).error, CodecError::BadValue);
  b = kStatus;
  b[3] = 0x80;
  EXPECT_EQ(decode_status(b, st).error, CodecError::ReservedNotZero);
  b = kStatus;
  b.pop_back();
  EXPECT_EQ(decode_status(b, st).error, CodecError::BadLength);

  BridgeInfo info;
  b = kInfo;
  b[0] = 2;
  s = decode_info(b, info);
  EXPECT_EQ(s.error, CodecError::UnsupportedVersion);
  EXPECT_NE(s.message.find("bridge speaks protocol version 2, this host speaks 1"),
            std::string::npos)
      << s.message;
  b = kInfo;
  b[2] = 40;
  EXPECT_EQ(decode_info(b, info).error, CodecError::BadValue);
  b = kInfo;
  b[4] = b[5] = b[6] = b[7] = 0;
  EXPECT_EQ(decode_info(b, info).error, CodecError::BadValue);
  // Failed decodes leave the output untouched.
  EXPECT_EQ(info.tick_hz, 0u);
}
