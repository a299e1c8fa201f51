#include "daemon/supervisor.h"

#include <chrono>
#include <cmath>
#include <limits>
#include <thread>

#include "drivers/clock.h"

namespace idm::daemon {

MotionSupervisor::MotionSupervisor(std::vector<Axis*> axes) : axes_(std::move(axes)) {}

MotionSupervisor::Ack MotionSupervisor::submit(AxisCommand command, const RtLoop& loop) {
  Ack ack;
  if (!loop.running()) return ack;
  command.seq = ++next_seq_;
  const double deadline = drivers::monotonic_s() + 5.0;
  while (!commands_.push(command)) {
    if (drivers::monotonic_s() > deadline || !loop.running()) return ack;
    std::this_thread::sleep_for(std::chrono::microseconds(100));
  }
  while (acked_seq_.load(std::memory_order_acquire) < command.seq) {
    if (drivers::monotonic_s() > deadline || !loop.running()) return ack;
    std::this_thread::sleep_for(std::chrono::microseconds(20));
  }
  ack.taken = true;
  ack.refusal = static_cast<control::Refusal>(acked_refusal_.load(std::memory_order_relaxed));
  ack.target_m = acked_target_m_.load(std::memory_order_relaxed);
  return ack;
}

bool MotionSupervisor::at_rest() const {
  if (!trials_.empty() || trial_held_) return false;
  for (const Axis* a : axes_) {
    const AxisPublished p = a->published();
    const bool rest = p.motion.state == control::MotionState::Idle ||
                      p.motion.state == control::MotionState::Fault || p.motion.holding;
    if (!rest || p.trial_active) return false;
  }
  return true;
}

// ---- the loop: no allocation, no lock, no log ----

void MotionSupervisor::tick(double now_s) {
  const bool stopping = stop_all_.load(std::memory_order_acquire);
  const auto park_mode = static_cast<Park>(park_request_.load(std::memory_order_acquire));
  const bool park = park_mode != Park::None;
  if (!park && parked_.load(std::memory_order_relaxed))
    parked_.store(false, std::memory_order_release);
  // Parked: the main thread is swapping the axes' positioners. The loop touches no axis (commands
  // wait in their queue, readings in the links') until it is let go.
  if (park && parked_.load(std::memory_order_relaxed)) return;
  // The server waits for one command at a time: at most one is applied per tick, and acknowledged
  // after the status that reflects it is published (MOVE:DONE? right after MOVE sees the motion).
  AxisCommand cmd;
  std::uint64_t ack = 0;
  if (commands_.pop(cmd)) {
    if ((stopping || park) && cmd.motion()) {
      acked_refusal_.store(
          static_cast<std::uint8_t>(park_mode == Park::Wait ? control::Refusal::Reloading
                                                            : control::Refusal::Busy),
          std::memory_order_relaxed);
      acked_target_m_.store(std::numeric_limits<double>::quiet_NaN(), std::memory_order_relaxed);
    } else {
      apply(cmd);
    }
    ack = cmd.seq;
  }
  if (stopping || park_mode == Park::Stop)
    for (Axis* a : axes_) a->stop(notices_);
  // A sweep's next trial (the recorder sends it when it has the last one's samples; the loop may
  // not have seen that segment's end yet: then it waits here).
  if (!trial_held_ && trials_.pop(held_trial_)) trial_held_ = true;
  if (trial_held_) {
    const bool axis_ok =
        held_trial_.axis >= 0 && static_cast<std::size_t>(held_trial_.axis) < axes_.size();
    if (stopping || park_mode == Park::Stop || !axis_ok) {
      TrialNotice n;
      n.kind = TrialNotice::Kind::Failed;
      n.index = held_trial_.index;
      n.seq = held_trial_.seq;
      n.why = axis_ok ? TrialFailure::Stopped : TrialFailure::Busy;
      notices_.push(n);
      trial_held_ = false;
    } else if (!axes_[static_cast<std::size_t>(held_trial_.axis)]->trial_finishing()) {
      axes_[static_cast<std::size_t>(held_trial_.axis)]->start_trial(held_trial_, notices_);
      trial_held_ = false;
    }
  }
  for (Axis* a : axes_) a->tick(now_s, notices_);
  bool rest = true, quiet = true;
  for (Axis* a : axes_) {
    rest = rest && a->at_rest();
    const bool q = a->quiet();
    quiet = quiet && q;
    a->port().controller_active.store(!q, std::memory_order_relaxed);
  }
  resting_ = quiet && ack == 0 && !stopping && !park && !trial_held_;
  const bool now_parked = park && rest;
  for (Axis* a : axes_) a->publish(now_parked);
  if (now_parked && !parked_.load(std::memory_order_relaxed))
    parked_.store(true, std::memory_order_release);
  if (ack != 0) acked_seq_.store(ack, std::memory_order_release);
}

void MotionSupervisor::apply(const AxisCommand& c) {
  control::Refusal r = control::Refusal::None;
  double target = std::numeric_limits<double>::quiet_NaN();
  if (c.axis < 0) {
    for (Axis* a : axes_) a->stop(notices_);
  } else if (static_cast<std::size_t>(c.axis) < axes_.size()) {
    Axis& a = *axes_[static_cast<std::size_t>(c.axis)];
    if (c.is<axis_command::Stop>()) {
      a.stop(notices_);
    } else {
      r = a.apply(c);
      if (c.motion() && !c.is<axis_command::Reference>()) target = a.requested_target_m();
    }
  }
  acked_target_m_.store(target, std::memory_order_relaxed);
  acked_refusal_.store(static_cast<std::uint8_t>(r), std::memory_order_relaxed);
}

}  // namespace idm::daemon
