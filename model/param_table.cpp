#include "model/param_table.h"

namespace idm::model {

std::string Range::text() const {
  const bool no_lo = lo <= -1e300, no_hi = hi >= 1e300;
  if (no_lo && no_hi) return "any number";
  if (no_lo) return std::string(hi_open ? "< " : "<= ") + format_number(hi);
  if (no_hi) return std::string(lo_open ? "> " : ">= ") + format_number(lo);
  return std::string(lo_open ? "(" : "[") + format_number(lo) + ", " + format_number(hi) +
         (hi_open ? ")" : "]");
}

std::string markdown_header() {
  return "| key | unit | default | range | meaning |\n|---|---|---|---|---|\n";
}

}  // namespace idm::model
