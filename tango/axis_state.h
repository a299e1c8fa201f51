// How an idmd axis maps onto a Tango motor's State (ON, MOVING, FAULT, ALARM, DISABLE), the way
// Sardana and other Tango motor clients read it. Pure: no Tango, no socket.
#pragma once

#include <string>

#include "client/replies.h"

namespace idm::tango {

enum class AxisState { On, Moving, Fault, Alarm, Disable };

const char* axis_state_name(AxisState s);  // "ON", "MOVING", ...

// The state of an axis from its STATus? reply:
//   FAULT    the axis is in FAULT (stall, beam lost, device lost, ...)
//   MOVING   a motion runs (MOVE, STEP, SWEEP, settling), i.e. not done
//   DISABLE  at rest without a position to trust (no valid reading, device not up): nothing can
//            be moved until it is back
//   ALARM    at rest at a soft limit or at an end of travel
//   ON       at rest, ready
AxisState axis_state(const client::AxisStatus& s);

// One line for Tango's Status.
std::string axis_status_text(const client::AxisStatus& s, AxisState state);

}  // namespace idm::tango
