// End of travel or obstruction (control/README.md, "In position, results, end of travel"): a
// collapse of the step met near the end of stage.travel_m the slider drove toward is the end of
// travel (END_OF_TRAVEL, motion further that way refused until it moves away); one met farther
// inside than end_margin_m() is something holding the slider (FAULT stall, which reset_fault
// clears). The simulated stage's hard stop stands for both, on the synthetic clock.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "positioner_rig.h"

using namespace idm;
using namespace idm::control;
using idm::control::test_rig::ideal_device;
using idm::control::test_rig::ideal_map;
using idm::control::test_rig::Rig;

namespace {

// The ideal plant with its low hard stop at low_stop_m (the high one far away).
drivers::sim::SimDeviceConfig stop_at(double low_stop_m) {
  drivers::sim::SimDeviceConfig c = ideal_device();
  c.sim.end_stop_low_m = low_stop_m;
  c.sim.end_stop_high_m = 5e-3;
  return c;
}

// The travel as the daemon fills it in from stage.travel_m, the soft limits on it.
PositionerConfig travel(double lower_m, double upper_m) {
  PositionerConfig c;
  c.travel_lower_m = c.soft_lower_m = lower_m;
  c.travel_upper_m = c.soft_upper_m = upper_m;
  return c;
}

}  // namespace

// The slider stuck 4 mm before the end of a 10 mm travel: a stall fault (it was END_OF_TRAVEL,
// which only a move away cleared and *RST did not); reset_fault clears it, and motion that way
// is not refused afterwards (nothing says the travel ends there); a reference that way finds it.
TEST(PositionerEndOfTravel, AStopFarInsideTheTravelIsAStallFault) {
  Rig rig(ideal_map(), stop_at(-1e-3), travel(-5e-3, 5e-3));
  Positioner& p = *rig.positioner;
  ASSERT_EQ(p.move_absolute(-0.2e-3), Refusal::None);
  ASSERT_EQ(rig.run(), MotionState::Idle);
  ASSERT_EQ(p.status().result, MoveResult::Ok);  // it has stepped that way
  ASSERT_EQ(p.move_absolute(-2e-3), Refusal::None);
  EXPECT_EQ(rig.run(), MotionState::Fault);
  const MotionStatus& s = p.status();
  EXPECT_EQ(s.fault, MotionFault::Stall) << motion_fault_name(s.fault);
  EXPECT_EQ(s.result, MoveResult::Fault) << move_result_name(s.result);
  EXPECT_EQ(s.eot, 0);
  EXPECT_NEAR(rig.sim->true_position_m(), -1e-3, 1e-6) << "held at the obstruction";
  EXPECT_EQ(rig.sim->commanded_elongation_m(), 0.0);
  p.reset_fault();
  EXPECT_EQ(p.status().state, MotionState::Idle);
  ASSERT_EQ(p.move_absolute(-0.5e-3), Refusal::None);
  ASSERT_EQ(rig.run(), MotionState::Idle);
  EXPECT_EQ(p.status().result, MoveResult::Ok);
  EXPECT_EQ(p.move_absolute(-1.5e-3), Refusal::None) << "not refused as an end of travel";
  p.stop();
  ASSERT_EQ(rig.run(), MotionState::Idle);
  // A reference looks for a stop wherever the coordinates put it: this one is the reference (the
  // position there becomes the travel's end).
  ASSERT_EQ(p.reference(-1, -5e-3), Refusal::None);
  ASSERT_EQ(rig.run(), MotionState::Idle) << motion_fault_name(p.status().fault);
  EXPECT_EQ(p.status().result, MoveResult::Ok);
  EXPECT_EQ(p.status().references, 1u);
  EXPECT_NEAR(p.status().position_m, -5e-3, 1e-7);
  // And it stays there at rest: the readings the mean at rest held from before the offset was
  // set move with it (they once read the position 0.11 mm off, in the old frame, for a moment).
  for (int k = 0; k < 40; ++k) {
    rig.run_for(1e-3);
    ASSERT_NEAR(p.status().position_m, -5e-3, 2 * p.count_m()) << k;
  }
}

// The same obstruction met by open-loop STEPs.
TEST(PositionerEndOfTravel, AStopFarInsideTheTravelIsAStallFaultOpenLoop) {
  Rig rig(ideal_map(), stop_at(-1e-3), travel(-5e-3, 5e-3));
  Positioner& p = *rig.positioner;
  MotionState state = MotionState::Idle;
  for (int k = 0; k < 20 && state == MotionState::Idle; ++k) {
    ASSERT_EQ(p.step_open_loop(-100), Refusal::None) << k;
    state = rig.run();
  }
  EXPECT_EQ(state, MotionState::Fault);
  EXPECT_EQ(p.status().fault, MotionFault::Stall) << motion_fault_name(p.status().fault);
  EXPECT_EQ(p.status().kind, MotionKind::Step);
  EXPECT_EQ(p.status().eot, 0);
  EXPECT_NEAR(rig.sim->true_position_m(), -1e-3, 1e-6);
}

// Where the travel's end lies decides, by the margin: a stop within end_margin_m() of the
// travel's end (or a travel not known) is the end of travel; one beyond it, an obstruction.
TEST(PositionerEndOfTravel, TheMarginFromTheTravelsEndDecides) {
  const double stop = -1e-3;
  const double margin = Rig(ideal_map(), stop_at(stop)).positioner->end_margin_m();
  EXPECT_NEAR(margin, 5 * ideal_map().config().stage.stroke_m, 1e-15);
  const double inf = std::numeric_limits<double>::infinity();
  struct Case {
    double lower_m;  // the travel's low end
    bool end_of_travel;
  };
  for (const Case& c :
       {Case{stop - 0.8 * margin, true}, Case{stop - 1.2 * margin, false}, Case{-inf, true}}) {
    const double target = std::isfinite(c.lower_m) ? c.lower_m : stop - margin;
    Rig rig(ideal_map(), stop_at(stop), travel(c.lower_m, 5e-3));
    Positioner& p = *rig.positioner;
    ASSERT_EQ(p.move_absolute(target), Refusal::None);
    rig.run();
    const MotionStatus& s = p.status();
    if (c.end_of_travel) {
      EXPECT_EQ(s.state, MotionState::Idle) << c.lower_m;
      EXPECT_EQ(s.result, MoveResult::EndOfTravel)
          << c.lower_m << " " << move_result_name(s.result);
      EXPECT_EQ(s.eot, -1) << c.lower_m;
      EXPECT_EQ(p.move_absolute(target), Refusal::EndOfTravel) << "further in is refused";
    } else {
      EXPECT_EQ(s.state, MotionState::Fault) << c.lower_m;
      EXPECT_EQ(s.fault, MotionFault::Stall) << c.lower_m << " " << motion_fault_name(s.fault);
      EXPECT_EQ(s.eot, 0) << c.lower_m;
    }
  }
}
