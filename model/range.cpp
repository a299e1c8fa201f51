#include "model/range.h"

#include <cctype>
#include <cmath>
#include <cstdlib>
#include <sstream>

namespace idm::model {

NumberText parse_decimal(std::string_view text, double& value) {
  if (text.empty() || std::isspace(static_cast<unsigned char>(text.front())) != 0)
    return NumberText::NotANumber;
  const std::string copy(text);  // strtod needs the terminating NUL
  char* end = nullptr;
  const double v = std::strtod(copy.c_str(), &end);
  if (end != copy.c_str() + copy.size()) return NumberText::NotANumber;
  if (!std::isfinite(v)) return NumberText::NotFinite;
  value = v;
  return NumberText::Ok;
}

std::string format_number(double value) {
  return format_number(value, 9);
}

std::string format_number(double value, int significant) {
  // the significant digits, then the exponent as a person writes it: no '+', no leading zeros.
  std::ostringstream out;
  out.precision(significant);
  out << value;
  std::string text = out.str();
  const std::size_t e = text.find('e');
  if (e == std::string::npos) return text;
  std::size_t digits = e + 1;
  std::string sign;
  if (text[digits] == '+' || text[digits] == '-') {
    if (text[digits] == '-') sign = "-";
    ++digits;
  }
  while (digits + 1 < text.size() && text[digits] == '0') ++digits;
  return text.substr(0, e + 1) + sign + text.substr(digits);
}

std::string Range::text() const {
  const bool no_lo = lo <= -1e300, no_hi = hi >= 1e300;
  if (no_lo && no_hi) return "any number";
  if (no_lo) return std::string(hi_open ? "< " : "<= ") + format_number(hi);
  if (no_hi) return std::string(lo_open ? "> " : ">= ") + format_number(lo);
  return std::string(lo_open ? "(" : "[") + format_number(lo) + ", " + format_number(hi) +
         (hi_open ? ")" : "]");
}

std::string qualified(const std::string& where, const std::string& key) {
  return where.empty() ? key : where + "." + key;
}

void throw_out_of_range(const std::string& where, const std::string& key, double value,
                        const std::string& allowed) {
  throw InputError(qualified(where, key) + ": " + format_number(value) +
                   " is out of range, allowed " + allowed);
}

}  // namespace idm::model
