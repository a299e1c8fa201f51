// Ranges of allowed values, and the one range check that configs, parameters, effects and driver
// settings all go through: InputError "WHERE.KEY: VALUE is out of range, allowed RANGE".
#pragma once

#include <cmath>
#include <string>
#include <string_view>

#include "model/stage.h"

namespace idm::model {

// A number as messages print it: up to 9 significant digits, exponents without '+' and
// leading zeros ("0.05", "1e-5", "1e6", "-3").
std::string format_number(double value);

// The same with `significant` digits: a fitted figure in a sentence for a person ("3510",
// "0.534"), where nine digits would claim a precision the fit does not have.
std::string format_number(double value, int significant);

// The one reader of a decimal number's text (files, command lines, the protocol): the whole text
// must be the number. A value too small for a normal double (1e-320) reads as the nearest double
// (stod and from_chars call it out of range); one too large, inf and nan are NotFinite.
enum class NumberText : unsigned char { Ok, NotANumber, NotFinite };
NumberText parse_decimal(std::string_view text, double& value);

// A closed (or half-open) interval of allowed values; an unbounded end is +-1e300.
struct Range {
  double lo = -1e300;
  double hi = 1e300;
  bool lo_open = false;
  bool hi_open = false;
  bool contains(double v) const {
    return std::isfinite(v) && (lo_open ? v > lo : v >= lo) && (hi_open ? v < hi : v <= hi);
  }
  std::string text() const;  // "[0, 1000]", "(0, 0.001]", ">= 0", "any number"
  // The values both ranges allow (lo > hi, or an open end at lo == hi: none).
  Range intersect(const Range& o) const {
    Range r = *this;
    if (o.lo > r.lo || (o.lo == r.lo && o.lo_open)) {
      r.lo = o.lo;
      r.lo_open = o.lo_open || (o.lo == lo && lo_open);
    }
    if (o.hi < r.hi || (o.hi == r.hi && o.hi_open)) {
      r.hi = o.hi;
      r.hi_open = o.hi_open || (o.hi == hi && hi_open);
    }
    return r;
  }
};

// "WHERE.KEY" ("KEY" when where is empty).
std::string qualified(const std::string& where, const std::string& key);

[[noreturn]] void throw_out_of_range(const std::string& where, const std::string& key, double value,
                                     const std::string& allowed);

// Throws unless `range` contains `value` (finite).
inline void check_range(const std::string& where, const std::string& key, double value,
                        const Range& range) {
  if (!range.contains(value)) throw_out_of_range(where, key, value, range.text());
}
// For a condition that one interval cannot say (bounds that depend on other values, a size):
// throws unless ok and value is finite; `allowed` is the range as the message shows it.
inline void check_range(bool ok, const std::string& where, const std::string& key, double value,
                        const std::string& allowed) {
  if (!ok || !std::isfinite(value)) throw_out_of_range(where, key, value, allowed);
}

}  // namespace idm::model
