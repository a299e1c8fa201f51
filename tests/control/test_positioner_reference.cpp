// The positioner's reference mark search on the simulated stage (sim.reference_mark_m): a mark
// ahead, a mark behind the start (the search turns at the end stop), no mark at all.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "positioner_rig.h"

using namespace idm;
using namespace idm::control;
using idm::control::test_rig::ideal_device;
using idm::control::test_rig::Rig;

namespace {

const RegionMap& ideal_map() {
  static const RegionMap map(test_rig::rig_map_config(1.0));
  return map;
}

drivers::sim::SimDeviceConfig device_with(double mark_m, double low_m, double high_m) {
  drivers::sim::SimDeviceConfig c = ideal_device();
  c.sim.reference_mark_m = mark_m;
  c.sim.end_stop_low_m = low_m;
  c.sim.end_stop_high_m = high_m;
  return c;
}

// After a successful search: referenced, at rest on the reference position, and the slider on
// the mark (readings are the device's plus the offset, so the mark maps to the reference
// position).
void expect_referenced_at_mark(Rig& rig, double mark_m, double reference_m) {
  const Positioner& p = *rig.positioner;
  const MotionStatus& s = p.status();
  const double count = p.count_m();
  EXPECT_EQ(s.state, MotionState::Idle) << motion_fault_name(s.fault);
  EXPECT_EQ(s.kind, MotionKind::Reference);
  EXPECT_EQ(s.result, MoveResult::Ok) << move_result_name(s.result);
  EXPECT_EQ(s.references, 1u);
  EXPECT_TRUE(s.position_valid);
  EXPECT_LE(std::fabs(s.position_m - reference_m), p.tolerance_m());
  EXPECT_NEAR(s.target_m, reference_m, 1e-15);
  // The slider is where the mark is, to the reading's resolution: the crawl's marked word lies
  // at most the slider's travel between two stream samples past the mark (a count or less for
  // the ideal plant's fine cells), and the readings and the move's window add a count each.
  const double true_m = rig.sim->true_position_m();
  const double bound = 3.0 * count;
  std::printf("slider %.4g m from the mark (%.3g counts; bound %.3g counts); offset %.6g m\n",
              true_m - mark_m, (true_m - mark_m) / count, bound / count, s.offset_m);
  EXPECT_LE(std::fabs(true_m - mark_m), bound);
  EXPECT_NEAR(s.offset_m, reference_m - mark_m, bound);
  EXPECT_EQ(rig.sim->commanded_elongation_m(), 0.0);
}

}  // namespace

TEST(PositionerReference, FindsAMarkAheadAndSitsOnIt) {
  const double mark = -20e-6, reference = 5e-6;
  Rig rig(ideal_map(), device_with(mark, -1e-3, 1e-3));
  Positioner& p = *rig.positioner;
  ASSERT_EQ(p.reference_mark(-1, reference), Refusal::None);
  EXPECT_EQ(p.status().state, MotionState::Moving);
  ASSERT_EQ(rig.run(), MotionState::Idle) << motion_fault_name(p.status().fault);
  expect_referenced_at_mark(rig, mark, reference);
  EXPECT_EQ(p.status().eot, 0);
  // It stopped at the mark, not at the end stop.
  EXPECT_GT(rig.sim->true_position_m(), -0.5e-3);
}

TEST(PositionerReference, AMarkBehindTheStartIsFoundAfterTheEndStop) {
  const double mark = 30e-6, reference = 0.0;
  Rig rig(ideal_map(), device_with(mark, -50e-6, 200e-6));
  Positioner& p = *rig.positioner;
  ASSERT_EQ(p.reference_mark(-1, reference), Refusal::None);
  double lowest = 0;
  rig.run_until([&] {
    lowest = std::min(lowest, rig.sim->true_position_m());
    return false;
  });
  EXPECT_LT(lowest, -45e-6) << "the search went to the low end stop first";
  expect_referenced_at_mark(rig, mark, reference);
}

TEST(PositionerReference, NoMarkBetweenTheEndStopsIsNotAReference) {
  // The positioner does not know whether the device has a mark (the daemon refuses MARK on a
  // device without one): here the mark lies outside the travel, so no word ever carries it.
  Rig rig(ideal_map(), device_with(1e-3, -40e-6, 40e-6));
  Positioner& p = *rig.positioner;
  const double offset = p.status().offset_m;
  ASSERT_EQ(p.reference_mark(1, 0.0), Refusal::None);
  double lowest = 0, highest = 0;
  rig.run_until([&] {
    lowest = std::min(lowest, rig.sim->true_position_m());
    highest = std::max(highest, rig.sim->true_position_m());
    return false;
  });
  const MotionStatus& s = p.status();
  EXPECT_EQ(s.state, MotionState::Idle) << motion_fault_name(s.fault);
  EXPECT_EQ(s.kind, MotionKind::Reference);
  EXPECT_NE(s.result, MoveResult::Ok);
  EXPECT_EQ(s.result, MoveResult::EndOfTravel) << move_result_name(s.result);
  EXPECT_EQ(s.references, 0u);
  EXPECT_EQ(s.offset_m, offset) << "the coordinates are left as they were";
  // Both ends were tried (a chunk ends with the slider thrown back from the stop a little).
  EXPECT_GT(highest, 20e-6);
  EXPECT_LT(lowest, -20e-6);
  EXPECT_EQ(s.eot, -1) << "it stopped at the second end stop";
  EXPECT_EQ(rig.sim->commanded_elongation_m(), 0.0);
}

TEST(PositionerReference, StopEndsTheSearchUnreferenced) {
  Rig rig(ideal_map(), device_with(-0.9e-3, -1e-3, 1e-3));
  Positioner& p = *rig.positioner;
  ASSERT_EQ(p.reference_mark(-1, 0.0), Refusal::None);
  rig.run_until([&] { return p.status().bursts >= 1; });
  p.stop();
  ASSERT_EQ(rig.run(), MotionState::Idle);
  EXPECT_EQ(p.status().result, MoveResult::Stopped);
  EXPECT_EQ(p.status().references, 0u);
  EXPECT_EQ(p.status().offset_m, 0.0);
  EXPECT_LT(rig.sim->true_position_m(), -1e-6) << "it moved";
  EXPECT_GT(rig.sim->true_position_m(), -0.9e-3) << "and stopped before the mark";
  // Refusals as for the end-stop reference.
  EXPECT_EQ(p.reference_mark(-1, std::nan("")), Refusal::NotFinite);
}

TEST(PositionerReference, FindsTheMarkOnTheRealisticPlant) {
  // Mass-damper-spring actuator, Stribeck friction varying along the guide, 2 nm rms noise: some
  // fine cells step less than the map says, or the other way (the crawl then tries another),
  // and the readings scatter by a count.
  static const RegionMap map(test_rig::realistic_map_config());
  for (std::uint64_t seed : {1u, 2u, 3u, 4u}) {
    drivers::sim::SimDeviceConfig device = test_rig::realistic_device(seed);
    const double mark = 40e-6, reference = -1e-3;
    device.sim.reference_mark_m = mark;
    device.sim.end_stop_low_m = -60e-6;
    device.sim.end_stop_high_m = 1e-3;
    Rig rig(map, device);
    Positioner& p = *rig.positioner;
    ASSERT_EQ(p.reference_mark(-1, reference), Refusal::None);
    ASSERT_EQ(rig.run(), MotionState::Idle) << motion_fault_name(p.status().fault);
    const double count = p.count_m();
    const double true_m = rig.sim->true_position_m();
    std::printf("realistic, seed %d: slider %.4g m from the mark (%.3g counts)\n",
                static_cast<int>(seed), true_m - mark, (true_m - mark) / count);
    EXPECT_EQ(p.status().result, MoveResult::Ok) << move_result_name(p.status().result);
    EXPECT_EQ(p.status().references, 1u);
    EXPECT_LE(std::fabs(p.status().position_m - reference), p.tolerance_m()) << seed;
    EXPECT_LE(std::fabs(true_m - mark), 4.0 * count) << seed;
  }
}
