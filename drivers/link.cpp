#include "drivers/link.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

#include "drivers/clock.h"
#include "drivers/sim/sim_backend.h"
#include "drivers/thread.h"
#include "model/stage.h"
#include "model/yaml_util.h"

namespace idm::drivers {

namespace {

constexpr std::size_t kStreamSlice = 4096;
constexpr std::size_t kMaxSampleBuffer = std::size_t{1} << 21;
// Readings may be dropped when the controller's queue is this full; segment and device events
// always find room.
constexpr std::size_t kEventHeadroom = 64;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

using Kind = model::AxisEvent::Kind;

bool means_lost(DriverError e) {
  return e == DriverError::NoDevice || e == DriverError::Disconnected ||
         e == DriverError::Timeout || e == DriverError::ProtocolError;
}

}  // namespace

void validate(const LinkConfig& c, const std::string& where) {
  const auto fail = [&](const char* key, double v, const char* range) {
    throw model::InputError(where + "." + key + ": " + model::format_number(v) +
                            " is out of range, allowed " + range);
  };
  if (!(c.poll_interval_s >= 1e-5 && c.poll_interval_s <= 10))
    fail("poll_interval_s", c.poll_interval_s, "[1e-05, 10]");
  if (!(c.io_period_s >= 1e-6 && c.io_period_s <= 0.1))
    fail("io_period_s", c.io_period_s, "[1e-06, 0.1]");
  if (c.stream_every < 1 || c.stream_every > 1000000)
    fail("stream_every", c.stream_every, "[1, 1e6]");
  if (!(c.reconnect_min_s >= 1e-3 && c.reconnect_min_s <= 60))
    fail("reconnect_min_s", c.reconnect_min_s, "[0.001, 60]");
  if (!(c.reconnect_max_s >= c.reconnect_min_s && c.reconnect_max_s <= 3600))
    fail("reconnect_max_s", c.reconnect_max_s, "[reconnect_min_s, 3600]");
}

const char* link_state_name(LinkState s) {
  switch (s) {
    case LinkState::Closed:
      return "closed";
    case LinkState::Up:
      return "up";
    case LinkState::Lost:
      return "lost";
  }
  return "?";
}

struct DeviceLink::Channel {
  Device device;
  std::unique_ptr<ChannelPort> port = std::make_unique<ChannelPort>();
  std::unique_ptr<PositionDecoder> latch_decoder, stream_decoder;
  std::vector<double> samples;    // a clocked segment's samples (sized at open)
  std::vector<TimedWord> stream;  // a slice of the stream
  bool playing = false;
  model::OutputRequest request;  // the segment playing
  double segment_start_s = 0;    // when it was started (the link's clock)
  std::uint32_t streamed = 0;    // readings of the segment so far
  bool capture_lost = false;     // a capture record found no room
  double next_poll_s = 0;
  bool has_epoch = false;
  std::uint64_t epoch = 0;
  std::int64_t offset_counts = 0;  // added to the device's count (after a lost count)
  std::int64_t last_count = 0;     // the last valid reading's count, offset included
  bool has_count = false;
  std::unique_ptr<Seqlock<CountOrigin>> origin = std::make_unique<Seqlock<CountOrigin>>();
  void publish_origin() const { origin->store({has_epoch, epoch, offset_counts}); }
};

DeviceLink::DeviceLink(std::string name, std::vector<Device> devices, LinkConfig config)
    : name_(std::move(name)), config_(config) {
  validate(config_, "link");
  channels_.reserve(devices.size());
  for (Device& d : devices) {
    Channel c;
    c.device = std::move(d);
    channels_.push_back(std::move(c));
  }
}

DeviceLink::~DeviceLink() {
  stop_thread();
  close();
}

std::size_t DeviceLink::channel_count() const {
  return channels_.size();
}

ChannelPort& DeviceLink::port(std::size_t ch) {
  return *channels_.at(ch).port;
}

Device& DeviceLink::device(std::size_t ch) {
  return channels_.at(ch).device;
}

const OutputCapabilities& DeviceLink::output_capabilities(std::size_t ch) const {
  return channels_.at(ch).device.output->capabilities();
}

const InterferometerCapabilities& DeviceLink::interferometer_capabilities(std::size_t ch) const {
  return channels_.at(ch).device.interferometer->capabilities();
}

CountOrigin DeviceLink::count_origin(std::size_t ch) const {
  return channels_.at(ch).origin->load();
}

void DeviceLink::continue_count(std::size_t ch, std::int64_t offset_counts) {
  Channel& c = channels_.at(ch);
  c.offset_counts = offset_counts;
  c.publish_origin();
}

DriverStatus DeviceLink::open() {
  for (Channel& c : channels_) {
    if (DriverStatus s = c.device.configure(); !s.ok()) {
      close();
      return DriverStatus::failure(
          s.error, "cannot open the " + c.device.driver + " device " + name_ + ": " + s.message);
    }
    if (DriverStatus s = c.device.activate(); !s.ok()) {
      close();
      return DriverStatus::failure(s.error, "cannot activate the " + c.device.driver + " device " +
                                                name_ + ": " + s.message);
    }
    const InterferometerCapabilities& ic = c.device.interferometer->capabilities();
    // Latches at rest come every poll_interval_s: the jump check allows the slider that long.
    PositionWordConfig latch_word = ic.word;
    latch_word.sample_interval_s = config_.poll_interval_s;
    c.latch_decoder = std::make_unique<PositionDecoder>(latch_word);
    c.stream_decoder = std::make_unique<PositionDecoder>(ic.word);
    const OutputCapabilities& oc = c.device.output->capabilities();
    if (oc.mode == OutputMode::BufferedSamples)
      c.samples.assign(std::min(oc.max_burst_samples, kMaxSampleBuffer), 0.0);
    c.stream.assign(kStreamSlice, TimedWord{});
    std::uint64_t epoch = 0;
    c.has_epoch = c.device.interferometer->count_epoch(epoch).ok();
    c.epoch = epoch;
    c.publish_origin();
  }
  opened_ = true;
  state_ = LinkHealth{};
  state_.state = LinkState::Up;
  publish();
  return DriverStatus::success();
}

void DeviceLink::close() {
  if (!opened_) return;
  opened_ = false;
  for (Channel& c : channels_) {
    c.device.output->stop();
    c.device.deactivate();
    c.device.shutdown();
  }
  state_.state = LinkState::Closed;
  publish();
}

void DeviceLink::start_thread() {
  if (thread_.joinable()) return;
  quit_.store(false);
  thread_ = StackThread("idmd-io-" + name_, kIoStackBytes, [this] {
    const double period = config_.io_period_s;
    double next = monotonic_s();
    while (!quit_.load(std::memory_order_acquire)) {
      service(monotonic_s());
      next += period;
      const double now = monotonic_s();
      if (next < now) next = now;  // behind (a slow device): no catching up in a burst
      next = std::max(next, idle_until_s(now));
      sleep_until_s(next);
    }
  });
}

void DeviceLink::stop_thread() {
  quit_.store(true, std::memory_order_release);
  if (thread_.joinable()) thread_.join();
}

// ---- the I/O cycle ----

double DeviceLink::idle_until_s(double now_s) const {
  if (!opened_ || !sim_actions_.empty()) return now_s;
  double until = now_s + config_.poll_interval_s;
  if (state_.state == LinkState::Lost) return std::max(now_s, std::min(until, next_retry_s_));
  for (const Channel& c : channels_) {
    if (c.playing || c.port->controller_active.load(std::memory_order_relaxed) ||
        !c.port->requests.empty())
      return now_s;
    until = std::min(until, c.next_poll_s);
  }
  return std::max(now_s, until);  // a latch already due: now
}

bool DeviceLink::simulated(std::size_t ch) const {
  return ch < channels_.size() && channels_[ch].device.sim != nullptr;
}

bool DeviceLink::inject(const SimAction& a) {
  if (!simulated(a.channel)) return false;
  return sim_actions_.push(a);
}

void DeviceLink::apply_sim_actions() {
  SimAction a;
  while (sim_actions_.pop(a)) {
    sim::SimBackend& sim = *channels_[a.channel].device.sim;
    using K = SimAction::Kind;
    switch (a.kind) {
      case K::Push:
        sim.push(a.value);
        break;
      case K::BeamLost:
        sim.set_beam_lost(a.value != 0);
        break;
      case K::Stalled:
        sim.set_slider_stalled(a.value != 0);
        break;
      case K::Glitches:
        sim.set_glitch_probability(std::clamp(a.value, 0.0, 1.0), true);
        break;
      case K::Disconnect:
        sim.disconnect();
        break;
      case K::Reconnect:
        sim.reconnect();
        break;
      case K::PowerCycle:
        sim.power_cycle();
        break;
      case K::Timeouts:
        sim.set_timeouts(a.value != 0);
        break;
    }
  }
}

void DeviceLink::service(double now_s) {
  if (!opened_) return;
  apply_sim_actions();
  if (state_.state == LinkState::Lost) {
    // Requests that arrive while the device is away fail at once (nothing is queued up to play
    // later, when nobody expects it).
    for (Channel& c : channels_) {
      model::OutputRequest r;
      while (c.port->requests.pop(r)) {
        if (r.kind != model::OutputRequest::Kind::Play) continue;
        model::AxisEvent e;
        e.kind = Kind::OutputFailed;
        e.seq = r.seq;
        e.t_s = now_s;
        push_event(c, e, false);
      }
    }
    if (now_s >= next_retry_s_) try_reconnect(now_s);
    return;
  }
  for (Channel& c : channels_) {
    service_channel(c, now_s);
    if (state_.state == LinkState::Lost) return;  // the loss ended this cycle
  }
}

void DeviceLink::service_channel(Channel& c, double now_s) {
  model::OutputRequest r;
  while (c.port->requests.pop(r)) {
    if (r.kind == model::OutputRequest::Kind::Read) {
      for (std::uint32_t i = 0; i < r.readings && state_.state != LinkState::Lost; ++i)
        latch(c, now_s);
      if (state_.state == LinkState::Lost) return;
      c.next_poll_s = now_s + config_.poll_interval_s;
    } else if (r.kind == model::OutputRequest::Kind::Stop) {
      const DriverStatus s = c.device.output->stop();
      if (c.playing) end_segment(c, now_s, Kind::SegmentDone, false);
      if (!s.ok() && failed(s, now_s)) return;
    } else {
      if (c.playing) {  // a new segment ends the old one (the controller never does this)
        c.device.output->stop();
        end_segment(c, now_s, Kind::SegmentDone, false);
      }
      start_segment(c, r, now_s);
      if (state_.state == LinkState::Lost) return;
    }
  }
  if (c.playing) {
    drain_stream(c, now_s, false);
    if (!c.playing || state_.state == LinkState::Lost) return;
    bool done = false;
    const DriverStatus s = c.device.output->is_done(done);
    if (!s.ok()) {
      if (!failed(s, now_s)) end_segment(c, now_s, Kind::OutputFailed, false);
      return;
    }
    if (!done) return;
    drain_stream(c, now_s, true);
    if (c.playing) end_segment(c, now_s, Kind::SegmentDone, !c.capture_lost);
    c.next_poll_s = now_s;  // a reading at rest right after the segment
  }
  if (now_s >= c.next_poll_s) {
    c.next_poll_s = now_s + config_.poll_interval_s;
    latch(c, now_s);
  }
}

void DeviceLink::start_segment(Channel& c, const model::OutputRequest& r, double now_s) {
  const model::Segment& seg = r.segment;
  DriverStatus s;
  if (seg.clocked()) {
    const std::size_t n = seg.sample_count();
    if (seg.period_samples < 2 || seg.extension_samples < 1 ||
        seg.extension_samples >= seg.period_samples || n > c.samples.size()) {
      s = DriverStatus::failure(DriverError::InvalidArgument,
                                "a segment of " + std::to_string(n) +
                                    " samples does not fit the output buffer of " +
                                    std::to_string(c.samples.size()));
    } else {
      model::fill_samples(seg, c.samples.data());
      s = c.device.output->write_burst(c.samples.data(), n, seg.sample_rate_hz);
    }
  } else {
    s = c.device.output->write_burst_parameters(seg.wave());
  }
  if (s.ok()) s = c.device.output->start();
  model::AxisEvent e;
  e.seq = r.seq;
  e.t_s = now_s;
  if (!s.ok()) {
    if (failed(s, now_s)) return;
    e.kind = Kind::OutputFailed;
    push_event(c, e, false);
    if (r.record) {
      CaptureRecord end;
      end.seq = r.seq;
      end.end = true;
      c.port->capture.push(end);
    }
    return;
  }
  c.playing = true;
  c.request = r;
  c.segment_start_s = now_s;
  c.streamed = 0;
  c.capture_lost = false;
  c.stream_decoder->continue_from(*c.latch_decoder);
  e.kind = Kind::SegmentStarted;
  push_event(c, e, false);
}

void DeviceLink::drain_stream(Channel& c, double now_s, bool final) {
  for (;;) {
    std::size_t n = 0;
    const DriverStatus s =
        c.device.interferometer->read_stream(c.stream.data(), c.stream.size(), n);
    for (std::size_t i = 0; i < n; ++i) {
      const PositionSample p = c.stream_decoder->decode(c.stream[i].word);
      const double position =
          p.valid() ? p.position_m + c.offset_counts * c.stream_decoder->count_m() : kNaN;
      if (c.request.record) {
        CaptureRecord rec;
        rec.t_s = c.stream[i].t_s;
        rec.position_m = position;
        rec.seq = c.request.seq;
        rec.status = p.status;
        if (!c.port->capture.push(rec)) c.capture_lost = true;
      }
      ++c.streamed;
      const bool last = final && i + 1 == n && n < c.stream.size();
      // A reading with the reference mark is never thinned out nor dropped: the controller
      // looks for it.
      if (!p.valid() || p.mark || last || c.streamed % config_.stream_every == 0) {
        model::AxisEvent e;
        e.kind = Kind::Reading;
        e.in_segment = true;
        e.status = p.status;
        e.overrun = (p.status & sample_status::kSampleOverrun) != 0;
        e.mark = p.mark;
        e.position_m = position;
        e.t_s = std::min(now_s, c.segment_start_s + c.stream[i].t_s);
        e.seq = c.request.seq;
        push_event(c, e, p.valid() && !p.mark);
      }
    }
    if (!s.ok()) {
      if (!failed(s, now_s)) end_segment(c, now_s, Kind::OutputFailed, false);
      return;
    }
    if (n < c.stream.size()) return;
  }
}

void DeviceLink::end_segment(Channel& c, double now_s, Kind kind, bool complete) {
  c.playing = false;
  if (c.stream_decoder->has_reference() && !c.stream_decoder->continuity_lost())
    c.latch_decoder->continue_from(*c.stream_decoder);  // the rest latches go on from the burst
  model::AxisEvent e;
  e.kind = kind;
  e.seq = c.request.seq;
  e.t_s = now_s;
  push_event(c, e, false);
  if (c.request.record) {
    CaptureRecord end;
    end.seq = c.request.seq;
    end.end = true;
    end.complete = complete && kind == Kind::SegmentDone;
    c.port->capture.push(end);  // the recorder drains continuously; a full ring loses the mark
  }
}

void DeviceLink::latch(Channel& c, double now_s) {
  std::uint64_t word = 0;
  const DriverStatus s = c.device.interferometer->latch(word);
  if (!s.ok()) {
    if (!failed(s, now_s)) {
      model::AxisEvent e;  // a reading that failed: not valid, and says so
      e.kind = Kind::Reading;
      e.status = sample_status::kNotValid;
      e.position_m = kNaN;
      e.t_s = now_s;
      push_event(c, e, false);
    }
    return;
  }
  // Consecutive latches are checked against each other (a wild count is a glitch, flagged or
  // not); after a loss of continuity the next valid word is taken as the board's count again.
  const PositionSample p = c.latch_decoder->decode(word);
  if ((p.status & (sample_status::kContinuityLost | sample_status::kMeasurementSignalLost |
                   sample_status::kReferenceSignalLost)) != 0)
    c.latch_decoder->reset();
  model::AxisEvent e;
  e.kind = Kind::Reading;
  e.status = p.status;
  e.mark = p.mark;
  e.t_s = now_s;
  if (p.valid()) {
    const std::int64_t count = p.count + c.offset_counts;
    e.position_m = static_cast<double>(count) * c.latch_decoder->count_m();
    c.last_count = count;
    c.has_count = true;
  } else {
    e.position_m = kNaN;
  }
  push_event(c, e, p.valid() && !p.mark);
}

// ---- loss and reconnection ----

bool DeviceLink::failed(const DriverStatus& s, double now_s) {
  set_message(s.message);
  if (!means_lost(s.error)) {
    publish();
    return false;
  }
  lose(now_s);
  return true;
}

void DeviceLink::lose(double now_s) {
  state_.state = LinkState::Lost;
  state_.since_s = now_s;
  ++state_.losses;
  backoff_s_ = config_.reconnect_min_s;
  next_retry_s_ = now_s + backoff_s_;
  for (Channel& c : channels_) {
    model::AxisEvent e;  // first: the segment's end below is a consequence, not the cause
    e.kind = Kind::DeviceLost;
    e.t_s = now_s;
    push_event(c, e, false);
    c.device.output->stop();  // output to zero where the device still answers
    if (c.playing) end_segment(c, now_s, Kind::OutputFailed, false);
  }
  publish();
}

void DeviceLink::try_reconnect(double now_s) {
  for (Channel& c : channels_) c.device.cleanup();
  for (Channel& c : channels_) {
    DriverStatus s = c.device.configure();
    if (s.ok()) s = c.device.activate();
    if (!s.ok()) {
      set_message(s.message);
      backoff_s_ = std::min(2 * backoff_s_, config_.reconnect_max_s);
      next_retry_s_ = now_s + backoff_s_;
      publish();
      return;
    }
  }
  for (Channel& c : channels_) {
    std::uint64_t epoch = 0;
    const bool has_epoch = c.device.interferometer->count_epoch(epoch).ok();
    const bool kept = has_epoch && c.has_epoch && epoch == c.epoch;
    c.has_epoch = has_epoch;
    c.epoch = epoch;
    c.latch_decoder->reset();
    if (!kept && c.has_count) {
      // Continue from the last good reading: the device's new count is re-based onto it.
      std::uint64_t word = 0;
      if (c.device.interferometer->latch(word).ok()) {
        const PositionSample p = c.latch_decoder->decode(word);
        if (p.valid()) c.offset_counts = c.last_count - p.count;
        c.latch_decoder->reset();
      }
    }
    c.publish_origin();
    model::AxisEvent e;
    e.kind = Kind::DeviceBack;
    e.count_kept = kept;
    e.t_s = now_s;
    push_event(c, e, false);
    c.next_poll_s = now_s;
  }
  state_.state = LinkState::Up;
  state_.since_s = now_s;
  ++state_.reconnects;
  publish();
}

// ---- bookkeeping ----

void DeviceLink::push_event(Channel& c, const model::AxisEvent& e, bool droppable) {
  auto& q = c.port->events;
  if (droppable && q.size() + kEventHeadroom >= q.capacity()) {
    ++state_.readings_dropped;
    return;
  }
  if (!q.push(e)) ++state_.readings_dropped;
}

void DeviceLink::set_message(const std::string& text) {
  const std::size_t n = std::min(text.size(), sizeof state_.message - 1);
  if (std::strncmp(state_.message, text.c_str(), sizeof state_.message) == 0) return;
  std::memcpy(state_.message, text.data(), n);
  state_.message[n] = '\0';
  ++state_.message_version;
}

void DeviceLink::publish() {
  health_.store(state_);
}

}  // namespace idm::drivers
