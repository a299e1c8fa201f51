// What a per-axis controller (control/) and the device link that plays its output and reads its
// interferometer (drivers/link.h) exchange. The controller never calls a driver: it takes these
// events in and hands output requests out, and the link (on a device's I/O thread, or inside the
// real-time loop for a device that never blocks) is the only code that touches the device. Both
// records are fixed size and trivially copyable: they cross lock-free queues.
#pragma once

#include <cstdint>

#include "model/waveform.h"

namespace idm::model {

// Link -> controller.
struct AxisEvent {
  enum class Kind : std::uint8_t {
    Reading,         // a position read from the device (latched at rest, or streamed in a burst)
    SegmentStarted,  // the output started playing segment `seq`
    SegmentDone,     // segment `seq` has played (and the device's own settling is over)
    OutputFailed,    // the device refused or failed segment `seq` (message: the link's health)
    DeviceLost,      // the device stopped answering; readings stop, the output is stopped
    DeviceBack,      // reconnected; count_kept says whether positions continue
  };
  Kind kind = Kind::Reading;
  // Reading: the decoder's sample-status bits (drivers/position_word.h); 0 is a valid reading.
  std::uint8_t status = 0;
  bool in_segment = false;  // Reading: streamed while a segment played
  bool overrun = false;     // Reading: the capture overflowed before this sample (not the beam)
  bool count_kept = true;   // DeviceBack: the device kept its position count through the loss
  // Reading: the word carried the reference mark (the slider crossed the scale's index mark
  // since the device's previous word; position_word.h bit 45).
  bool mark = false;
  std::uint32_t seq = 0;  // segment events: the request's sequence number
  double t_s = 0;         // the link's clock (monotonic seconds; the synthetic clock in tests)
  double position_m = 0;  // Reading: metres, meaningful when status == 0

  bool valid() const { return kind == Kind::Reading && status == 0; }
};

// Controller -> link.
struct OutputRequest {
  enum class Kind : std::uint8_t {
    Play,  // load and start `segment` (the previous one has ended)
    Stop,  // end any burst at once, output to zero (a fault, or a sweep trial stopped)
    Read,  // latch `readings` positions now (fresh readings after a segment), not at the next poll
  };
  Kind kind = Kind::Play;
  bool record = false;  // stream every sample of this segment to the capture queue (a sweep trial)
  std::uint32_t seq = 0;
  std::uint32_t readings = 0;  // Read: how many
  Segment segment;
};

}  // namespace idm::model
