#include "tango/axis_state.h"

#include <cmath>
#include <cstdio>

namespace idm::tango {

const char* axis_state_name(AxisState s) {
  switch (s) {
    case AxisState::On:
      return "ON";
    case AxisState::Moving:
      return "MOVING";
    case AxisState::Fault:
      return "FAULT";
    case AxisState::Alarm:
      return "ALARM";
    case AxisState::Disable:
      return "DISABLE";
  }
  return "UNKNOWN";
}

AxisState axis_state(const client::AxisStatus& s) {
  if (s.state == "FAULT") return AxisState::Fault;
  if (!s.done || s.state == "MOVING" || s.state == "SETTLING") return AxisState::Moving;
  if (!s.position_valid || s.device != "up") return AxisState::Disable;
  if (!s.eot.empty()) return AxisState::Alarm;
  if (std::isfinite(s.lower_m) && s.position_m <= s.lower_m) return AxisState::Alarm;
  if (std::isfinite(s.upper_m) && s.position_m >= s.upper_m) return AxisState::Alarm;
  return AxisState::On;
}

std::string axis_status_text(const client::AxisStatus& s, AxisState state) {
  char position[64] = "not valid";
  if (s.position_valid) std::snprintf(position, sizeof position, "%.6f um", s.position_m * 1e6);
  std::string text = "axis " + s.name + ": " + axis_state_name(state) + " (idmd " + s.state +
                     "), position " + position;
  if (s.fault != "none") text += ", fault " + s.fault;
  if (!s.eot.empty()) text += ", end of travel " + s.eot;
  if (s.device != "up") text += ", device " + s.device;
  if (state == AxisState::Alarm && s.eot.empty()) text += ", at a soft limit";
  if (!s.daemon_error.empty() && s.daemon_error != "none") text += ", last error " + s.daemon_error;
  return text;
}

}  // namespace idm::tango
