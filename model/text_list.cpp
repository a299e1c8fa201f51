#include "model/text_list.h"

#include <charconv>
#include <cmath>

namespace idm::model {

bool is_blank(char c) {
  return c == ' ' || c == '\t';
}

std::string_view trim(std::string_view s) {
  while (!s.empty() && is_blank(s.front())) s.remove_prefix(1);
  while (!s.empty() && is_blank(s.back())) s.remove_suffix(1);
  return s;
}

bool split_range(std::string_view text, std::string_view (&parts)[3]) {
  const std::size_t c1 = text.find(':');
  if (c1 == std::string_view::npos) return false;
  const std::size_t c2 = text.find(':', c1 + 1);
  if (c2 == std::string_view::npos || text.find(':', c2 + 1) != std::string_view::npos)
    return false;
  parts[0] = text.substr(0, c1);
  parts[1] = text.substr(c1 + 1, c2 - c1 - 1);
  parts[2] = text.substr(c2 + 1);
  return true;
}

RangeError expand_range(double start, double stop, double step, std::size_t max_values,
                        std::vector<double>& out) {
  if (!(step > 0) || !(stop >= start)) return RangeError::BadRange;
  const double n = std::floor((stop - start) / step + 1e-9);  // values after the first
  if (!(n + 1 <= static_cast<double>(max_values))) return RangeError::TooMany;
  out.reserve(out.size() + static_cast<std::size_t>(n) + 1);
  for (long k = 0; k <= static_cast<long>(n); ++k) {
    // Locale-independent round trip through 12 significant digits.
    char buf[40];
    const double raw = start + static_cast<double>(k) * step;
    const auto written = std::to_chars(buf, buf + sizeof buf, raw, std::chars_format::general, 12);
    double v = raw;
    std::from_chars(buf, written.ptr, v);
    out.push_back(v);
  }
  return RangeError::None;
}

}  // namespace idm::model
