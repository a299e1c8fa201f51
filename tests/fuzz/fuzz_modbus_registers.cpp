// The Modbus reply decoders (drivers/modbus/register_map.h): registers as a device sends them,
// through decode_position (every latch and capture record) and decode_value (the capture rate and
// the other scaled fields), with the word width, word order and value formats from the input.
//
// Input: byte 0 bit 0 the word width, bit 1 the word order, bits 2..3 the value format; byte 1
// the scale (10^(k-6), k = 0..15); then 2 bytes per register (little-endian).
//
// Invariants:
//  * a decoded position word carries only the count field, the status bits, the reference mark
//    (bit 45) and, for a status register with undefined bits, reserved bit 46; encode_position
//    carries all but that bit, so decode . encode . decode == decode less bit 46;
//  * the word goes through a PositionDecoder without harm and is invalid when bit 46 is set;
//  * a decoded value that is finite encodes back (encode_value succeeds) into registers that
//    decode to the same value.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>

#include "drivers/modbus/register_map.h"
#include "drivers/position_word.h"

using namespace idm::drivers;
using namespace idm::drivers::modbus;

namespace {

[[noreturn]] void fail(const char* what, const std::uint16_t* regs, std::size_t n) {
  std::fprintf(stderr, "fuzz_modbus_registers: %s; registers", what);
  for (std::size_t i = 0; i < n; ++i) std::fprintf(stderr, " 0x%04x", regs[i]);
  std::fprintf(stderr, "\n");
  std::abort();
}

bool same_double(double a, double b) {
  return std::memcmp(&a, &b, sizeof a) == 0;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 2) return 0;
  const WordWidth width = (data[0] & 1) ? WordWidth::Bits36 : WordWidth::Bits32;
  const WordOrder order = (data[0] & 2) ? WordOrder::LowFirst : WordOrder::HighFirst;
  ScaledField field;
  field.format = static_cast<ValueFormat>((data[0] >> 2) & 3);
  field.scale = std::pow(10.0, static_cast<int>(data[1] % 16) - 6);
  const std::size_t n = (size - 2) / 2;
  if (n == 0) return 0;
  std::uint16_t regs[64] = {};
  const std::size_t count = n < 64 ? n : 64;
  for (std::size_t i = 0; i < count; ++i)
    regs[i] = static_cast<std::uint16_t>(data[2 + 2 * i] | (data[3 + 2 * i] << 8));

  // Position records, one after another as in the capture area.
  const std::size_t per_record = RegisterMap::position_registers(width);
  const unsigned bits = static_cast<unsigned>(width);
  const std::uint64_t undefined_status = std::uint64_t{1} << 46;  // reserved: undefined status
  const std::uint64_t allowed =
      ((std::uint64_t{1} << bits) - 1) | position_word::kDefinedBits | undefined_status;
  PositionWordConfig config;
  config.width = width;
  PositionDecoder decoder(config);
  for (std::size_t at = 0; at + per_record <= count; at += per_record) {
    const std::uint16_t* record = regs + at;
    const std::uint64_t word = decode_position(record, width, order);
    if (word & ~allowed) fail("a decoded word with bits outside the layout", record, per_record);
    std::uint16_t again[4] = {};
    encode_position(word, width, order, again);
    if (decode_position(again, width, order) != (word & ~undefined_status))
      fail("decode(encode(word)) != word without its reserved bits", record, per_record);
    const PositionSample s = decoder.decode(word);
    if ((word & undefined_status) != 0 && s.valid())
      fail("a malformed record decoded as valid", record, per_record);
  }

  // Scaled values.
  const std::size_t per_value = register_count(field.format);
  for (std::size_t at = 0; at + per_value <= count; at += per_value) {
    const std::uint16_t* value_regs = regs + at;
    const double value = decode_value(field, order, value_regs);
    if (!std::isfinite(value)) continue;
    std::uint16_t again[2] = {};
    if (!encode_value(field, value, order, again))
      fail("a finite decoded value does not encode", value_regs, per_value);
    if (!same_double(decode_value(field, order, again), value))
      fail("decode(encode(value)) != value", value_regs, per_value);
  }
  return 0;
}
