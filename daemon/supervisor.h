// The motion supervisor: the real-time loop's body. Each tick it applies at most one command from
// the command link, steps every axis (the device links' events in, the positioners' requests
// out), starts the sweep trials the recorder asks for, and publishes every axis's status. It
// never calls a driver, allocates, locks or logs; the other threads reach it only through the
// lock-free queues and atomics below.
//
//   server thread   --commands (SPSC)-->  loop  --ack (seq, refusal, target)--> server thread
//   recorder thread --trials (SPSC)---->  loop  --notices (SPSC)-------------> recorder thread
//   any thread      <--AxisPublished (seqlock per axis)--  loop
//   main/housekeeping: park() / unpark() to swap an axis's positioner at rest
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <vector>

#include "daemon/axis.h"
#include "daemon/rt_loop.h"

namespace idm::daemon {

class MotionSupervisor final : public LoopBody {
 public:
  explicit MotionSupervisor(std::vector<Axis*> axes);

  // ---- the server thread (one producer) ----
  // Queues the command and waits (bounded, 5 s) for `loop` to apply it.
  struct Ack {
    bool taken = false;
    control::Refusal refusal = control::Refusal::None;
    double target_m = 0;  // the command's target as the axis computed it (NaN: none)
  };
  Ack submit(AxisCommand command, const RtLoop& loop);

  // ---- the recorder thread ----
  bool send_trial(const TrialRequest& trial) { return trials_.push(trial); }
  bool next_notice(TrialNotice& out) { return notices_.pop(out); }

  // ---- any thread ----
  void request_stop_all() { stop_all_.store(true, std::memory_order_release); }
  bool stopping() const { return stop_all_.load(std::memory_order_acquire); }
  // Ask the loop to hold every axis at rest (parked() once it is), then let it go (None). Stop:
  // every motion is stopped at its chunk's end (a *RST, which stops motion by definition). Wait:
  // nothing is stopped; the loop parks once every motion in progress has ended, and refuses new
  // ones meanwhile (Refusal::Reloading), so that a reload never cuts another client's move short.
  enum class Park : std::uint8_t { None, Stop, Wait };
  void request_park(Park park) {
    park_request_.store(static_cast<std::uint8_t>(park), std::memory_order_release);
  }
  bool parked() const { return parked_.load(std::memory_order_acquire); }
  // Every axis at rest and no trial pending (the loop's last publication).
  bool at_rest() const;

  // ---- the loop ----
  void tick(double now_s) override;
  // After a tick: every axis quiet, nothing commanded or held, no stop or park under way.
  bool resting() const override { return resting_; }

 private:
  void apply(const AxisCommand& command);

  std::vector<Axis*> axes_;
  SpscRing<AxisCommand, 64> commands_;
  std::uint64_t next_seq_ = 0;  // server thread
  std::atomic<std::uint64_t> acked_seq_{0};
  std::atomic<std::uint8_t> acked_refusal_{0};
  std::atomic<double> acked_target_m_{0};
  SpscRing<TrialRequest, 8> trials_;
  // A trial taken from the ring whose axis is still finishing the trial before (its segment's end
  // not yet seen by the loop): started once it has.
  std::atomic<bool> trial_held_{false};  // read by at_rest() on other threads
  TrialRequest held_trial_{};
  TrialNotices notices_;
  std::atomic<bool> stop_all_{false};
  std::atomic<std::uint8_t> park_request_{0};  // Park
  std::atomic<bool> parked_{false};
  bool resting_ = false;  // the loop thread's
};

}  // namespace idm::daemon
