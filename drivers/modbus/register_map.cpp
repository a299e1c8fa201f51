#include "drivers/modbus/register_map.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <vector>

#include "drivers/config.h"
#include "model/stage.h"
#include "model/yaml_util.h"

namespace idm::drivers::modbus {

using model::InputError;
using model::located;

const char* word_order_name(WordOrder order) {
  return order == WordOrder::HighFirst ? "high_first" : "low_first";
}

const char* value_format_name(ValueFormat format) {
  switch (format) {
    case ValueFormat::U16:
      return "u16";
    case ValueFormat::U32:
      return "u32";
    case ValueFormat::I32:
      return "i32";
    case ValueFormat::Float32:
      return "float32";
  }
  return "?";
}

std::size_t register_count(ValueFormat format) {
  return format == ValueFormat::U16 ? 1 : 2;
}

std::size_t RegisterMap::register_span(WordWidth width) const {
  return std::size_t{capture_base} + std::size_t{capture_capacity} * position_registers(width);
}

namespace {

// A record's status register: bits 0..5 are the word's bits 40..45 (the status bits and the
// reference mark); a higher bit is not defined and becomes reserved word bit 46.
constexpr std::uint16_t kDefinedStatus = 0x3Fu;
constexpr std::uint64_t kUndefinedStatusBit = std::uint64_t{1} << 46;

struct Span {
  const char* name;
  std::size_t first, count;
};

std::vector<Span> spans(const RegisterMap& m, WordWidth width) {
  std::vector<Span> out = {
      {"command", m.command, 1},
      {"status", m.status, 1},
      {"burst_id", m.burst_id, 1},
      {"freq_hz", m.freq_hz.address, register_count(m.freq_hz.format)},
      {"duty", m.duty.address, register_count(m.duty.format)},
      {"stroke_m", m.stroke_m.address, register_count(m.stroke_m.format)},
      {"cycles", m.cycles.address, register_count(m.cycles.format)},
      {"position", m.position, RegisterMap::position_registers(width)},
      {"capture_count", m.capture_count, 2},
      {"capture_rate_hz", m.capture_rate_hz.address, register_count(m.capture_rate_hz.format)},
      {"capture_base", m.capture_base,
       std::size_t{m.capture_capacity} * RegisterMap::position_registers(width)}};
  if (m.boot_id >= 0) out.push_back({"boot_id", static_cast<std::size_t>(m.boot_id), 1});
  return out;
}

void put32(std::uint32_t v, WordOrder order, std::uint16_t* regs) {
  const std::uint16_t hi = static_cast<std::uint16_t>(v >> 16), lo = static_cast<std::uint16_t>(v);
  regs[0] = order == WordOrder::HighFirst ? hi : lo;
  regs[1] = order == WordOrder::HighFirst ? lo : hi;
}

std::uint32_t get32(const std::uint16_t* regs, WordOrder order) {
  const std::uint32_t a = regs[0], b = regs[1];
  return order == WordOrder::HighFirst ? (a << 16) | b : (b << 16) | a;
}

}  // namespace

void validate(const RegisterMap& m, WordWidth width, const std::string& where) {
  for (const ScaledField* f : {&m.freq_hz, &m.duty, &m.stroke_m, &m.cycles, &m.capture_rate_hz})
    if (!(std::isfinite(f->scale) && f->scale > 0))
      throw InputError(where + ": every scale must be finite and > 0");
  if (m.capture_capacity < 1) throw InputError(where + ".capture_capacity: must be >= 1");
  if (m.register_span(width) > 65536)
    throw InputError(where + ".capture_base: the capture area (" +
                     std::to_string(m.capture_capacity) + " records of " +
                     std::to_string(RegisterMap::position_registers(width)) + " registers from " +
                     std::to_string(m.capture_base) + ") leaves the 16-bit address space");
  const std::vector<Span> s = spans(m, width);
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (s[i].first + s[i].count > 65536)
      throw InputError(where + "." + s[i].name + ": ends past register 65535");
    for (std::size_t j = i + 1; j < s.size(); ++j)
      if (s[i].first < s[j].first + s[j].count && s[j].first < s[i].first + s[i].count)
        throw InputError(where + ": " + s[i].name + " (" + std::to_string(s[i].first) + ", " +
                         std::to_string(s[i].count) + " registers) overlaps " + s[j].name + " (" +
                         std::to_string(s[j].first) + ", " + std::to_string(s[j].count) +
                         " registers)");
  }
}

RegisterMap parse_register_map(const YAML::Node& node, const std::string& file, WordWidth width) {
  RegisterMap m;
  const std::string w = "daq.modbus.registers";
  if (!detail::present(node)) {
    validate(m, width, w);
    return m;
  }
  detail::check_keys(node, file, w,
                     {"word_order", "command", "status", "burst_id", "boot_id", "freq_hz", "duty",
                      "stroke_m", "cycles", "position", "capture_count", "capture_rate_hz",
                      "capture_base", "capture_capacity"});
  auto address = [&](const char* key, std::uint16_t& out) {
    if (const YAML::Node v = node[key])
      out = static_cast<std::uint16_t>(model::read_integer(v, file, w + "." + key, 0, 65535));
  };
  auto field = [&](const char* key, ScaledField& out) {
    const YAML::Node v = node[key];
    if (!v) return;
    const std::string k = w + "." + key;
    detail::check_keys(v, file, k, {"address", "format", "scale"});
    if (v["address"])
      out.address = static_cast<std::uint16_t>(
          model::read_integer(v["address"], file, k + ".address", 0, 65535));
    if (const YAML::Node f = v["format"]) {
      const std::string name = model::read_string(f, file, k + ".format");
      bool found = false;
      for (ValueFormat vf :
           {ValueFormat::U16, ValueFormat::U32, ValueFormat::I32, ValueFormat::Float32})
        if (name == value_format_name(vf)) out.format = vf, found = true;
      if (!found)
        throw InputError(located(file, f, k + ".format",
                                 "unknown format '" + name + "', allowed u16, u32, i32, float32"));
    }
    if (v["scale"]) out.scale = model::read_double(v["scale"], file, k + ".scale", 0, 1e15, true);
  };
  if (const YAML::Node v = node["word_order"]) {
    const std::string o = model::read_string(v, file, w + ".word_order");
    if (o == "high_first")
      m.word_order = WordOrder::HighFirst;
    else if (o == "low_first")
      m.word_order = WordOrder::LowFirst;
    else
      throw InputError(located(file, v, w + ".word_order",
                               "unknown word order '" + o + "', allowed high_first, low_first"));
  }
  address("command", m.command);
  address("status", m.status);
  address("burst_id", m.burst_id);
  if (const YAML::Node v = node["boot_id"]) {
    if (v.IsScalar() && v.Scalar() == "none")
      m.boot_id = -1;
    else
      m.boot_id = static_cast<int>(model::read_integer(v, file, w + ".boot_id", 0, 65535));
  }
  field("freq_hz", m.freq_hz);
  field("duty", m.duty);
  field("stroke_m", m.stroke_m);
  field("cycles", m.cycles);
  address("position", m.position);
  address("capture_count", m.capture_count);
  field("capture_rate_hz", m.capture_rate_hz);
  address("capture_base", m.capture_base);
  if (const YAML::Node v = node["capture_capacity"])
    m.capture_capacity =
        static_cast<std::uint16_t>(model::read_integer(v, file, w + ".capture_capacity", 1, 65535));
  try {
    validate(m, width, w);
  } catch (const InputError& e) {
    throw InputError(located(file, node, w, e.what()));
  }
  return m;
}

bool encode_value(const ScaledField& f, double value, WordOrder order, std::uint16_t* regs) {
  const double scaled = value * f.scale;
  if (!std::isfinite(scaled)) return false;
  switch (f.format) {
    case ValueFormat::U16: {
      const double r = std::round(scaled);
      if (r < 0 || r > 65535) return false;
      regs[0] = static_cast<std::uint16_t>(r);
      return true;
    }
    case ValueFormat::U32: {
      const double r = std::round(scaled);
      if (r < 0 || r > 4294967295.0) return false;
      put32(static_cast<std::uint32_t>(r), order, regs);
      return true;
    }
    case ValueFormat::I32: {
      const double r = std::round(scaled);
      if (r < -2147483648.0 || r > 2147483647.0) return false;
      put32(static_cast<std::uint32_t>(static_cast<std::int32_t>(r)), order, regs);
      return true;
    }
    case ValueFormat::Float32: {
      // Every value that rounds to a finite float32, up to halfway between its largest and 2^128:
      // the largest a device sends, read back through a scale, can come back a rounding above it.
      constexpr double kFloatMax = std::numeric_limits<float>::max();
      if (!(std::fabs(scaled) < 0x1.ffffffp127)) return false;
      const float fl = static_cast<float>(std::clamp(scaled, -kFloatMax, kFloatMax));
      std::uint32_t bits = 0;
      std::memcpy(&bits, &fl, sizeof bits);
      put32(bits, order, regs);
      return true;
    }
  }
  return false;
}

double decode_value(const ScaledField& f, WordOrder order, const std::uint16_t* regs) {
  switch (f.format) {
    case ValueFormat::U16:
      return regs[0] / f.scale;
    case ValueFormat::U32:
      return get32(regs, order) / f.scale;
    case ValueFormat::I32:
      return static_cast<std::int32_t>(get32(regs, order)) / f.scale;
    case ValueFormat::Float32: {
      const std::uint32_t bits = get32(regs, order);
      float fl = 0;
      std::memcpy(&fl, &bits, sizeof fl);
      return static_cast<double>(fl) / f.scale;
    }
  }
  return 0.0;
}

void encode_position(std::uint64_t word, WordWidth width, WordOrder order, std::uint16_t* regs) {
  const std::uint16_t status =
      static_cast<std::uint16_t>((word >> position_word::kStatusShift) & kDefinedStatus);
  if (width == WordWidth::Bits32) {
    put32(static_cast<std::uint32_t>(word), order, regs);
    regs[2] = status;
    return;
  }
  const std::uint16_t top = static_cast<std::uint16_t>((word >> 32) & 0xFu);
  const std::uint16_t mid = static_cast<std::uint16_t>(word >> 16),
                      low = static_cast<std::uint16_t>(word);
  regs[0] = order == WordOrder::HighFirst ? top : low;
  regs[1] = mid;
  regs[2] = order == WordOrder::HighFirst ? low : top;
  regs[3] = status;
}

std::uint64_t decode_position(const std::uint16_t* regs, WordWidth width, WordOrder order) {
  std::uint64_t count = 0;
  std::uint16_t status = 0;
  if (width == WordWidth::Bits32) {
    count = get32(regs, order);
    status = regs[2];
  } else {
    const std::uint64_t top = (order == WordOrder::HighFirst ? regs[0] : regs[2]) & 0xFu;
    const std::uint64_t low = order == WordOrder::HighFirst ? regs[2] : regs[0];
    count = (top << 32) | (std::uint64_t{regs[1]} << 16) | low;
    status = regs[3];
  }
  std::uint64_t word =
      count | (static_cast<std::uint64_t>(status & kDefinedStatus) << position_word::kStatusShift);
  // Status bits the layout does not define: a malformed record; a reserved word bit makes the
  // decoder mark it invalid rather than drop the evidence.
  if ((status & ~kDefinedStatus) != 0) word |= kUndefinedStatusBit;
  return word;
}

}  // namespace idm::drivers::modbus
