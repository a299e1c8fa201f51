// The positioner's loop (tick and the commands) does not allocate on the simulated stage once it
// is constructed: a counting operator new around a loop of moves, stops and steps.
#include <gtest/gtest.h>

#include <atomic>
#include <cstdlib>
#include <new>

#include "positioner_rig.h"

// The replacement pairs malloc with free on purpose; GCC cannot see that across inlining.
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wmismatched-new-delete"
#endif

namespace {
std::atomic<bool> g_counting{false};
std::atomic<std::uint64_t> g_allocations{0};
}  // namespace

void* operator new(std::size_t n) {
  if (g_counting.load(std::memory_order_relaxed)) g_allocations.fetch_add(1, std::memory_order_relaxed);
  if (void* p = std::malloc(n == 0 ? 1 : n)) return p;
  throw std::bad_alloc();
}
void* operator new[](std::size_t n) { return operator new(n); }
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }

using namespace idm;
using namespace idm::control;

TEST(PositionerAlloc, LoopDoesNotAllocate) {
  static const RegionMap map(test_rig::rig_map_config(1.0));
  Calibration calibration(map.config().stage);
  test_rig::Rig rig(map, test_rig::ideal_device(), {}, &calibration);
  Positioner& p = *rig.positioner;
  ASSERT_EQ(p.set_soft_limits(-0.1, 0.1), Refusal::None);
  g_allocations = 0;
  g_counting = true;
  Refusal r1 = p.move_relative(1.2e-3);
  MotionState s1 = rig.run();
  Refusal r2 = p.move_relative(-3.3e-7);
  MotionState s2 = rig.run();
  Refusal r3 = p.move_relative(-5e-4);
  rig.run_until([&] { return p.status().bursts >= 20; }, 0.02);
  p.stop();
  MotionState s3 = rig.run();
  Refusal r4 = p.step_open_loop(-30);
  MotionState s4 = rig.run();
  Refusal r5 = p.move_absolute(0.2);  // refused: outside the soft limits
  g_counting = false;
  EXPECT_EQ(g_allocations.load(), 0u);
  EXPECT_EQ(r1, Refusal::None);
  EXPECT_EQ(r2, Refusal::None);
  EXPECT_EQ(r3, Refusal::None);
  EXPECT_EQ(r4, Refusal::None);
  EXPECT_EQ(r5, Refusal::OutsideSoftLimits);
  EXPECT_EQ(s1, MotionState::Idle);
  EXPECT_EQ(s2, MotionState::Idle);
  EXPECT_EQ(s3, MotionState::Idle);
  EXPECT_EQ(s4, MotionState::Idle);
  EXPECT_GT(calibration.total_updates(), 0u);
}
