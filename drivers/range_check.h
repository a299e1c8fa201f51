// Range checks that throw idm::model::InputError in the project's one format:
// "WHERE.KEY: VALUE is out of range, allowed RANGE". Internal to drivers/.
#pragma once

#include <string>

namespace idm::drivers::detail {

// Throws unless ok and value is finite.
void check_range(bool ok, const std::string& where, const std::string& key, double value,
                 const char* range);

}  // namespace idm::drivers::detail
