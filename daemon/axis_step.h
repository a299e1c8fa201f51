// One real-time cycle of one axis: what the device link reported goes into the positioner, and
// what the positioner wants of the output goes back to the link. The daemon's motion supervisor
// runs it for every axis each tick; tests and benchmarks run the same on the synthetic clock.
// Never blocks or allocates.
#pragma once

#include "control/positioner.h"
#include "drivers/link.h"
#include "model/axis_io.h"

namespace idm::daemon {

// A request the link's queue had no room for waits here for the next cycle (a stop is never
// dropped).
struct PendingRequest {
  bool due = false;
  model::OutputRequest request;
};

// `observe(event)` sees every event before the positioner does (the supervisor's bookkeeping:
// loss, reconnection, readings for the status).
template <typename Observe>
void step_axis(drivers::ChannelPort& port, control::Positioner& positioner, double now_s,
               PendingRequest& pending, Observe&& observe) {
  model::AxisEvent event;
  while (port.events.pop(event)) {
    observe(event);
    positioner.on_event(event);
  }
  if (pending.due) {
    if (!port.requests.push(pending.request)) return;
    pending.due = false;
  }
  model::OutputRequest request;
  if (positioner.tick(now_s, request) && !port.requests.push(request)) {
    pending.due = true;
    pending.request = request;
  }
}

inline void step_axis(drivers::ChannelPort& port, control::Positioner& positioner, double now_s,
                      PendingRequest& pending) {
  step_axis(port, positioner, now_s, pending, [](const model::AxisEvent&) {});
}

// The positioner's view of a link's channel (its capabilities as plain numbers).
inline control::AxisDeviceInfo axis_device_info(const drivers::OutputCapabilities& output,
                                                const drivers::InterferometerCapabilities& ifm) {
  control::AxisDeviceInfo d;
  d.count_m = ifm.word.count_m();
  d.max_velocity_m_s = ifm.word.max_velocity_m_s;
  d.stream_rate_hz = ifm.stream_rate_hz;
  d.stream_capacity = ifm.stream_capacity;
  d.buffered = output.mode == drivers::OutputMode::BufferedSamples;
  d.max_burst_samples = output.max_burst_samples;
  d.max_cycles = output.max_cycles;
  return d;
}

}  // namespace idm::daemon
