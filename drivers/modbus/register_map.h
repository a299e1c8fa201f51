// The register map of a Modbus waveform generator with a position counter, shared by the client
// backend (modbus_backend.h) and the simulated device (tools/idm-simdev): addresses, value
// formats, scaling and word order, all from the config (`daq.modbus.registers`, defaults in
// drivers/modbus/README.md), and the encoding of values and position words into 16-bit registers.
// No libmodbus here: plain functions over uint16_t arrays.
#pragma once

#include <yaml-cpp/yaml.h>

#include <cstddef>
#include <cstdint>
#include <string>

#include "drivers/position_word.h"
#include "model/waveform.h"

namespace idm::drivers::modbus {

enum class WordOrder : std::uint8_t { HighFirst, LowFirst };
enum class ValueFormat : std::uint8_t { U16, U32, I32, Float32 };

const char* word_order_name(WordOrder order);       // "high_first", "low_first"
const char* value_format_name(ValueFormat format);  // "u16", "u32", "i32", "float32"
std::size_t register_count(ValueFormat format);     // 1 or 2

// A scaled value: register value = SI value * scale (rounded to the nearest integer for the
// integer formats).
struct ScaledField {
  std::uint16_t address = 0;
  ValueFormat format = ValueFormat::U32;
  double scale = 1.0;
};

// Command register values.
namespace command {
inline constexpr std::uint16_t kStart = 1;
inline constexpr std::uint16_t kStop = 2;
}  // namespace command

// Status register bits.
namespace status_bit {
inline constexpr std::uint16_t kRunning = 1u << 0;         // a burst is playing
inline constexpr std::uint16_t kDone = 1u << 1;            // a burst finished since START
inline constexpr std::uint16_t kParameterError = 1u << 2;  // the last START was rejected
inline constexpr std::uint16_t kFault = 1u << 3;           // the device has a fault
inline constexpr std::uint16_t kCaptureOverrun = 1u << 4;  // the capture buffer was full
}  // namespace status_bit

struct RegisterMap {
  WordOrder word_order = WordOrder::HighFirst;
  // Holding registers (function codes 3, 6, 16).
  std::uint16_t command = 0;   // u16, write: 1 START, 2 STOP
  std::uint16_t status = 1;    // u16, read: status_bit
  std::uint16_t burst_id = 2;  // u16: +1 at every START
  // u16 that changes whenever the device restarts (and so its position count): the same value
  // before and after a reconnect means the count went on. -1: the map has none.
  int boot_id = 3;
  ScaledField freq_hz{4, ValueFormat::U32, 1e3};    // mHz
  ScaledField duty{6, ValueFormat::U32, 1e6};       // parts per million
  ScaledField stroke_m{8, ValueFormat::U32, 1e12};  // pm
  ScaledField cycles{10, ValueFormat::U32, 1.0};
  std::uint16_t position = 16;       // the latched word: count (2 or 3 registers), status
  std::uint16_t capture_count = 24;  // u32: samples captured since the last START
  ScaledField capture_rate_hz{26, ValueFormat::U32, 1.0};
  std::uint16_t capture_base = 1024;      // capture records, each like `position`
  std::uint16_t capture_capacity = 8192;  // records

  // Registers of one position record: 2 count registers (32-bit words) or 3 (36-bit), then one
  // status register (bits 0..4 = word bits 40..44).
  static std::size_t position_registers(WordWidth width) {
    return width == WordWidth::Bits32 ? 3 : 4;
  }
  // One past the highest register the map uses.
  std::size_t register_span(WordWidth width) const;
};

// Throws model::InputError (naming the key) when fields overlap, the capture area leaves the
// 16-bit address space, or a scale is not positive.
void validate(const RegisterMap& map, WordWidth width, const std::string& where);

// `daq.modbus.registers` (unknown keys are errors with file:line):
//   word_order: high_first | low_first
//   command, status, burst_id, position, capture_count, capture_base, capture_capacity: integers
//   boot_id: an address, or none
//   freq_hz, duty, stroke_m, cycles, capture_rate_hz: {address, format: u16|u32|i32|float32, scale}
RegisterMap parse_register_map(const YAML::Node& node, const std::string& file, WordWidth width);

// Encodes an SI value into register_count(format) registers. False (nothing written) when the
// scaled value does not fit the format or is not finite.
bool encode_value(const ScaledField& field, double value, WordOrder order, std::uint16_t* regs);
// Decodes registers into an SI value.
double decode_value(const ScaledField& field, WordOrder order, const std::uint16_t* regs);

// Encodes a raw word (position_word.h layout) into a position record and back. Count bits above
// the width and reserved word bits are not carried. The status register's bits 0..5 are the
// word's bits 40..45 (status bits and the reference mark); bits above 5 (undefined) decode to
// reserved word bit 46, so that the decoder marks such a sample invalid.
void encode_position(std::uint64_t word, WordWidth width, WordOrder order, std::uint16_t* regs);
std::uint64_t decode_position(const std::uint16_t* regs, WordWidth width, WordOrder order);

}  // namespace idm::drivers::modbus
