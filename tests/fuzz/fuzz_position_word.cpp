// The position-word codec (drivers/position_word.h): a stream of raw words, as a backend reads
// them from the axis board, through PositionDecoder, with a decoder configuration from the input.
//
// Input: byte 0 the word width (bit 0) and optics (bit 1), byte 1 the maximum velocity
// (1e-4 .. 10 m/s, log scale), byte 2 max_consecutive_jumps, byte 3 the sample interval
// (1e-7 .. 1e-2 s, log scale), byte 4 bit 0: start from a given count; then 8 bytes per word
// (little-endian).
//
// Invariants:
//  * the batch decode gives the same positions and status, bit for bit, as one decode() per word;
//  * status 0 <=> a finite position, and then position == count * count_m;
//  * an invalid sample leaves the unwrapped count where it was;
//  * a word with the valid bit clear, an error bit or a reserved bit set is invalid;
//  * between accepted words the count moves by at most (k + 1) * max_step_counts(), k the words
//    rejected in between;
//  * encode_position_word(word_count(w), width, status bits of w) gives w back for every word
//    without reserved bits.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <vector>

#include "drivers/position_word.h"
#include "model/stage.h"

namespace pw = idm::drivers::position_word;
using idm::drivers::PositionDecoder;
using idm::drivers::PositionWordConfig;
using idm::drivers::WordWidth;

namespace {

[[noreturn]] void fail(const char* what, std::size_t index, std::uint64_t word) {
  std::fprintf(stderr, "fuzz_position_word: word %zu (0x%016llx): %s\n", index,
               static_cast<unsigned long long>(word), what);
  std::abort();
}

double log_scale(std::uint8_t b, double lo, double hi) {
  return lo * std::pow(hi / lo, b / 255.0);
}

bool same_double(double a, double b) {
  return std::memcmp(&a, &b, sizeof a) == 0;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 5) return 0;
  PositionWordConfig config;
  config.width = (data[0] & 1) ? WordWidth::Bits36 : WordWidth::Bits32;
  config.optics =
      (data[0] & 2) ? idm::drivers::Optics::PlaneMirror : idm::drivers::Optics::SingleBeamLinear;
  config.max_velocity_m_s = log_scale(data[1], 1e-4, 10);
  config.max_consecutive_jumps = data[2];
  config.sample_interval_s = log_scale(data[3], 1e-7, 1e-2);
  const bool given_start = data[4] & 1;
  const std::size_t n = (size - 5) / 8;
  std::vector<std::uint64_t> words(n);
  for (std::size_t i = 0; i < n; ++i) {
    std::uint64_t w = 0;
    for (int b = 7; b >= 0; --b) w = (w << 8) | data[5 + 8 * i + static_cast<std::size_t>(b)];
    words[i] = w;
  }

  try {
    PositionDecoder batch(config), single(config);
    if (given_start) {
      batch.reset(-12345);
      single.reset(-12345);
    }
    std::vector<double> position(n);
    std::vector<std::uint8_t> status(n);
    batch.decode(words.data(), n, position.data(), status.data());

    const unsigned bits = static_cast<unsigned>(config.width);
    const std::uint64_t count_mask = (std::uint64_t{1} << bits) - 1;
    const std::uint64_t reserved = ~(count_mask | pw::kDefinedBits);
    bool have_previous = false;
    std::int64_t previous = 0;
    std::uint64_t rejected = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const std::uint64_t w = words[i];
      const std::int64_t before = single.count();
      const idm::drivers::PositionSample s = single.decode(w);
      if (s.status != status[i] || !same_double(s.position_m, position[i]))
        fail("the batch decode differs from decode()", i, w);
      if ((s.status == 0) != std::isfinite(s.position_m))
        fail("status and position disagree", i, w);
      if (s.status == 0 && s.position_m != static_cast<double>(s.count) * single.count_m())
        fail("position is not count * count_m", i, w);
      if (s.status != 0 && have_previous && s.count != before)
        fail("an invalid sample moved the count", i, w);
      const bool malformed =
          !(w & pw::kValid) || (w & (pw::kStatusBits & ~pw::kValid)) || (w & reserved);
      if (malformed && s.status == 0) fail("a malformed or flagged word was accepted", i, w);
      if (s.status == 0) {
        if (have_previous) {
          const std::int64_t delta = s.count - previous;
          const std::uint64_t magnitude =
              delta < 0 ? 0 - static_cast<std::uint64_t>(delta) : static_cast<std::uint64_t>(delta);
          if (magnitude > (rejected + 1) * single.max_step_counts())
            fail("the count jumped farther than the allowance", i, w);
        }
        have_previous = true;
        previous = s.count;
        rejected = 0;
      } else if (have_previous) {
        ++rejected;
      }
      if (!(w & reserved)) {
        const std::uint64_t again = idm::drivers::encode_position_word(
            idm::drivers::word_count(w, config.width), config.width, w & pw::kDefinedBits);
        if (again != w) fail("encode(decode(word)) != word", i, w);
      }
    }
    if (batch.count() != single.count() || batch.continuity_lost() != single.continuity_lost())
      fail("the decoders' states differ after the stream", n, 0);
  } catch (const idm::model::InputError&) {
    // A configuration validate() refuses: not this target's business.
  }
  return 0;
}
