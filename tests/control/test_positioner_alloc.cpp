// The positioner's loop (tick and the commands) does not allocate on the simulated stage once it
// is constructed: a counting operator new (tests/counting_new.h) around a loop of moves, stops,
// steps and a reference mark search.
#include <gtest/gtest.h>

#include "positioner_rig.h"
#include "tests/counting_new.h"

using namespace idm;
using namespace idm::control;

TEST(PositionerAlloc, LoopDoesNotAllocate) {
  static const RegionMap map(test_rig::rig_map_config(1.0));
  Calibration calibration(map.config().stage);
  drivers::sim::SimDeviceConfig device = test_rig::ideal_device();
  device.sim.reference_mark_m = 0.3e-3;  // crossed by the moves, then searched for
  device.sim.end_stop_low_m = -2e-3;
  device.sim.end_stop_high_m = 2e-3;
  test_rig::Rig rig(map, device, {}, &calibration);
  Positioner& p = *rig.positioner;
  ASSERT_EQ(p.set_soft_limits(-0.1, 0.1), Refusal::None);
  idm::test_alloc::allocations = 0;
  idm::test_alloc::t_counting = true;
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
  Refusal r6 = p.reference_mark(-1, 0.0);
  MotionState s6 = rig.run();
  idm::test_alloc::t_counting = false;
  EXPECT_EQ(idm::test_alloc::allocations.load(), 0);
  EXPECT_EQ(r1, Refusal::None);
  EXPECT_EQ(r2, Refusal::None);
  EXPECT_EQ(r3, Refusal::None);
  EXPECT_EQ(r4, Refusal::None);
  EXPECT_EQ(r5, Refusal::OutsideSoftLimits);
  EXPECT_EQ(s1, MotionState::Idle);
  EXPECT_EQ(s2, MotionState::Idle);
  EXPECT_EQ(s3, MotionState::Idle);
  EXPECT_EQ(s4, MotionState::Idle);
  EXPECT_EQ(r6, Refusal::None);
  EXPECT_EQ(s6, MotionState::Idle);
  EXPECT_EQ(p.status().result, MoveResult::Ok);
  EXPECT_EQ(p.status().references, 1u);
  EXPECT_GT(calibration.total_updates(), 0u);
}
