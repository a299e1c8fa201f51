#include "drivers/range_check.h"

#include <cmath>
#include <sstream>

#include "model/stage.h"

namespace idm::drivers::detail {

void check_range(bool ok, const std::string& where, const std::string& key, double value,
                 const char* range) {
  if (ok && std::isfinite(value)) return;
  std::ostringstream msg;
  msg.precision(10);
  msg << where << "." << key << ": " << value << " is out of range, allowed " << range;
  throw model::InputError(msg.str());
}

}  // namespace idm::drivers::detail
