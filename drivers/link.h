// The device link: the only code that calls a device's drivers while the daemon runs. One link
// owns one device (one card: one or more channels, each an output and an interferometer axis)
// and exchanges fixed-size records with the per-axis controllers through lock-free queues
// (model/axis_io.h): output requests in, position readings and segment events out, and for
// recorded segments (sweep trials) every streamed sample to a capture queue.
//
// It runs on its own I/O thread (start_thread), so that a device that blocks (a network or bus
// round trip, a timeout, a reconnect) never delays the real-time loop; tests and tools on the
// synthetic clock call service(now) themselves instead. Loss and recovery: a call that fails
// with no_device, disconnected, timeout or protocol_error marks the device lost at once (every
// channel gets DeviceLost, the output is stopped where the device still answers, the health says
// why); the link then reconnects by itself with exponential backoff and, once back, tells each
// channel whether the device kept its position count (Interferometer::count_epoch). When it did
// not, positions continue from the last good reading (offset) and count_kept is false.
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "drivers/interfaces.h"
#include "drivers/lockfree.h"
#include "drivers/position_word.h"
#include "drivers/thread.h"
#include "model/axis_io.h"

namespace idm::drivers {

struct LinkConfig {
  double poll_interval_s = 1e-3;   // each channel's position is latched this often at rest
  double io_period_s = 1e-4;       // the I/O thread's cycle
  std::uint32_t stream_every = 8;  // in a segment: every Nth streamed reading goes to the
                                   // controller (every invalid one, and the last, always)
  double reconnect_min_s = 0.05;   // first retry after a loss; doubles up to reconnect_max_s
  double reconnect_max_s = 2.0;
};

// Throws model::InputError naming the key and the allowed range.
void validate(const LinkConfig& config, const std::string& where);

enum class LinkState : std::uint8_t { Closed, Up, Lost };
const char* link_state_name(LinkState state);  // "closed", "up", "lost"

// Published by the link after every change (seqlock), read by any thread.
struct LinkHealth {
  LinkState state = LinkState::Closed;
  std::uint32_t losses = 0;            // times the device was lost
  std::uint32_t reconnects = 0;        // times it came back
  std::uint64_t readings_dropped = 0;  // readings the controller's queue had no room for
  std::uint64_t message_version = 0;   // +1 whenever `message` changes
  double since_s = 0;                  // when `state` last changed (the link's clock)
  char message[232] = {};              // the last driver error ("" none), NUL terminated
};

// One streamed sample of a recorded segment, for the recorder. t_s: seconds from the segment's
// first output sample on the device's clock. The record with `end` set closes the segment.
struct CaptureRecord {
  double t_s = 0;
  double position_m = 0;
  std::uint32_t seq = 0;
  std::uint8_t status = 0;  // sample_status bits; 0 valid
  bool end = false;         // the segment ended (done, stopped or failed)
  bool complete = false;    // end: it played in full and every sample was delivered
};

// A fault or a push for a simulated channel (the protocol's SIMulation: commands, for tests and
// hardware-in-the-loop work), applied by the link's own thread: the simulated device is driven
// from one thread only.
struct SimAction {
  enum class Kind : std::uint8_t {
    Push,        // value: metres the slider is displaced by at once
    BeamLost,    // value != 0: on
    Stalled,     // value != 0: the slider is held
    Glitches,    // value: probability per word (flagged glitches)
    Disconnect,  // a pulled cable: every call fails until Reconnect; the device keeps its count
    Reconnect,
    PowerCycle,  // disconnected, and back with a new count epoch (position from the start)
    Timeouts,    // value != 0: every read times out
  };
  Kind kind = Kind::Push;
  std::uint32_t channel = 0;
  double value = 0;
};

// One channel's queues: each has one producer and one consumer thread.
struct ChannelPort {
  SpscRing<model::OutputRequest, 16> requests;  // controller -> link
  SpscRing<model::AxisEvent, 8192> events;      // link -> controller
  SpscRing<CaptureRecord, 1u << 16> capture;    // link -> recorder (record = true segments)
  // controller -> link: a motion is under way (between its segments too), so the link keeps its
  // full rate; false: the controller is at rest and the link may idle (idle_until_s).
  std::atomic<bool> controller_active{false};
};

// Where a channel's count comes from: the device's count epoch (when it reports one: it changes
// when the device's count started over) and the counts the link adds to the device's after a
// reconnect that lost the count. A reference saved with it holds in a later run only while both
// are the same (daemon/reference_file.h).
struct CountOrigin {
  bool has_epoch = false;
  std::uint64_t epoch = 0;
  std::int64_t offset_counts = 0;
};

class DeviceLink {
 public:
  // `channels`: the device's channels (each an output and an interferometer sharing the
  // device's connection); none may be configured yet.
  DeviceLink(std::string name, std::vector<Device> channels, LinkConfig config);
  ~DeviceLink();
  DeviceLink(const DeviceLink&) = delete;
  DeviceLink& operator=(const DeviceLink&) = delete;

  // Caller's thread, before anything runs: configure and activate every channel (output at
  // zero), read the count epoch. The first failure is returned with the device's name in it.
  DriverStatus open();
  // One I/O cycle at `now_s` (the link's clock): requests, the playing segments, the stream, the
  // rest latches, loss and reconnection. The I/O thread calls it; so do tests on the synthetic
  // clock (never both).
  void service(double now_s);
  // The I/O thread: service(monotonic_s()) every io_period_s until stop_thread(); while the link
  // is idle (idle_until_s), not before there is something to do (a request or a simulated action
  // then waits one poll_interval_s at most).
  void start_thread();
  // I/O side: when the link has nothing to do before a later time (no segment playing, no request
  // or simulated action queued, no controller in a motion), that time: the next rest latch or
  // reconnection try, at most one poll_interval_s from now; else now_s.
  double idle_until_s(double now_s) const;
  void stop_thread();
  // Caller's thread, after stop_thread(): output to zero, deactivate, shut down. Idempotent.
  void close();

  const std::string& name() const { return name_; }
  std::size_t channel_count() const;
  ChannelPort& port(std::size_t channel);
  // The channel's device: before open() and after close(), or from the I/O thread.
  Device& device(std::size_t channel);
  const OutputCapabilities& output_capabilities(std::size_t channel) const;
  const InterferometerCapabilities& interferometer_capabilities(std::size_t channel) const;
  LinkHealth health() const { return health_.load(); }
  // Any thread: the channel's count origin as the I/O side last set it (at open and reconnect).
  CountOrigin count_origin(std::size_t channel) const;
  // After open(), before start_thread(): the count goes on from an earlier run's (its
  // offset_counts), when the device kept counting meanwhile (the same epoch).
  void continue_count(std::size_t channel, std::int64_t offset_counts);
  // Queues a simulated fault or push (any one thread); false when the channel is not simulated or
  // the queue is full. The link's thread applies it at its next cycle.
  bool inject(const SimAction& action);
  bool simulated(std::size_t channel) const;
  bool thread_running() const { return thread_.joinable(); }

 private:
  struct Channel;
  void service_channel(Channel& c, double now_s);
  void apply_sim_actions();
  void start_segment(Channel& c, const model::OutputRequest& r, double now_s);
  void drain_stream(Channel& c, double now_s, bool final);
  void end_segment(Channel& c, double now_s, model::AxisEvent::Kind kind, bool complete);
  void latch(Channel& c, double now_s);
  // A failed call: true when it means the device is lost (then the loss is handled).
  bool failed(const DriverStatus& s, double now_s);
  void lose(double now_s);
  void try_reconnect(double now_s);
  void push_event(Channel& c, const model::AxisEvent& e, bool droppable);
  void set_message(const std::string& text);
  void publish();

  std::string name_;
  LinkConfig config_;
  std::vector<Channel> channels_;
  SpscRing<SimAction, 16> sim_actions_;
  LinkHealth state_;  // the I/O side's copy
  Seqlock<LinkHealth> health_;
  double next_retry_s_ = 0;
  double backoff_s_ = 0;
  bool opened_ = false;
  std::atomic<bool> quit_{false};
  StackThread thread_;
};

}  // namespace idm::drivers
