// The real-time loop: one thread that wakes every period on absolute deadlines
// (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME)), calls LoopBody::tick(now), and keeps its
// wake-up latency (min / avg / max, a histogram) and deadline misses, as cyclictest does.
//
// Real-time setup is attempted in the thread before the first deadline: mlockall, CPU affinity,
// SCHED_FIFO. What is not permitted is collected into one warning that says why (CAP_SYS_NICE,
// RLIMIT_RTPRIO, RLIMIT_MEMLOCK, CAP_IPC_LOCK) and the loop carries on without it.
//
// Inside the loop: no allocation, no lock, no log. Statistics go out through a seqlock, the tick
// counter through an atomic.
#pragma once

#include <atomic>
#include <cstdint>
#include <string>
#include <thread>

#include "daemon/config.h"
#include "daemon/instrument.h"
#include "drivers/lockfree.h"
#include "drivers/thread.h"

namespace idm::daemon {

using drivers::kLoopStackBytes;
using drivers::kRecorderStackBytes;
using drivers::kServerStackBytes;
using drivers::kSmallStackBytes;
using drivers::Seqlock;
using drivers::SpscRing;
using drivers::StackThread;

class LoopBody {
 public:
  virtual ~LoopBody() = default;
  // Called once per period on the loop thread; now_s on CLOCK_MONOTONIC. Must not block,
  // allocate, lock or log.
  virtual void tick(double now_s) = 0;
  // After a tick: nothing needs the next one sooner than the rest period (RealtimeConfig::
  // rest_period_s). Bodies that never rest keep the default.
  virtual bool resting() const { return false; }
};

// Called on the loop thread with true right before the first tick and false right after the last
// one (tests use it to count allocations made on that thread only).
using LoopThreadHook = void (*)(bool entering);

class RtLoop {
 public:
  RtLoop(const RealtimeConfig& config, LoopBody& body);
  ~RtLoop();
  RtLoop(const RtLoop&) = delete;
  RtLoop& operator=(const RtLoop&) = delete;

  // Starts the thread and waits until its real-time setup is done. Returns "" or the one warning
  // about what could not be set up (the caller logs it; the loop runs anyway).
  std::string start();
  // Asks the loop to end after its current tick and joins it. Idempotent.
  void stop();
  bool running() const { return running_.load(std::memory_order_acquire); }

  // Ticks so far (the watchdog checks that it advances).
  std::uint64_t ticks() const { return ticks_.load(std::memory_order_acquire); }
  LoopStats stats() const { return stats_.load(); }
  void set_thread_hook(LoopThreadHook hook) { hook_ = hook; }

 private:
  void run();
  std::string setup_realtime();
  void publish_stats();

  RealtimeConfig config_;
  LoopBody& body_;
  LoopThreadHook hook_ = nullptr;
  StackThread thread_;
  std::atomic<bool> stop_{false};
  std::atomic<bool> running_{false};
  std::atomic<int> setup_done_{0};
  std::string setup_warning_;  // written by the thread before setup_done_, read after
  std::atomic<std::uint64_t> ticks_{0};

  // Loop-thread statistics (published through stats_).
  LoopStats local_;
  double latency_sum_s_ = 0;
  Seqlock<LoopStats> stats_;
};

// Tells when the loop misses too many deadlines (housekeeping asks it every cycle with the loop's
// published statistics): more than `max_fraction` of the deadlines of a window of `window_s`
// missed gives a warning saying the rate and what to do, at most one every `interval_s`. Not
// thread-safe (one caller); no clock of its own (the caller's now_s).
class DeadlineMissWatch {
 public:
  explicit DeadlineMissWatch(double max_fraction = 0.01, double window_s = 10,
                             double interval_s = 60)
      : max_fraction_(max_fraction), window_s_(window_s), interval_s_(interval_s) {}
  // "" or the warning.
  std::string update(const LoopStats& stats, double now_s);

 private:
  double max_fraction_, window_s_, interval_s_;
  bool started_ = false;
  double window_start_s_ = 0;
  std::uint64_t window_wakeups_ = 0, window_misses_ = 0;  // at the window's start
  double last_warning_s_ = 0;
  bool warned_ = false;
  std::uint64_t windows_over_ = 0;  // windows over the limit since the last warning
};

}  // namespace idm::daemon
