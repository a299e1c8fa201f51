#include "daemon/rt_loop.h"

#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <time.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>

#include "model/range.h"

namespace idm::daemon {

namespace {

constexpr std::int64_t kNsPerS = 1000000000;

std::int64_t to_ns(const timespec& t) {
  return std::int64_t{t.tv_sec} * kNsPerS + t.tv_nsec;
}
timespec to_timespec(std::int64_t ns) {
  timespec t;
  t.tv_sec = static_cast<time_t>(ns / kNsPerS);
  t.tv_nsec = static_cast<long>(ns % kNsPerS);
  return t;
}
std::int64_t now_ns() {
  timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return to_ns(t);
}

std::string limit_text(int resource) {
  rlimit lim{};
  if (getrlimit(resource, &lim) != 0) return "unknown";
  if (lim.rlim_cur == RLIM_INFINITY) return "unlimited";
  return std::to_string(static_cast<unsigned long long>(lim.rlim_cur));
}

// Touches a stack region so that the loop's first ticks do not fault pages in.
void prefault_stack() {
  volatile unsigned char buffer[64 * 1024];
  for (std::size_t i = 0; i < sizeof(buffer); i += 4096) buffer[i] = 0;
}

}  // namespace

RtLoop::RtLoop(const RealtimeConfig& config, LoopBody& body) : config_(config), body_(body) {
  local_.period_s = config_.period_s;
  local_.bin_width_s = config_.histogram_bin_s;
  stats_.store(local_);
}

RtLoop::~RtLoop() {
  stop();
}

std::string RtLoop::start() {
  if (thread_.joinable()) return {};
  stop_.store(false);
  setup_done_.store(0);
  running_.store(true, std::memory_order_release);
  thread_ = StackThread("idmd-rt", kLoopStackBytes, [this] { run(); });
  while (setup_done_.load(std::memory_order_acquire) == 0) std::this_thread::yield();
  return setup_warning_;
}

void RtLoop::stop() {
  stop_.store(true, std::memory_order_release);
  if (thread_.joinable()) thread_.join();
  running_.store(false, std::memory_order_release);
}

std::string RtLoop::setup_realtime() {
  std::string why;
  auto add = [&why](const std::string& s) { why += (why.empty() ? "" : "; ") + s; };
  if (config_.lock_memory) {
    if (mlockall(MCL_CURRENT | MCL_FUTURE) != 0) {
      const int e = errno;
      add(std::string("mlockall failed (") + std::strerror(e) + "): RLIMIT_MEMLOCK is " +
          limit_text(RLIMIT_MEMLOCK) +
          " bytes; grant CAP_IPC_LOCK or LimitMEMLOCK=infinity to lock memory");
    }
  }
  if (config_.cpu >= 0) {
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(config_.cpu, &set);
    const int e = pthread_setaffinity_np(pthread_self(), sizeof(set), &set);
    if (e != 0)
      add("CPU affinity to CPU " + std::to_string(config_.cpu) + " failed (" + std::strerror(e) +
          "): is that CPU online and in the allowed set?");
  }
  if (config_.sched_fifo) {
    sched_param p{};
    p.sched_priority = config_.priority;
    const int e = pthread_setschedparam(pthread_self(), SCHED_FIFO, &p);
    if (e != 0)
      add("SCHED_FIFO priority " + std::to_string(config_.priority) + " failed (" +
          std::strerror(e) + "): needs CAP_SYS_NICE or RLIMIT_RTPRIO >= priority (now " +
          limit_text(RLIMIT_RTPRIO) + ")");
  }
  // The kernel may defer a normal thread's timer by its slack (50 us by default) to batch
  // wake-ups; the loop wakes on deadlines and wants each on time (SCHED_FIFO has no slack, so
  // this matters where it is not permitted).
  (void)prctl(PR_SET_TIMERSLACK, 1UL, 0UL, 0UL, 0UL);
  prefault_stack();
  if (why.empty()) return {};
  return "real-time setup incomplete, running without it: " + why;
}

void RtLoop::publish_stats() {
  if (local_.wakeups > 0)
    local_.latency_avg_s = latency_sum_s_ / static_cast<double>(local_.wakeups);
  stats_.store(local_);
}

void RtLoop::run() {
  setup_warning_ = setup_realtime();
  setup_done_.store(1, std::memory_order_release);

  const std::int64_t period_ns = static_cast<std::int64_t>(std::llround(config_.period_s * 1e9));
  // The rest period in whole periods (the deadlines stay on one grid); at least one.
  const std::int64_t rest_periods =
      std::max<std::int64_t>(1, std::llround(config_.rest_period_s / config_.period_s));
  const double bin_ns = config_.histogram_bin_s * 1e9;
  constexpr std::size_t kBins = sizeof(local_.bins) / sizeof(local_.bins[0]);
  constexpr std::int64_t kPublishEveryNs = 50'000'000;  // the statistics, every 50 ms

  if (hook_) hook_(true);
  std::int64_t deadline = now_ns() + period_ns;
  std::int64_t next_publish = deadline;
  while (!stop_.load(std::memory_order_acquire)) {
    const timespec ts = to_timespec(deadline);
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
    }
    const std::int64_t woke = now_ns();
    const std::int64_t late = woke - deadline;
    const double late_s = static_cast<double>(late) * 1e-9;
    if (local_.wakeups == 0 || late_s < local_.latency_min_s) local_.latency_min_s = late_s;
    if (late_s > local_.latency_max_s) local_.latency_max_s = late_s;
    latency_sum_s_ += late_s;
    ++local_.wakeups;
    std::size_t bin = late > 0 ? static_cast<std::size_t>(static_cast<double>(late) / bin_ns) : 0;
    if (bin >= kBins) bin = kBins - 1;
    ++local_.bins[bin];

    body_.tick(static_cast<double>(woke) * 1e-9);
    ticks_.fetch_add(1, std::memory_order_release);

    // Next deadline (the rest period's while the body rests); when the tick (or the wake-up)
    // overran one or more periods, those deadlines are counted as missed and skipped rather than
    // run back to back.
    deadline += body_.resting() ? rest_periods * period_ns : period_ns;
    const std::int64_t after = now_ns();
    if (after > deadline) {
      const std::int64_t missed = (after - deadline) / period_ns + 1;
      local_.deadline_misses += static_cast<std::uint64_t>(missed);
      deadline += missed * period_ns;
    }
    if (woke >= next_publish) {
      publish_stats();
      next_publish = woke + kPublishEveryNs;
    }
  }
  publish_stats();
  if (hook_) hook_(false);
}

std::string DeadlineMissWatch::update(const LoopStats& stats, double now_s) {
  if (!started_ || stats.wakeups < window_wakeups_) {  // the first look, or a new loop
    started_ = true;
    window_start_s_ = now_s;
    window_wakeups_ = stats.wakeups;
    window_misses_ = stats.deadline_misses;
    return {};
  }
  if (now_s - window_start_s_ < window_s_) return {};
  const std::uint64_t ticks = stats.wakeups - window_wakeups_;
  const std::uint64_t missed = stats.deadline_misses - window_misses_;
  const double seconds = now_s - window_start_s_;
  window_start_s_ = now_s;
  window_wakeups_ = stats.wakeups;
  window_misses_ = stats.deadline_misses;
  // Every deadline was either met by a tick or skipped as missed.
  const double deadlines = static_cast<double>(ticks + missed);
  if (deadlines <= 0 || static_cast<double>(missed) <= max_fraction_ * deadlines) return {};
  ++windows_over_;
  if (warned_ && now_s - last_warning_s_ < interval_s_) return {};
  warned_ = true;
  last_warning_s_ = now_s;
  char rate[32];
  std::snprintf(rate, sizeof rate, "%.3g %%", 100.0 * static_cast<double>(missed) / deadlines);
  std::string text = "the real-time loop missed " + std::to_string(missed) + " of " +
                     std::to_string(ticks + missed) + " deadlines (" + rate + ") in the last " +
                     model::format_number(seconds, 3) + " s (period " +
                     model::format_number(stats.period_s, 3) + " s, worst wake-up " +
                     model::format_number(stats.latency_max_s, 3) +
                     " s late): readings, chunks and STOP are handled late";
  if (windows_over_ > 1)
    text += " (" + std::to_string(windows_over_ - 1) + " more such windows since the last warning)";
  windows_over_ = 0;
  return text +
         "; give idmd SCHED_FIFO (realtime.sched_fifo with CAP_SYS_NICE, as the systemd unit "
         "does), a CPU of its own (realtime.cpu, isolcpus) and locked memory, take load off the "
         "machine, or lengthen realtime.period_s (SYST:LOOP? shows the latencies)";
}

}  // namespace idm::daemon
