// What the session's handlers share (session.cpp, session_axis.cpp): the untrusted-position
// reply and the errors handlers pass on. Internal to daemon/'s protocol library.
#pragma once

#include <string>

#include "daemon/protocol.h"

namespace idm::daemon::session_replies {

constexpr char kUntrusted[] = "9.91E37";  // SCPI's not-a-number: a position that cannot be trusted

// An error from the instrument as the session reports it.
inline CommandError instrument_error(CommandError e) {
  if (e.ok()) return e;
  return make_error(e.code, e.text);
}

inline CommandError untrusted_position(const std::string& name) {
  return make_error(
      error_code::kDataCorruptOrStale,
      "axis " + name + ": no trustworthy position (no valid reading yet, beam or device lost)");
}

}  // namespace idm::daemon::session_replies
