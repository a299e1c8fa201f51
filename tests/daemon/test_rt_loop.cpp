// The lock-free structures between the loop and the other threads, and the real-time loop.
#include <gtest/gtest.h>

#include <atomic>
#include <cstdint>
#include <string>
#include <thread>
#include <vector>

#include "daemon/rt_loop.h"
#include "drivers/clock.h"
#include "drivers/lockfree.h"
#include "tests/daemon/daemon_test_util.h"

namespace {

using namespace idm::daemon;
using namespace idm::daemon::test;

// ---- lock-free structures --------------------------------------------------------------------

TEST(SpscRing, FifoAndCapacity) {
  SpscRing<int, 4> ring;
  for (int i = 0; i < 4; ++i) EXPECT_TRUE(ring.push(i));
  EXPECT_FALSE(ring.push(99));
  int v = -1;
  for (int i = 0; i < 4; ++i) {
    ASSERT_TRUE(ring.pop(v));
    EXPECT_EQ(v, i);
  }
  EXPECT_FALSE(ring.pop(v));
}

TEST(SpscRing, TwoThreadsLoseNothing) {
  SpscRing<std::uint64_t, 64> ring;
  constexpr std::uint64_t kN = 200000;
  std::thread producer([&] {
    for (std::uint64_t i = 1; i <= kN; ++i)
      while (!ring.push(i)) std::this_thread::yield();
  });
  std::uint64_t expected = 1, v = 0;
  while (expected <= kN) {
    if (ring.pop(v)) {
      ASSERT_EQ(v, expected);
      ++expected;
    } else {
      std::this_thread::yield();
    }
  }
  producer.join();
}

struct Pair {
  std::uint64_t a, b;
};

TEST(Seqlock, ReadersNeverSeeATornValue) {
  Seqlock<Pair> s;
  s.store({0, ~std::uint64_t{0}});
  std::atomic<bool> done{false};
  std::thread writer([&] {
    for (std::uint64_t i = 1; i <= 200000; ++i) s.store({i, ~i});
    done = true;
  });
  long reads = 0;
  while (!done || reads < 1000) {
    const Pair p = s.load();
    ASSERT_EQ(p.b, ~p.a);
    ++reads;
  }
  writer.join();
  EXPECT_EQ(s.load().a, 200000u);
  EXPECT_GT(reads, 0);
}

// ---- the loop
// ------------------------------------------------------------------------------------

struct CountingBody : LoopBody {
  std::atomic<std::uint64_t> n{0};
  double last = 0;
  bool monotonic = true;
  void tick(double now_s) override {
    if (now_s < last) monotonic = false;
    last = now_s;
    n.fetch_add(1);
  }
};

TEST(RtLoop, TicksKeepsStatisticsAndStops) {
  RealtimeConfig rc;
  rc.period_s = 1e-3;
  rc.sched_fifo = false;
  rc.lock_memory = false;
  CountingBody body;
  RtLoop loop(rc, body);
  EXPECT_EQ(loop.start(), "");
  ASSERT_TRUE(wait_for([&] { return loop.stats().wakeups >= 20; }, 10));
  loop.stop();
  EXPECT_FALSE(loop.running());
  const LoopStats s = loop.stats();
  EXPECT_EQ(s.wakeups, body.n.load());
  EXPECT_EQ(loop.ticks(), body.n.load());
  EXPECT_TRUE(body.monotonic);
  EXPECT_DOUBLE_EQ(s.period_s, 1e-3);
  EXPECT_LE(s.latency_min_s, s.latency_avg_s);
  EXPECT_LE(s.latency_avg_s, s.latency_max_s);
  std::uint64_t in_bins = 0;
  for (std::uint64_t b : s.bins) in_bins += b;
  EXPECT_EQ(in_bins, s.wakeups);
  const std::uint64_t after = body.n.load();
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  EXPECT_EQ(body.n.load(), after);  // stopped
}

TEST(RtLoop, RealtimeRefusalIsOneWarningThatSaysWhy) {
  RealtimeConfig rc;
  rc.period_s = 1e-3;
  rc.sched_fifo = true;
  rc.priority = 99;
  rc.cpu = 100000 % 1024;  // not a CPU this machine has
  rc.lock_memory = false;
  CountingBody body;
  RtLoop loop(rc, body);
  const std::string warning = loop.start();
  ASSERT_TRUE(wait_for([&] { return body.n.load() > 3; }, 10));  // carries on
  loop.stop();
  EXPECT_NE(warning.find("CPU affinity"), std::string::npos) << warning;
  EXPECT_NE(warning.find("running without it"), std::string::npos) << warning;
}

}  // namespace

// Deadline misses: one warning saying the rate and what to do once a window of 10 s missed more
// than 1 % of its deadlines, then at most one a minute however long it lasts (saying how many
// windows it left out); nothing for a rate under the limit. The statistics and the clock are
// made up: no timing.
TEST(DeadlineMissWatch, ARateAboveTheLimitWarnsAtMostOnceAMinute) {
  DeadlineMissWatch watch(0.01, 10, 60);
  LoopStats s;
  s.period_s = 1e-4;
  double t = 100;
  // Every 50 ms (housekeeping's cycle) 500 deadlines pass, `missed` of them missed.
  std::vector<std::string> warnings;
  std::vector<double> when;
  const auto run = [&](double seconds, std::uint64_t missed) {
    for (int k = 0; k < static_cast<int>(seconds / 0.05); ++k) {
      t += 0.05;
      s.wakeups += 500 - missed;
      s.deadline_misses += missed;
      if (std::string w = watch.update(s, t); !w.empty()) {
        warnings.push_back(w);
        when.push_back(t);
      }
    }
  };
  run(60, 4);  // 0.8 %
  EXPECT_TRUE(warnings.empty()) << warnings.front();
  run(180, 25);  // 5 %
  ASSERT_EQ(warnings.size(), 3u);
  // After the first whole window over the limit; then a minute apart, not every window.
  EXPECT_GT(when[0], 170 - 0.1);
  EXPECT_LT(when[0], 180 + 0.1);
  EXPECT_GE(when[1] - when[0], 60 - 0.1);
  EXPECT_LT(when[1] - when[0], 70 + 0.1);
  EXPECT_NE(warnings[0].find("missed 5000 of 100000 deadlines (5 %) in the last 10 s"),
            std::string::npos)
      << warnings[0];
  EXPECT_NE(warnings[0].find("realtime.sched_fifo"), std::string::npos) << warnings[0];
  EXPECT_NE(warnings[0].find("realtime.period_s"), std::string::npos) << warnings[0];
  EXPECT_NE(warnings[1].find("5 more such windows since the last warning"), std::string::npos)
      << warnings[1];
  run(120, 0);
  EXPECT_EQ(warnings.size(), 3u) << "nothing once the loop keeps up";
}

namespace {

// Rests (resting() true) for its first kRest ticks, then ticks at the full rate; keeps each
// tick's time (preallocated: the loop thread must not allocate).
struct RestThenWorkBody : LoopBody {
  static constexpr int kRest = 20;
  static constexpr int kTicks = 60;
  double t[kTicks] = {};
  std::atomic<int> n{0};
  void tick(double now_s) override {
    const int k = n.load(std::memory_order_relaxed);
    if (k < kTicks) t[k] = now_s;
    n.store(k + 1, std::memory_order_release);
  }
  bool resting() const override { return n.load(std::memory_order_relaxed) <= kRest; }
};

}  // namespace

// At rest the loop's deadlines are rest_period_s apart (on the period's grid): a tick never comes
// before its deadline, so the k-th tick at rest is at least k - 1 rest periods after the start.
// (Only lower bounds: an upper bound would be a timing assertion on a shared machine.)
TEST(RtLoop, AtRestTheDeadlinesAreTheRestPeriodApart) {
  RealtimeConfig rc;
  rc.period_s = 1e-4;
  rc.rest_period_s = 2e-3;
  rc.sched_fifo = false;
  rc.lock_memory = false;
  RestThenWorkBody body;
  RtLoop loop(rc, body);
  const double start_s = idm::drivers::monotonic_s();
  EXPECT_EQ(loop.start(), "");
  ASSERT_TRUE(wait_for([&] { return body.n.load() >= RestThenWorkBody::kTicks; }, 30));
  loop.stop();
  for (int k = 1; k <= RestThenWorkBody::kRest + 1; ++k)
    EXPECT_GE(body.t[k - 1] - start_s, (k - 1) * rc.rest_period_s - 1e-9) << "tick " << k;
  const LoopStats s = loop.stats();
  EXPECT_EQ(s.wakeups, static_cast<std::uint64_t>(body.n.load()));
}
