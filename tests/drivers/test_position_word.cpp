#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "drivers/position_word.h"
#include "model/stage.h"

using namespace idm::drivers;
namespace pw = idm::drivers::position_word;
namespace ss = idm::drivers::sample_status;
using idm::model::InputError;

namespace {

PositionWordConfig config_for(WordWidth width) {
  PositionWordConfig c;
  c.width = width;
  c.sample_interval_s = 1e-5;
  c.max_velocity_m_s = 0.01;  // 1e-7 m per sample: ceil(10.1 counts) + 1 = 12 counts allowed
  return c;
}

std::string error_of(const PositionWordConfig& c) {
  try {
    validate(c);
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

// Decodes counts (encoded as valid words) one by one and returns the decoded counts.
std::vector<std::int64_t> decode_counts(PositionDecoder& d,
                                        const std::vector<std::int64_t>& counts) {
  const PositionEncoder enc(d.config());
  std::vector<std::int64_t> out;
  for (std::int64_t c : counts) {
    const PositionSample s = d.decode(enc.encode_count(c));
    EXPECT_TRUE(s.valid()) << describe_sample_status(s.status) << " at count " << c;
    out.push_back(s.count);
  }
  return out;
}

}  // namespace

TEST(PositionWord, LayoutAndRoundTrip) {
  EXPECT_EQ(pw::kValid, 0x100'0000'0000ull);
  EXPECT_EQ(pw::kSampleOverrun, 0x1000'0000'0000ull);
  EXPECT_EQ(encode_position_word(0, WordWidth::Bits32), 0x100'0000'0000ull);
  EXPECT_EQ(encode_position_word(-1, WordWidth::Bits32), 0x100'FFFF'FFFFull);
  EXPECT_EQ(encode_position_word(-1, WordWidth::Bits36), 0x10F'FFFF'FFFFull);
  EXPECT_EQ(encode_position_word(5, WordWidth::Bits36, pw::kValid | pw::kGlitch),
            0x900'0000'0005ull);
  EXPECT_EQ(encode_position_word(0, WordWidth::Bits32, pw::kMeasurementSignalLost),
            0x200'0000'0000ull);
  // Counts beyond the width wrap (the board's counter rolls over).
  EXPECT_EQ(encode_position_word(std::int64_t{1} << 32, WordWidth::Bits32), pw::kValid);
  for (WordWidth w : {WordWidth::Bits32, WordWidth::Bits36}) {
    const std::int64_t half = std::int64_t{1} << (static_cast<int>(w) - 1);
    for (std::int64_t c : {std::int64_t{0}, std::int64_t{1}, std::int64_t{-1}, half - 1, -half,
                           std::int64_t{123456789}, std::int64_t{-987654}}) {
      EXPECT_EQ(word_count(encode_position_word(c, w), w), c) << c;
    }
    EXPECT_EQ(word_count(encode_position_word(half, w), w), -half);  // rolled over
  }
  EXPECT_THROW(encode_position_word(0, WordWidth::Bits32, std::uint64_t{1} << 46), InputError);
  EXPECT_THROW(encode_position_word(0, WordWidth::Bits32, std::uint64_t{1} << 39), InputError);
}

TEST(PositionWord, ReferenceMarkIsBit45AndKeepsTheSampleValid) {
  EXPECT_EQ(pw::kReferenceMark, 0x2000'0000'0000ull);
  EXPECT_EQ(pw::kStatusBits & pw::kReferenceMark, 0u);
  EXPECT_EQ(encode_position_word(5, WordWidth::Bits32, pw::kValid | pw::kReferenceMark),
            0x2100'0000'0005ull);
  for (WordWidth w : {WordWidth::Bits32, WordWidth::Bits36}) {
    PositionDecoder d(config_for(w));
    const PositionEncoder enc(d.config());
    const PositionSample first = d.decode(enc.encode_count(100));
    EXPECT_TRUE(first.valid());
    EXPECT_FALSE(first.mark);
    const PositionSample marked = d.decode(enc.encode_count(103, pw::kValid | pw::kReferenceMark));
    EXPECT_TRUE(marked.valid());
    EXPECT_TRUE(marked.mark);
    EXPECT_EQ(marked.count, 103);
    EXPECT_DOUBLE_EQ(marked.position_m, 103 * d.count_m());
    const PositionSample after = d.decode(enc.encode_count(104));
    EXPECT_TRUE(after.valid());
    EXPECT_FALSE(after.mark);
    // The mark on a word with an error bit: reported, and the sample is still invalid.
    const PositionSample lost =
        d.decode(enc.encode_count(105, pw::kValid | pw::kGlitch | pw::kReferenceMark));
    EXPECT_TRUE(lost.mark);
    EXPECT_EQ(lost.status, ss::kGlitchFlagged);
    // Bits 46..63 stay reserved, with or without the mark.
    for (unsigned bit : {46u, 47u, 55u, 63u}) {
      PositionDecoder r(config_for(w));
      r.decode(enc.encode_count(0));
      const PositionSample s = r.decode(enc.encode_count(1, pw::kValid | pw::kReferenceMark) |
                                        (std::uint64_t{1} << bit));
      EXPECT_EQ(s.status, ss::kReservedBitsSet) << bit;
      EXPECT_TRUE(std::isnan(s.position_m)) << bit;
    }
    // The batch decode takes a marked word as valid too.
    PositionDecoder b(config_for(w));
    const std::uint64_t words[3] = {enc.encode_count(7),
                                    enc.encode_count(8, pw::kValid | pw::kReferenceMark),
                                    enc.encode_count(9)};
    double x[3];
    std::uint8_t st[3];
    b.decode(words, 3, x, st);
    EXPECT_EQ(st[1], 0u);
    EXPECT_DOUBLE_EQ(x[1], 8 * b.count_m());
  }
}

TEST(PositionWord, CountSizeFromOptics) {
  PositionWordConfig c;
  EXPECT_DOUBLE_EQ(c.count_m(), 632.991e-9 / 64.0);
  EXPECT_NEAR(c.count_m(), 9.8905e-9, 1e-13);  // the paper's 9.89 nm resolution
  c.optics = Optics::PlaneMirror;
  EXPECT_DOUBLE_EQ(c.count_m(), 632.991e-9 / 128.0);
  c.optics = Optics::Custom;
  c.divisor = 256.0;
  EXPECT_DOUBLE_EQ(c.count_m(), 632.991e-9 / 256.0);
  c.air_index = 1.000271374;
  EXPECT_DOUBLE_EQ(c.count_m(), 632.991e-9 / (1.000271374 * 256.0));
  EXPECT_EQ(optics_divisor(Optics::SingleBeamLinear), 64.0);
  EXPECT_EQ(optics_divisor(Optics::PlaneMirror), 128.0);
  EXPECT_THROW(optics_divisor(Optics::Custom), InputError);
  EXPECT_EQ(parse_optics("plane_mirror"), Optics::PlaneMirror);
  EXPECT_EQ(parse_optics("single_beam_linear"), Optics::SingleBeamLinear);
  try {
    parse_optics("wollaston", "idmd.yaml:12: interferometer.optics");
    FAIL() << "no throw";
  } catch (const InputError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("idmd.yaml:12: interferometer.optics"), std::string::npos) << m;
    EXPECT_NE(m.find("'wollaston'"), std::string::npos) << m;
    EXPECT_NE(m.find("plane_mirror"), std::string::npos) << m;
  }
}

TEST(PositionWord, ValidationNamesTheKeyAndRange) {
  EXPECT_EQ(error_of(PositionWordConfig{}), "");
  PositionWordConfig c;
  c.width = static_cast<WordWidth>(48);
  EXPECT_NE(error_of(c).find("interferometer.word_bits: 48 is out of range, allowed 32 or 36"),
            std::string::npos)
      << error_of(c);
  c = {};
  c.optics = Optics::Custom;
  c.divisor = 0.0;
  EXPECT_NE(error_of(c).find("interferometer.divisor"), std::string::npos) << error_of(c);
  c = {};
  c.air_index = 0.99;
  EXPECT_NE(error_of(c).find("interferometer.air_index: 0.99 is out of range, allowed [1, 1.01]"),
            std::string::npos)
      << error_of(c);
  c = {};
  c.max_velocity_m_s = NAN;
  EXPECT_NE(error_of(c).find("interferometer.max_velocity_m_s"), std::string::npos);
  c = {};
  c.sample_interval_s = 0.0;
  EXPECT_NE(error_of(c).find("interferometer.sample_interval_s"), std::string::npos);
  c = {};
  c.max_consecutive_jumps = 0;
  EXPECT_NE(error_of(c).find("interferometer.max_consecutive_jumps"), std::string::npos);
  // 100 m/s for 1 s is ~1e10 counts: more than half the 32-bit range, fine for 36 bits.
  c = {};
  c.max_velocity_m_s = 100.0;
  c.sample_interval_s = 1.0;
  EXPECT_NE(error_of(c).find("half the counter range"), std::string::npos) << error_of(c);
  c.width = WordWidth::Bits36;
  EXPECT_EQ(error_of(c), "");
  EXPECT_THROW(PositionDecoder{PositionWordConfig{.air_index = 2.0}}, InputError);
}

TEST(PositionDecoder, StepAllowanceFromMaxVelocity) {
  const PositionDecoder d(config_for(WordWidth::Bits32));
  // 0.01 m/s * 1e-5 s / 9.8905e-9 m = 10.11 counts -> 11, plus one for quantization.
  EXPECT_EQ(d.max_step_counts(), 12u);
}

TEST(PositionDecoder, FirstValidWordIsTheReference) {
  PositionDecoder d(config_for(WordWidth::Bits36));
  EXPECT_FALSE(d.has_reference());
  const PositionSample a = d.decode(encode_position_word(77, WordWidth::Bits36, 0));
  EXPECT_EQ(a.status, ss::kNotValid);
  EXPECT_TRUE(std::isnan(a.position_m));
  EXPECT_FALSE(d.has_reference());
  const PositionSample b = d.decode(encode_position_word(-5000, WordWidth::Bits36));
  EXPECT_TRUE(b.valid());
  EXPECT_EQ(b.count, -5000);  // absolute: the board's count as is
  EXPECT_DOUBLE_EQ(b.position_m, -5000 * d.count_m());
  // reset(next_count): the next valid word reads as next_count, travel continues from there.
  d.reset(1000);
  EXPECT_EQ(d.decode(encode_position_word(-4990, WordWidth::Bits36)).count, 1000);
  EXPECT_EQ(d.decode(encode_position_word(-4985, WordWidth::Bits36)).count, 1005);
}

TEST(PositionDecoder, UnwrapsPositiveAndNegativeRollOver) {
  for (WordWidth w : {WordWidth::Bits32, WordWidth::Bits36}) {
    SCOPED_TRACE(static_cast<int>(w));
    const std::int64_t half = std::int64_t{1} << (static_cast<int>(w) - 1);
    const std::int64_t full = half * 2;
    // Upward through +2^(w-1): the word goes from max positive to min negative.
    {
      PositionDecoder d(config_for(w));
      std::vector<std::int64_t> truth;
      for (std::int64_t c = half - 40; c < half + 40; c += 7) truth.push_back(c);
      EXPECT_EQ(decode_counts(d, truth), truth);
    }
    // Downward through -2^(w-1).
    {
      PositionDecoder d(config_for(w));
      std::vector<std::int64_t> truth;
      for (std::int64_t c = -half + 50; c > -half - 50; c -= 12) truth.push_back(c);
      EXPECT_EQ(decode_counts(d, truth), truth);
    }
    // Through the unsigned wrap (all ones -> zero) both ways.
    {
      PositionDecoder d(config_for(w));
      std::vector<std::int64_t> truth{-3, -1, 0, 2, 1, -1, -2};
      EXPECT_EQ(decode_counts(d, truth), truth);
    }
    // A long run: several full turns of the counter, up and back down.
    {
      PositionWordConfig c = config_for(w);
      c.max_velocity_m_s = 100.0;  // ~1e5 counts per sample
      c.sample_interval_s = 1e-3;
      PositionDecoder d(c);
      const PositionEncoder enc(c);
      const std::int64_t step = static_cast<std::int64_t>(d.max_step_counts()) - 1;
      const std::int64_t turns = 3;
      const std::int64_t n = turns * full / step + 10;
      std::int64_t truth = half - 2 * step;
      d.reset();
      for (std::int64_t i = 0; i < n; ++i, truth += step) {
        const PositionSample s = d.decode(enc.encode_count(truth));
        ASSERT_TRUE(s.valid()) << i;
        ASSERT_EQ(s.count, truth) << i;
      }
      EXPECT_GT(d.count(), half + turns * full - 100 * step);  // really went around
      for (std::int64_t i = 0; i < n; ++i, truth -= step) {
        const PositionSample s = d.decode(enc.encode_count(truth));
        ASSERT_TRUE(s.valid()) << i;
        ASSERT_EQ(s.count, truth) << i;
      }
    }
  }
}

TEST(PositionDecoder, JumpFasterThanMaxVelocityIsAGlitch) {
  for (WordWidth w : {WordWidth::Bits32, WordWidth::Bits36}) {
    PositionDecoder d(config_for(w));
    const PositionEncoder enc(d.config());
    ASSERT_EQ(d.max_step_counts(), 12u);
    EXPECT_EQ(d.decode(enc.encode_count(100)).count, 100);
    EXPECT_TRUE(d.decode(enc.encode_count(112)).valid());  // exactly the allowance
    EXPECT_TRUE(d.decode(enc.encode_count(100)).valid());
    const PositionSample g = d.decode(enc.encode_count(113));  // one count too far
    EXPECT_EQ(g.status, ss::kJumpTooFast);
    EXPECT_TRUE(std::isnan(g.position_m));
    EXPECT_EQ(g.count, 100);  // the last valid count, not unwrapped
    EXPECT_EQ(d.count(), 100);
    // After one rejected sample two intervals have passed: up to 11 * 2 + 1 = 23 counts.
    EXPECT_TRUE(d.decode(enc.encode_count(123)).valid());
    EXPECT_EQ(d.count(), 123);
    // A spike that would look like a roll-over (half the range away) is rejected, not unwrapped.
    const std::int64_t half = std::int64_t{1} << (static_cast<int>(w) - 1);
    EXPECT_EQ(d.decode(enc.encode_count(123 + half)).status, ss::kJumpTooFast);
    EXPECT_EQ(d.decode(enc.encode_count(123 - half + 1)).status, ss::kJumpTooFast);
    EXPECT_EQ(d.decode(enc.encode_count(125)).count, 125);
    EXPECT_FALSE(d.continuity_lost());
  }
}

TEST(PositionDecoder, TooManyJumpsInARowLoseContinuity) {
  PositionWordConfig c = config_for(WordWidth::Bits32);
  c.max_consecutive_jumps = 3;
  PositionDecoder d(c);
  const PositionEncoder enc(c);
  d.decode(enc.encode_count(0));
  // The counter was reset behind our back: every word is now ~1e6 counts away.
  for (int i = 0; i < 3; ++i)
    EXPECT_EQ(d.decode(enc.encode_count(1000000 + i)).status, ss::kJumpTooFast) << i;
  EXPECT_FALSE(d.continuity_lost());
  EXPECT_EQ(d.decode(enc.encode_count(1000003)).status, ss::kJumpTooFast);
  EXPECT_TRUE(d.continuity_lost());
  // Sticky: even a word that would be consistent with the old position stays invalid.
  const PositionSample s = d.decode(enc.encode_count(1));
  EXPECT_EQ(s.status, ss::kContinuityLost);
  EXPECT_TRUE(std::isnan(s.position_m));
  d.reset();
  EXPECT_EQ(d.decode(enc.encode_count(1000005)).count, 1000005);
  EXPECT_FALSE(d.continuity_lost());
}

TEST(PositionDecoder, AllowanceReachingHalfTheRangeLosesContinuity) {
  PositionWordConfig c;
  c.width = WordWidth::Bits32;
  c.max_velocity_m_s = 100.0;
  c.sample_interval_s = 0.075;  // 7.5 m per sample: 7.6e8 counts, over a third of 2^31
  c.max_consecutive_jumps = 1000;
  PositionDecoder d(c);
  const PositionEncoder enc(c);
  ASSERT_LT(d.max_step_counts(), std::uint64_t{1} << 31);
  ASSERT_GT(3 * d.max_step_counts(), std::uint64_t{1} << 31);
  d.decode(enc.encode_count(0));
  EXPECT_EQ(d.decode(enc.encode_count(0) & ~pw::kValid).status, ss::kNotValid);
  EXPECT_FALSE(d.continuity_lost());  // 2 intervals still resolve the wrap
  EXPECT_EQ(d.decode(enc.encode_count(0) & ~pw::kValid).status, ss::kNotValid);
  EXPECT_TRUE(d.continuity_lost());  // 3 intervals could be a full turn
  EXPECT_EQ(d.decode(enc.encode_count(0)).status, ss::kContinuityLost);
}

TEST(PositionDecoder, ErrorBitsAreNeverAPosition) {
  struct Case {
    std::uint64_t word_bits;
    std::uint8_t status;
    bool sticky;
  };
  const Case cases[] = {
      {0, ss::kNotValid, false},
      {pw::kValid | pw::kMeasurementSignalLost, ss::kMeasurementSignalLost, true},
      {pw::kValid | pw::kReferenceSignalLost, ss::kReferenceSignalLost, true},
      {pw::kValid | pw::kGlitch, ss::kGlitchFlagged, false},
      {pw::kValid | pw::kSampleOverrun, ss::kSampleOverrun, false},
      {pw::kMeasurementSignalLost | pw::kReferenceSignalLost,
       ss::kNotValid | ss::kMeasurementSignalLost | ss::kReferenceSignalLost, true},
  };
  for (WordWidth w : {WordWidth::Bits32, WordWidth::Bits36}) {
    for (const Case& k : cases) {
      SCOPED_TRACE(describe_sample_status(k.status));
      PositionDecoder d(config_for(w));
      const PositionEncoder enc(d.config());
      ASSERT_TRUE(d.decode(enc.encode_count(500)).valid());
      // The bad word carries a count that would be a plausible move: it must not be used.
      const PositionSample bad = d.decode(enc.encode_count(505, k.word_bits));
      EXPECT_EQ(bad.status, k.status);
      EXPECT_TRUE(std::isnan(bad.position_m));
      EXPECT_EQ(bad.count, 500);
      EXPECT_EQ(d.count(), 500);
      const PositionSample next = d.decode(enc.encode_count(503));
      if (k.sticky) {
        EXPECT_EQ(next.status, ss::kContinuityLost);  // counts may have been missed
        EXPECT_TRUE(d.continuity_lost());
        d.reset(d.count());
        EXPECT_EQ(d.decode(enc.encode_count(503)).count, 500);
      } else {
        EXPECT_TRUE(next.valid());
        EXPECT_EQ(next.count, 503);
      }
    }
    // Reserved bits: 36..39 (and 32..35 of a 32-bit word), 46..63.
    std::vector<unsigned> reserved{36, 37, 38, 39, 46, 50, 63};
    if (w == WordWidth::Bits32) reserved.insert(reserved.end(), {32, 33, 34, 35});
    for (unsigned bit : reserved) {
      PositionDecoder d(config_for(w));
      const PositionEncoder enc(d.config());
      d.decode(enc.encode_count(0));
      const PositionSample s = d.decode(enc.encode_count(1) | (std::uint64_t{1} << bit));
      EXPECT_EQ(s.status, ss::kReservedBitsSet) << bit;
      EXPECT_TRUE(std::isnan(s.position_m)) << bit;
    }
  }
  EXPECT_EQ(describe_sample_status(0), "valid");
  EXPECT_EQ(describe_sample_status(ss::kMeasurementSignalLost | ss::kJumpTooFast),
            "measurement_signal_lost+jump_too_fast");
}

TEST(PositionDecoder, MetresFollowTheAirIndex) {
  PositionWordConfig c = config_for(WordWidth::Bits36);
  c.optics = Optics::PlaneMirror;
  PositionDecoder d(c);
  const PositionEncoder enc(c);
  EXPECT_DOUBLE_EQ(d.decode(enc.encode_count(128)).position_m, 632.991e-9);
  d.set_air_index(1.000271374);
  EXPECT_DOUBLE_EQ(d.decode(enc.encode_count(128)).position_m, 632.991e-9 / 1.000271374);
  EXPECT_THROW(d.set_air_index(0.5), InputError);
  // The encoder quantizes to the nearest count.
  EXPECT_EQ(enc.counts_from_m(5.4 * enc.count_m()), 5);
  EXPECT_EQ(enc.counts_from_m(-5.6 * enc.count_m()), -6);
  EXPECT_EQ(word_count(enc.encode_m(1e-3), WordWidth::Bits36),
            std::llround(1e-3 / (632.991e-9 / 128.0)));
  EXPECT_THROW(enc.counts_from_m(INFINITY), InputError);
}

TEST(PositionDecoder, BatchDecodeMatchesWordByWord) {
  for (WordWidth w : {WordWidth::Bits32, WordWidth::Bits36}) {
    PositionWordConfig c = config_for(w);
    c.max_consecutive_jumps = 4;
    const PositionEncoder enc(c);
    std::mt19937_64 rng(42);
    std::uniform_int_distribution<int> move(-9, 9);
    std::uniform_int_distribution<int> fault(0, 199);
    const std::int64_t half = std::int64_t{1} << (static_cast<int>(w) - 1);
    std::int64_t truth = half - 3000;
    std::vector<std::uint64_t> words;
    std::vector<std::int64_t> truths;
    for (int i = 0; i < 20000; ++i) {
      truth += move(rng) + 3;  // -6 .. 12 counts per sample: drifts up through the roll-over
      truths.push_back(truth);
      std::uint64_t word = enc.encode_count(truth);
      switch (fault(rng)) {
        case 0:
          word = enc.encode_count(truth + 5000);
          break;  // spike
        case 1:
          word &= ~pw::kValid;
          break;
        case 2:
          word |= pw::kGlitch;
          break;
        case 3:
          word |= pw::kSampleOverrun;
          break;
        case 4:
          word |= std::uint64_t{1} << 47;
          break;
        default:
          break;
      }
      if (i == 15000) word |= pw::kMeasurementSignalLost;  // continuity lost from here on
      words.push_back(word);
    }
    PositionDecoder one(c), batch(c);
    std::vector<double> metres(words.size());
    std::vector<std::uint8_t> status(words.size());
    // In uneven chunks, to check that the state carries over between calls.
    std::size_t at = 0;
    for (std::size_t chunk : {std::size_t{1}, std::size_t{999}, std::size_t{7000}}) {
      batch.decode(words.data() + at, chunk, metres.data() + at, status.data() + at);
      at += chunk;
    }
    batch.decode(words.data() + at, words.size() - at, metres.data() + at, status.data() + at);
    std::size_t valid = 0;
    for (std::size_t i = 0; i < words.size(); ++i) {
      const PositionSample s = one.decode(words[i]);
      ASSERT_EQ(s.status, status[i]) << i;
      ASSERT_EQ(std::memcmp(&s.position_m, &metres[i], sizeof(double)), 0) << i;
      valid += s.valid();
    }
    EXPECT_EQ(one.count(), batch.count());
    // Most samples before the beam loss are valid; none after it.
    EXPECT_GT(valid, 14000u);
    EXPECT_LE(valid, 15000u);
    EXPECT_TRUE(batch.continuity_lost());
    for (std::size_t i = 15000; i < words.size(); ++i) ASSERT_NE(status[i], 0) << i;
    // Every valid sample is the true position at that moment, across the roll-over.
    EXPECT_GT(truths[14999], half);
    for (std::size_t i = 0; i < 15000; ++i) {
      if (status[i] == 0) {
        ASSERT_EQ(metres[i], static_cast<double>(truths[i]) * c.count_m()) << i;
      }
    }
  }
}
