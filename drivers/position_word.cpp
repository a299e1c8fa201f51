#include "drivers/position_word.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "model/range.h"
#include "model/stage.h"

namespace idm::drivers {

namespace {

using model::check_range;

unsigned width_bits(WordWidth width) {
  return static_cast<unsigned>(width);
}

std::uint64_t count_mask(WordWidth width) {
  return (std::uint64_t{1} << width_bits(width)) - 1;
}

std::int64_t sign_extend(std::uint64_t raw, unsigned sign_shift) {
  // C++20: conversion to signed is modular and >> of a negative value is arithmetic.
  return static_cast<std::int64_t>(raw << sign_shift) >> sign_shift;
}

// Allowed |delta| in counts right after an accepted word: the travel at max velocity in one
// interval, rounded up, plus one count for quantization at both ends.
double step_allowance(const PositionWordConfig& c) {
  return std::ceil(c.max_velocity_m_s * c.sample_interval_s / c.count_m()) + 1.0;
}

// The unwrap state and the constants of one decoder, gathered so that the per-word step below
// is the only place where a word is judged (decode(word) and the batch decode share it).
struct UnwrapParams {
  std::uint64_t count_mask;
  std::uint64_t reserved_mask;
  unsigned sign_shift;
  std::uint64_t step_allowance;
  std::uint64_t half_range;
  std::uint32_t max_jumps;
};

struct UnwrapState {
  std::uint64_t last_raw;
  std::int64_t count;
  std::uint64_t allowance;
  std::uint32_t jumps;
  std::uint32_t lost;  // 0 or sample_status::kContinuityLost
};

constexpr std::uint32_t kSignalLost =
    sample_status::kMeasurementSignalLost | sample_status::kReferenceSignalLost;

// Status bits 0..5 of a word on its own: the word's status bits (valid inverted) and reserved.
inline std::uint32_t word_flags(std::uint64_t word, const UnwrapParams& p) {
  std::uint32_t f = static_cast<std::uint32_t>((word >> position_word::kStatusShift) & 0x1Fu) ^ 1u;
  f |= static_cast<std::uint32_t>((word & p.reserved_mask) != 0) << 5;
  return f;
}

// One word once a reference exists. Written without data-dependent branches: the outcome is
// folded into the state by selects so that the batch loop stays a straight line.
inline std::uint32_t step(std::uint64_t word, const UnwrapParams& p, UnwrapState& s) {
  const std::uint64_t raw = word & p.count_mask;
  std::uint32_t f = word_flags(word, p) | s.lost;
  const std::int64_t delta = sign_extend(raw - s.last_raw, p.sign_shift);
  const std::uint64_t magnitude = delta < 0 ? std::uint64_t{0} - static_cast<std::uint64_t>(delta)
                                            : static_cast<std::uint64_t>(delta);
  f |= static_cast<std::uint32_t>((f == 0) & (magnitude > s.allowance)) << 6;
  const bool ok = f == 0;
  s.count += ok ? delta : 0;
  s.last_raw = ok ? raw : s.last_raw;
  s.allowance = ok ? p.step_allowance : std::min(s.allowance + p.step_allowance, p.half_range);
  s.jumps = ok ? 0 : s.jumps + ((f >> 6) & 1u);
  const bool lose =
      ((f & kSignalLost) != 0) | (s.jumps > p.max_jumps) | (s.allowance >= p.half_range);
  s.lost |= lose ? sample_status::kContinuityLost : 0u;
  return f;
}

}  // namespace

std::string describe_sample_status(std::uint8_t status) {
  if (status == 0) return "valid";
  static constexpr const char* kNames[8] = {
      "not_valid",      "measurement_signal_lost", "reference_signal_lost", "glitch_flagged",
      "sample_overrun", "reserved_bits_set",       "jump_too_fast",         "continuity_lost"};
  std::string out;
  for (unsigned bit = 0; bit < 8; ++bit) {
    if ((status >> bit) & 1u) {
      if (!out.empty()) out += '+';
      out += kNames[bit];
    }
  }
  return out;
}

double optics_divisor(Optics optics) {
  switch (optics) {
    case Optics::SingleBeamLinear:
      return 64.0;
    case Optics::PlaneMirror:
      return 128.0;
    case Optics::Custom:
      break;
  }
  throw model::InputError(
      "optics: only single_beam_linear (64) and plane_mirror (128) have a "
      "fixed divisor; custom optics take interferometer.divisor");
}

const char* optics_name(Optics optics) {
  switch (optics) {
    case Optics::SingleBeamLinear:
      return "single_beam_linear";
    case Optics::PlaneMirror:
      return "plane_mirror";
    case Optics::Custom:
      return "custom";
  }
  return "unknown";
}

Optics parse_optics(const std::string& name, const std::string& where) {
  for (Optics o : {Optics::SingleBeamLinear, Optics::PlaneMirror, Optics::Custom}) {
    if (name == optics_name(o)) return o;
  }
  throw model::InputError(where + ": unknown optics '" + name +
                          "' (known: single_beam_linear, plane_mirror, custom)");
}

double PositionWordConfig::effective_divisor() const {
  return optics == Optics::Custom ? divisor : optics_divisor(optics);
}

double PositionWordConfig::count_m() const {
  return lambda_vac_m / (air_index * effective_divisor());
}

void validate(const PositionWordConfig& c, const std::string& where) {
  if (c.width != WordWidth::Bits32 && c.width != WordWidth::Bits36) {
    check_range(false, where, "word_bits", static_cast<double>(c.width), "32 or 36");
  }
  if (c.optics != Optics::SingleBeamLinear && c.optics != Optics::PlaneMirror &&
      c.optics != Optics::Custom) {
    throw model::InputError(where +
                            ".optics: unknown optics (known: single_beam_linear, "
                            "plane_mirror, custom)");
  }
  if (c.optics == Optics::Custom) {
    check_range(c.divisor > 0.0 && c.divisor <= 1e6, where, "divisor", c.divisor, "(0, 1e6]");
  }
  check_range(c.lambda_vac_m >= 100e-9 && c.lambda_vac_m <= 20e-6, where, "lambda_vac_m",
              c.lambda_vac_m, "[100e-9, 20e-6]");
  check_range(c.air_index >= 1.0 && c.air_index <= 1.01, where, "air_index", c.air_index,
              "[1, 1.01]");
  check_range(c.sample_interval_s > 0.0 && c.sample_interval_s <= 10.0, where, "sample_interval_s",
              c.sample_interval_s, "(0, 10]");
  check_range(c.max_velocity_m_s > 0.0 && c.max_velocity_m_s <= 100.0, where, "max_velocity_m_s",
              c.max_velocity_m_s, "(0, 100]");
  check_range(c.max_consecutive_jumps >= 1 && c.max_consecutive_jumps <= 1000000, where,
              "max_consecutive_jumps", c.max_consecutive_jumps, "[1, 1000000]");
  // The travel allowed in one interval must stay below half the counter range, or the roll-over
  // could not be told from a jump.
  const double half_range = std::ldexp(1.0, static_cast<int>(width_bits(c.width)) - 1);
  if (!(step_allowance(c) < half_range)) {
    std::ostringstream msg;
    msg.precision(10);
    msg << where << ".max_velocity_m_s: " << c.max_velocity_m_s << " m/s over "
        << c.sample_interval_s << " s is " << step_allowance(c)
        << " counts per sample, allowed below half the counter range (" << half_range << ")";
    throw model::InputError(msg.str());
  }
}

std::uint64_t encode_position_word(std::int64_t count, WordWidth width, std::uint64_t status_bits) {
  if ((status_bits & ~position_word::kDefinedBits) != 0) {
    std::ostringstream msg;
    msg << "encode_position_word: status bits 0x" << std::hex << status_bits
        << " outside the defined bits 40..45";
    throw model::InputError(msg.str());
  }
  return (static_cast<std::uint64_t>(count) & count_mask(width)) | status_bits;
}

std::int64_t word_count(std::uint64_t word, WordWidth width) {
  return sign_extend(word & count_mask(width), 64 - width_bits(width));
}

PositionEncoder::PositionEncoder(const PositionWordConfig& config) : config_(config) {
  validate(config_);
  count_m_ = config_.count_m();
}

void PositionEncoder::set_air_index(double air_index) {
  PositionWordConfig c = config_;
  c.air_index = air_index;
  validate(c);
  config_ = c;
  count_m_ = config_.count_m();
}

std::int64_t PositionEncoder::counts_from_m(double position_m) const {
  const double counts = std::nearbyint(position_m / count_m_);
  if (!(std::fabs(counts) < 0x1p62)) {
    std::ostringstream msg;
    msg.precision(10);
    msg << "PositionEncoder: position " << position_m << " m is not representable in counts";
    throw model::InputError(msg.str());
  }
  return static_cast<std::int64_t>(counts);
}

std::uint64_t PositionEncoder::encode_count(std::int64_t count, std::uint64_t status_bits) const {
  return encode_position_word(count, config_.width, status_bits);
}

std::uint64_t PositionEncoder::encode_m(double position_m, std::uint64_t status_bits) const {
  return encode_count(counts_from_m(position_m), status_bits);
}

PositionDecoder::PositionDecoder(const PositionWordConfig& config) : config_(config) {
  validate(config_);
  count_m_ = config_.count_m();
  const unsigned bits = width_bits(config_.width);
  count_mask_ = count_mask(config_.width);
  // Everything but the count field, the defined status bits and the reference mark.
  reserved_mask_ = ~(count_mask_ | position_word::kDefinedBits);
  sign_shift_ = 64 - bits;
  half_range_counts_ = std::uint64_t{1} << (bits - 1);
  step_allowance_counts_ = static_cast<std::uint64_t>(step_allowance(config_));
  reset();
}

void PositionDecoder::reset(std::optional<std::int64_t> next_count) {
  need_reference_ = true;
  next_count_ = next_count;
  last_raw_ = 0;
  allowance_counts_ = step_allowance_counts_;
  consecutive_jumps_ = 0;
  lost_ = 0;
}

void PositionDecoder::continue_from(const PositionDecoder& other) {
  reset();
  if (other.need_reference_) return;
  need_reference_ = false;
  last_raw_ = other.last_raw_;
  count_ = other.count_;
}

void PositionDecoder::set_air_index(double air_index) {
  PositionWordConfig c = config_;
  c.air_index = air_index;
  validate(c);
  config_ = c;
  count_m_ = config_.count_m();
  step_allowance_counts_ = static_cast<std::uint64_t>(step_allowance(config_));
}

PositionSample PositionDecoder::decode(std::uint64_t word) {
  double position_m = 0.0;
  std::uint8_t status = 0;
  decode(&word, 1, &position_m, &status);
  return PositionSample{count_, position_m, status, (word & position_word::kReferenceMark) != 0};
}

void PositionDecoder::decode(const std::uint64_t* words, std::size_t n, double* position_m,
                             std::uint8_t* status) {
  const UnwrapParams p{count_mask_,        reserved_mask_,
                       sign_shift_,        step_allowance_counts_,
                       half_range_counts_, config_.max_consecutive_jumps};
  const double scale_m = count_m_;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  std::size_t i = 0;

  // Until a well-formed word without error bits arrives there is nothing to unwrap against.
  for (; need_reference_ && i < n; ++i) {
    const std::uint32_t f = word_flags(words[i], p);
    if (f == 0) {
      last_raw_ = words[i] & count_mask_;
      count_ = next_count_ ? *next_count_ : sign_extend(last_raw_, sign_shift_);
      allowance_counts_ = step_allowance_counts_;
      consecutive_jumps_ = 0;
      need_reference_ = false;
    }
    position_m[i] = f == 0 ? static_cast<double>(count_) * scale_m : nan;
    status[i] = static_cast<std::uint8_t>(f);
  }

  UnwrapState s{last_raw_, count_, allowance_counts_, consecutive_jumps_, lost_};
  for (; i < n; ++i) {
    const std::uint32_t f = step(words[i], p, s);
    position_m[i] = f == 0 ? static_cast<double>(s.count) * scale_m : nan;
    status[i] = static_cast<std::uint8_t>(f);
  }
  last_raw_ = s.last_raw;
  count_ = s.count;
  allowance_counts_ = s.allowance;
  consecutive_jumps_ = s.jumps;
  lost_ = static_cast<std::uint8_t>(s.lost);
}

}  // namespace idm::drivers
