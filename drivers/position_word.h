// HP10885A-style position words: the raw sample layout, the decoder (roll-over unwrap, glitch
// rejection, error bits, counts to metres) and the encoder used by the simulated stage and tests.
//
// Raw sample layout (one std::uint64_t per latched sample, the same in every backend):
//
//   bits  0..35  position count, two's complement. A 36-bit board fills all 36 bits; a 32-bit
//                board fills bits 0..31 and leaves bits 32..35 zero.
//   bits 36..39  reserved, zero
//   bit  40      valid: the latch holds a count (clear: no sample, e.g. the axis is in reset)
//   bit  41      measurement signal lost (the beam from the moving reflector dropped out)
//   bit  42      reference signal lost (the laser head's reference dropped out)
//   bit  43      glitch (the board saw an impossible phase step)
//   bit  44      sample overrun (the latch was overwritten before it was read)
//   bit  45      reference mark: the slider crossed the scale's index mark since the previous
//                word the device produced (latched or streamed). Not an error: the sample
//                stays valid; the decoder reports it as PositionSample::mark.
//   bits 46..63  reserved, zero
//
// A count of one is lambda_vac / (n_air * divisor) of slider travel: divisor 64 for single-beam
// linear optics (HP 10705A, the paper's 9.89 nm), 128 for plane-mirror optics.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>

namespace idm::drivers {

namespace position_word {
inline constexpr unsigned kMaxCountBits = 36;
inline constexpr unsigned kStatusShift = 40;
inline constexpr std::uint64_t kValid = std::uint64_t{1} << 40;
inline constexpr std::uint64_t kMeasurementSignalLost = std::uint64_t{1} << 41;
inline constexpr std::uint64_t kReferenceSignalLost = std::uint64_t{1} << 42;
inline constexpr std::uint64_t kGlitch = std::uint64_t{1} << 43;
inline constexpr std::uint64_t kSampleOverrun = std::uint64_t{1} << 44;
// Every status bit defined above (the valid bit and the error bits).
inline constexpr std::uint64_t kStatusBits =
    kValid | kMeasurementSignalLost | kReferenceSignalLost | kGlitch | kSampleOverrun;
// The reference mark flag: not a status bit (it never makes a sample invalid).
inline constexpr std::uint64_t kReferenceMark = std::uint64_t{1} << 45;
// Every bit above the count field that a well-formed word may set.
inline constexpr std::uint64_t kDefinedBits = kStatusBits | kReferenceMark;
}  // namespace position_word

// Per-sample status written by the decoder: 0 means a valid position; any bit set means the
// sample is invalid and its position is NaN. Bits 0..4 mirror the word's status bits (bit 0 is
// the inverse of `valid`); bits 5..7 are found by the decoder.
namespace sample_status {
inline constexpr std::uint8_t kNotValid = 1u << 0;               // valid bit clear
inline constexpr std::uint8_t kMeasurementSignalLost = 1u << 1;  // word bit 41
inline constexpr std::uint8_t kReferenceSignalLost = 1u << 2;    // word bit 42
inline constexpr std::uint8_t kGlitchFlagged = 1u << 3;          // word bit 43 (the board's flag)
inline constexpr std::uint8_t kSampleOverrun = 1u << 4;          // word bit 44
inline constexpr std::uint8_t kReservedBitsSet = 1u << 5;        // malformed word
inline constexpr std::uint8_t kJumpTooFast = 1u << 6;            // faster than max velocity
inline constexpr std::uint8_t kContinuityLost = 1u << 7;         // sticky until reset()
}  // namespace sample_status

// "valid" or the names of the set bits joined by '+', e.g. "measurement_signal_lost+glitch".
std::string describe_sample_status(std::uint8_t status);

enum class WordWidth : std::uint8_t { Bits32 = 32, Bits36 = 36 };

enum class Optics : std::uint8_t {
  SingleBeamLinear,  // divisor 64 (HP 10705A, the paper)
  PlaneMirror,       // divisor 128 (HP 10706A)
  Custom,            // PositionWordConfig::divisor
};

// 64 or 128; Custom has no fixed divisor and throws InputError.
double optics_divisor(Optics optics);
// "single_beam_linear", "plane_mirror", "custom".
const char* optics_name(Optics optics);
// Throws InputError "WHERE: unknown optics 'NAME' (known: ...)".
Optics parse_optics(const std::string& name, const std::string& where = "interferometer.optics");

struct PositionWordConfig {
  WordWidth width = WordWidth::Bits32;
  Optics optics = Optics::SingleBeamLinear;
  double divisor = 64.0;                    // used only when optics == Custom
  double lambda_vac_m = 632.991e-9;         // HeNe vacuum wavelength
  double air_index = 1.0;                   // n_air; 1 = uncompensated (see air_index.h)
  double sample_interval_s = 1e-5;          // time between consecutive words
  double max_velocity_m_s = 0.1;            // a faster jump between words is a glitch
  std::uint32_t max_consecutive_jumps = 8;  // more too-fast jumps in a row: continuity lost

  double effective_divisor() const;
  // lambda_vac / (n_air * divisor).
  double count_m() const;
};

// Throws InputError naming the key and the allowed range.
void validate(const PositionWordConfig& config, const std::string& where = "interferometer");

// The raw word for `count` (taken modulo 2^width, two's complement) with the given status bits
// (a subset of position_word::kDefinedBits: the status bits and the reference mark; others throw
// InputError).
std::uint64_t encode_position_word(std::int64_t count, WordWidth width,
                                   std::uint64_t status_bits = position_word::kValid);

// The count field of a word, sign-extended to 64 bits (no unwrap, no status check).
std::int64_t word_count(std::uint64_t word, WordWidth width);

// Metres and counts to raw words for the simulated stage and tests.
class PositionEncoder {
 public:
  explicit PositionEncoder(const PositionWordConfig& config);  // validates

  // The nearest count to position_m (quantization of the interferometer).
  std::int64_t counts_from_m(double position_m) const;
  std::uint64_t encode_count(std::int64_t count,
                             std::uint64_t status_bits = position_word::kValid) const;
  std::uint64_t encode_m(double position_m,
                         std::uint64_t status_bits = position_word::kValid) const;
  double count_m() const { return count_m_; }
  void set_air_index(double air_index);  // validated like the config

 private:
  PositionWordConfig config_;
  double count_m_;
};

struct PositionSample {
  std::int64_t count = 0;   // unwrapped count; the last valid one when this sample is invalid
  double position_m = 0.0;  // count * count_m(); NaN when invalid
  std::uint8_t status = 0;  // sample_status bits; 0 = valid
  bool mark = false;        // the word's reference mark bit (set whatever the status)

  bool valid() const { return status == 0; }
};

// Turns a stream of consecutive words into unwrapped 64-bit counts and metres.
//
// Between two accepted words the count moved by the wrap-consistent delta: the difference of the
// two count fields taken modulo 2^width into [-2^(width-1), 2^(width-1)). The delta is accepted
// when |delta| <= (k + 1) * max_step_counts(), max_step_counts() = ceil(max_velocity *
// sample_interval / count_m) + 1 (the +1 for quantization) and k the words rejected since the
// last accepted one. A larger delta is a glitch: the sample is invalid and the unwrap state is
// left as it was. A word with any error bit, a clear valid bit or
// a reserved bit set is invalid too. Invalid samples never move the position. The reference mark
// bit is neither: decode(word) reports it in PositionSample::mark, the batch decode ignores it.
//
// Continuity is lost (every later sample carries kContinuityLost until reset()) when the
// measurement or reference signal is lost (counts were missed), after more than
// max_consecutive_jumps too-fast jumps in a row, or when the allowed travel since the last
// accepted word reaches half the counter range (the wrap can no longer be told).
class PositionDecoder {
 public:
  explicit PositionDecoder(const PositionWordConfig& config);  // validates

  // Forget the unwrap state. With no argument the next valid word's sign-extended count is taken
  // as is (the board's absolute count); with next_count, the next valid word reads as next_count.
  void reset(std::optional<std::int64_t> next_count = std::nullopt);

  PositionSample decode(std::uint64_t word);
  // Carry on from where `other` (a decoder of the same word format, e.g. a burst's stream) left
  // off: its last accepted word and count become this decoder's reference.
  void continue_from(const PositionDecoder& other);

  // Decodes n consecutive words: position_m[i] (NaN when invalid) and status[i] (0 = valid).
  // Same results as calling decode() n times; no allocation, branch-light.
  void decode(const std::uint64_t* words, std::size_t n, double* position_m, std::uint8_t* status);

  void set_air_index(double air_index);  // validated like the config
  double count_m() const { return count_m_; }
  const PositionWordConfig& config() const { return config_; }

  std::int64_t count() const { return count_; }  // last accepted unwrapped count
  bool has_reference() const { return !need_reference_; }
  bool continuity_lost() const { return lost_ != 0; }
  // Largest |delta| in counts accepted right after an accepted word.
  std::uint64_t max_step_counts() const { return step_allowance_counts_; }

 private:
  PositionWordConfig config_;
  double count_m_ = 0.0;
  std::uint64_t count_mask_ = 0;
  std::uint64_t reserved_mask_ = 0;
  unsigned sign_shift_ = 0;
  std::uint64_t half_range_counts_ = 0;
  std::uint64_t step_allowance_counts_ = 0;

  bool need_reference_ = true;
  std::optional<std::int64_t> next_count_;
  std::uint64_t last_raw_ = 0;
  std::int64_t count_ = 0;
  std::uint64_t allowance_counts_ = 0;
  std::uint32_t consecutive_jumps_ = 0;
  std::uint8_t lost_ = 0;  // 0 or sample_status::kContinuityLost
};

}  // namespace idm::drivers
