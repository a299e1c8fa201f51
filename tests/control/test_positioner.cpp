// The closed-loop positioner on the simulated stage: convergence, faults (beam loss, stall,
// invalid samples), stop, soft limits, open-loop steps, and no allocation in the loop.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <random>

#include "positioner_rig.h"

using namespace idm;
using namespace idm::control;
using idm::control::test_rig::ideal_device;
using idm::control::test_rig::Rig;

namespace {

using test_rig::ideal_map;

TEST(Positioner, ConvergesOnTheIdealPlantBothDirections) {
  Rig rig(ideal_map(), ideal_device());
  Positioner& p = *rig.positioner;
  ASSERT_TRUE(p.status().position_valid);
  const double count = p.count_m();
  // The window is one count; a move aims for the reading nearest the target (half a count), so
  // that the slider is within one count.
  EXPECT_NEAR(p.tolerance_m(), count, 1e-18);
  EXPECT_NEAR(p.landing_m(), 0.5 * count, 1e-18);
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> log_distance(std::log(20e-9), std::log(1e-3));
  for (int i = 0; i < 12; ++i) {
    const double distance = std::exp(log_distance(rng)) * (i % 2 == 0 ? 1 : -1);
    const double target = p.status().position_m + distance;
    ASSERT_EQ(p.move_absolute(target), Refusal::None);
    EXPECT_EQ(p.status().state, MotionState::Moving);
    ASSERT_EQ(rig.run(), MotionState::Idle)
        << "move " << i << " fault " << motion_fault_name(p.status().fault) << " "
        << drivers::describe_sample_status(p.invalid_sample_status());
    EXPECT_LE(std::fabs(p.status().position_m - target), 0.5 * count) << "move " << i;
    // The reading is the true position quantized to one count (no noise here).
    EXPECT_LE(std::fabs(rig.sim->true_position_m() - target), count) << "move " << i;
    std::printf("move %d of %.3g m: %u corrections\n", i, distance, p.status().corrections);
    EXPECT_LE(p.status().corrections, 6u) << "move " << i << " of " << distance;
    EXPECT_EQ(rig.sim->commanded_elongation_m(), 0.0);
  }
  EXPECT_EQ(p.status().moves, 12u);
  EXPECT_GT(p.status().bursts, 12u);
}

TEST(Positioner, ArrivedWithinToleranceMovesNothing) {
  Rig rig(ideal_map(), ideal_device());
  Positioner& p = *rig.positioner;
  ASSERT_EQ(p.move_relative(0.3 * p.count_m()), Refusal::None);
  ASSERT_EQ(rig.run(), MotionState::Idle);
  EXPECT_EQ(p.status().bursts, 0u);
}

TEST(Positioner, BeamLossMidMoveFaultsWithOutputAtZero) {
  Rig rig(ideal_map(), ideal_device());
  Positioner& p = *rig.positioner;
  ASSERT_EQ(p.move_relative(2e-3), Refusal::None);
  ASSERT_TRUE(rig.run_until([&] { return p.status().bursts >= 3; }));
  const std::uint64_t bursts = p.status().bursts;
  rig.sim->set_beam_lost(true);
  EXPECT_EQ(rig.run(), MotionState::Fault);
  EXPECT_EQ(p.status().fault, MotionFault::InvalidSample);
  EXPECT_FALSE(p.status().position_valid);
  EXPECT_EQ(p.status().bursts, bursts) << "nothing is played after the beam is lost";
  EXPECT_FALSE(rig.sim->running());
  EXPECT_EQ(rig.sim->commanded_elongation_m(), 0.0);
  // Commands are refused until reset_fault(); the fault stays while the beam is out.
  EXPECT_EQ(p.move_relative(1e-6), Refusal::Faulted);
  p.reset_fault();
  rig.run_for(0.005);  // the next readings at rest
  EXPECT_EQ(p.status().state, MotionState::Fault);
  rig.sim->set_beam_lost(false);
  p.reset_fault();
  rig.run_for(0.005);
  EXPECT_EQ(p.status().state, MotionState::Idle);
  EXPECT_TRUE(p.status().position_valid);
}

TEST(Positioner, BeamLossWhileAChunkPlaysStopsTheOutputAtOnce) {
  // Wall clock: the chunk is really playing when the beam goes; the output is stopped before the
  // chunk ends.
  drivers::sim::SimDeviceConfig cfg = ideal_device();
  cfg.clock = drivers::sim::ClockMode::Wall;
  Rig rig(ideal_map(), cfg);
  Positioner& p = *rig.positioner;
  ASSERT_EQ(p.move_relative(1e-3), Refusal::None);
  while (!rig.sim->running() && p.status().state != MotionState::Fault) rig.tick();
  ASSERT_EQ(p.status().state, MotionState::Moving);
  ASSERT_TRUE(rig.sim->running());
  const double end_s = rig.sim->now_s() + 0.9 * p.last_plan().bursts.front().duration_s();
  rig.sim->set_beam_lost(true);
  // Ticks (as the real-time loop would) until the first lost word is read.
  while (p.status().state == MotionState::Moving && rig.sim->now_s() < end_s) rig.tick();
  EXPECT_EQ(p.status().state, MotionState::Fault);
  EXPECT_EQ(p.status().fault, MotionFault::InvalidSample);
  EXPECT_LT(rig.sim->now_s(), end_s) << "the fault came before the chunk's end";
  EXPECT_FALSE(rig.sim->running());
  EXPECT_EQ(rig.sim->commanded_elongation_m(), 0.0);
}

TEST(Positioner, StallFaultsAfterStallBursts) {
  PositionerConfig cfg;
  cfg.stall_bursts = 3;
  Rig rig(ideal_map(), ideal_device(), cfg);
  Positioner& p = *rig.positioner;
  const double start = rig.sim->true_position_m();
  rig.sim->set_slider_stalled(true);
  ASSERT_EQ(p.move_relative(1e-3), Refusal::None);
  EXPECT_EQ(rig.run(), MotionState::Fault);
  EXPECT_EQ(p.status().fault, MotionFault::Stall);
  EXPECT_EQ(p.status().bursts, 3u);
  EXPECT_EQ(rig.sim->true_position_m(), start);
  EXPECT_FALSE(rig.sim->running());
  EXPECT_EQ(rig.sim->commanded_elongation_m(), 0.0);
}

TEST(Positioner, StopMidMoveEndsAfterThePlayingChunk) {
  PositionerConfig cfg;
  cfg.max_chunk_s = 0.02;
  Rig rig(ideal_map(), ideal_device(), cfg);
  Positioner& p = *rig.positioner;
  const double start = p.status().position_m;
  ASSERT_EQ(p.move_relative(1e-3), Refusal::None);
  // Right after the second chunk started (it is playing).
  ASSERT_TRUE(rig.run_until([&] { return p.status().bursts >= 2; }));
  ASSERT_EQ(p.status().state, MotionState::Moving);
  const double cycles = static_cast<double>(p.move_cycles());
  p.stop();
  EXPECT_EQ(rig.run(), MotionState::Idle);
  EXPECT_EQ(p.status().fault, MotionFault::None);
  EXPECT_EQ(p.status().bursts, 2u) << "nothing is played after the chunk that was playing";
  EXPECT_EQ(static_cast<double>(p.move_cycles()), cycles) << "the playing chunk ends whole";
  // At rest with the actuator at 0, short of the target, position read.
  EXPECT_EQ(rig.sim->commanded_elongation_m(), 0.0);
  EXPECT_EQ(rig.sim->stage().velocity_m_s(), 0.0);
  EXPECT_TRUE(p.status().position_valid);
  EXPECT_GT(p.status().position_m - start, 1e-6);
  EXPECT_LT(p.status().position_m - start, 1e-3 - 1e-6);
  // A new move is accepted after the stop.
  EXPECT_EQ(p.move_absolute(start), Refusal::None);
  EXPECT_EQ(rig.run(), MotionState::Idle);
}

TEST(Positioner, ChunksAreWholeCyclesWithinMaxChunk) {
  PositionerConfig cfg;
  cfg.max_chunk_s = 0.01;
  Rig rig(ideal_map(), ideal_device(), cfg);
  Positioner& p = *rig.positioner;
  ASSERT_EQ(p.move_relative(300e-6), Refusal::None);
  std::uint64_t seen = 0, cycles_before = 0;
  while (!p.at_rest()) {
    rig.sim->advance_s(1e-4);
    rig.tick();
    if (p.status().bursts != seen) {
      // A chunk just started: whole cycles of the plan's first burst, at most max_chunk_s of
      // them (one cycle if a cycle is longer).
      seen = p.status().bursts;
      const Burst& b = p.last_plan().bursts.front();
      const std::uint64_t cycles = p.move_cycles() - cycles_before;
      cycles_before = p.move_cycles();
      EXPECT_GE(cycles, 1u);
      EXPECT_LE(cycles, b.cycles);
      if (cycles > 1) {
        EXPECT_LE(static_cast<double>(cycles) / b.freq_hz, cfg.max_chunk_s * (1 + 1e-9));
      }
    }
  }
  ASSERT_EQ(p.status().state, MotionState::Idle);
  // 300 um at <= 0.01 s per chunk: many chunks, and the cycles of each fit the limit.
  EXPECT_GE(p.move_chunks(), 5u);
}

TEST(Positioner, SoftLimitsRefuseBeforeAnythingMoves) {
  PositionerConfig cfg;
  cfg.soft_lower_m = -1e-3;
  cfg.soft_upper_m = 1e-3;
  Rig rig(ideal_map(), ideal_device(), cfg);
  Positioner& p = *rig.positioner;
  const double start = rig.sim->true_position_m();
  EXPECT_EQ(p.move_absolute(1.5e-3), Refusal::OutsideSoftLimits);
  EXPECT_EQ(p.move_relative(-2e-3), Refusal::OutsideSoftLimits);
  EXPECT_EQ(p.step_open_loop(2000), Refusal::OutsideSoftLimits);  // ~2 um steps: 4 mm
  EXPECT_EQ(p.status().state, MotionState::Idle);
  rig.run();
  EXPECT_EQ(p.status().bursts, 0u);
  EXPECT_EQ(p.status().moves, 0u);
  EXPECT_EQ(rig.sim->true_position_m(), start);
  // Narrowed limits apply to the next command; inside them a move goes.
  EXPECT_EQ(p.set_soft_limits(-1e-4, 1e-4), Refusal::None);
  EXPECT_EQ(p.set_soft_limits(1e-4, -1e-4), Refusal::OutOfRange);
  EXPECT_EQ(p.move_absolute(5e-4), Refusal::OutsideSoftLimits);
  EXPECT_EQ(p.move_absolute(5e-5), Refusal::None);
  EXPECT_EQ(rig.run(), MotionState::Idle);
  EXPECT_LE(std::fabs(p.status().position_m - 5e-5), p.count_m());
}

TEST(Positioner, RefusesBadArgumentsAndBusy) {
  Rig rig(ideal_map(), ideal_device());
  Positioner& p = *rig.positioner;
  EXPECT_EQ(p.move_absolute(std::nan("")), Refusal::NotFinite);
  EXPECT_EQ(p.move_relative(INFINITY), Refusal::NotFinite);
  EXPECT_EQ(p.step_open_loop(0), Refusal::OutOfRange);
  EXPECT_EQ(p.step_open_loop(5, 0.5, 200, 20e-6), Refusal::OutOfRange);
  EXPECT_EQ(p.step_open_loop(5, 0.1, 5000, 20e-6), Refusal::OutOfRange);  // above 2 kHz
  EXPECT_EQ(p.step_open_loop(5, 0.1, 200, 30e-6), Refusal::OutOfRange);   // stroke too large
  ASSERT_EQ(p.move_relative(1e-4), Refusal::None);
  EXPECT_EQ(p.move_relative(1e-4), Refusal::Busy);
  EXPECT_EQ(p.step_open_loop(3), Refusal::Busy);
  EXPECT_FALSE(p.at_rest());
  EXPECT_EQ(rig.run(), MotionState::Idle);
  EXPECT_STREQ(motion_state_name(MotionState::Settling), "SETTLING");
  EXPECT_STREQ(motion_fault_name(MotionFault::RetryLimit), "retry_limit");
  EXPECT_STREQ(refusal_name(Refusal::OutsideSoftLimits), "outside_soft_limits");
}

TEST(Positioner, RefusesAnInterferometerTooSlowForTheMap) {
  drivers::sim::SimDeviceConfig cfg = ideal_device();
  cfg.interferometer.word.max_velocity_m_s = 0.1;
  try {
    Rig rig(ideal_map(), cfg);
    FAIL() << "a decoder that takes the slider's jumps for glitches must be refused";
  } catch (const model::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("interferometer.max_velocity_m_s"), std::string::npos)
        << e.what();
  }
}

TEST(Positioner, ConfigErrorsNameTheKey) {
  PositionerConfig bad;
  bad.max_chunk_s = 0;
  try {
    validate(bad);
    FAIL();
  } catch (const model::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("control.max_chunk_s"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("(0, 10]"), std::string::npos) << e.what();
  }
  bad = {};
  bad.soft_lower_m = 1;
  bad.soft_upper_m = 0;
  EXPECT_THROW(validate(bad), model::InputError);
}

TEST(Positioner, OpenLoopStepMovesByTheNominalSteps) {
  Rig rig(ideal_map(), ideal_device());
  Positioner& p = *rig.positioner;
  const double start = rig.sim->true_position_m();
  // 200 Hz, duty 0.9 (positive), full stroke: one-step on the ideal plant.
  ASSERT_EQ(p.step_open_loop(50, 0.9, 200, 20.35e-6), Refusal::None);
  ASSERT_EQ(rig.run(), MotionState::Idle);
  const double step =
      model::steady_step_corrected_m(ideal_map().config().stage, 200, 0.9, 20.35e-6);
  const double moved = rig.sim->true_position_m() - start;
  EXPECT_GT(step, 0);
  EXPECT_NEAR(moved, 50 * step, 2 * std::fabs(step));
  EXPECT_FALSE(p.status().closed_loop);
  // Negative cycles mirror the duty.
  ASSERT_EQ(p.step_open_loop(-50, 0.9, 200, 20.35e-6), Refusal::None);
  ASSERT_EQ(rig.run(), MotionState::Idle);
  EXPECT_NEAR(rig.sim->true_position_m(), start, 4 * std::fabs(step));
}

TEST(Positioner, InvalidSamplesFault) {
  // Flagged glitches during a move.
  {
    Rig rig(ideal_map(), ideal_device());
    Positioner& p = *rig.positioner;
    ASSERT_EQ(p.move_relative(5e-4), Refusal::None);
    ASSERT_TRUE(rig.run_until([&] { return p.status().bursts >= 1; }));
    rig.sim->set_glitch_probability(0.01, true);
    EXPECT_EQ(rig.run(), MotionState::Fault);
    EXPECT_EQ(p.status().fault, MotionFault::InvalidSample);
    EXPECT_EQ(rig.sim->commanded_elongation_m(), 0.0);
  }
  // Unflagged glitches (a wild count without the board's bit) at rest: the decoder's jump check.
  {
    Rig rig(ideal_map(), ideal_device());
    Positioner& p = *rig.positioner;
    rig.sim->set_glitch_probability(0.5, false);
    rig.run_for(0.05);
    EXPECT_EQ(p.status().state, MotionState::Fault);
    EXPECT_EQ(p.status().fault, MotionFault::InvalidSample);
    EXPECT_EQ(p.move_relative(1e-6), Refusal::Faulted);
  }
  // No valid position at start: moves are refused (the position is not guessed).
  {
    drivers::sim::SimDeviceConfig cfg = ideal_device();
    cfg.faults.beam_lost = true;
    Rig rig(ideal_map(), cfg);
    Positioner& p = *rig.positioner;
    EXPECT_EQ(p.status().state, MotionState::Fault);
    EXPECT_FALSE(p.status().position_valid);
    EXPECT_EQ(p.move_relative(1e-6), Refusal::Faulted);
  }
}

TEST(Positioner, ADeviceLostMidMoveFaultsAndStaysFaultedWhenItComesBack) {
  Rig rig(ideal_map(), ideal_device());
  Positioner& p = *rig.positioner;
  ASSERT_EQ(p.move_relative(1e-3), Refusal::None);
  ASSERT_TRUE(rig.run_until([&] { return p.status().bursts >= 1; }));
  rig.sim->disconnect();
  EXPECT_EQ(rig.run(), MotionState::Fault);
  EXPECT_EQ(p.status().fault, MotionFault::DeviceLost);
  EXPECT_FALSE(p.status().position_valid);
  const drivers::LinkHealth h = rig.link->health();
  EXPECT_EQ(h.state, drivers::LinkState::Lost);
  EXPECT_NE(std::string(h.message).find("disconnected"), std::string::npos) << h.message;
  // The link reconnects by itself once the device is back; the cut-short move stays a fault.
  rig.sim->reconnect();
  rig.run_for(0.5);
  EXPECT_EQ(rig.link->health().state, drivers::LinkState::Up);
  EXPECT_EQ(rig.link->health().reconnects, 1u);
  EXPECT_EQ(p.status().state, MotionState::Fault);
  EXPECT_TRUE(p.status().position_valid);
  p.reset_fault();
  EXPECT_EQ(p.status().state, MotionState::Idle);
  EXPECT_EQ(p.move_relative(2e-6), Refusal::None);
  EXPECT_EQ(rig.run(), MotionState::Idle);
}

TEST(Positioner, ADeviceLostAtRestThatKeptItsCountCarriesOn) {
  Rig rig(ideal_map(), ideal_device());
  Positioner& p = *rig.positioner;
  rig.run_for(0.01);
  const double before = p.status().position_m;
  rig.sim->disconnect();
  rig.run_for(0.01);
  EXPECT_EQ(p.status().fault, MotionFault::DeviceLost);
  EXPECT_FALSE(p.status().position_valid);
  rig.sim->reconnect();
  rig.run_for(0.5);
  EXPECT_EQ(p.status().state, MotionState::Idle);
  EXPECT_TRUE(p.status().position_valid);
  EXPECT_NEAR(p.status().position_m, before, 2 * p.count_m());
}

TEST(Positioner, APowerCycledDeviceContinuesFromTheLastPositionAndStaysFaulted) {
  drivers::sim::SimDeviceConfig cfg = ideal_device();
  cfg.sim.start_position_m = 0;
  Rig rig(ideal_map(), cfg);
  Positioner& p = *rig.positioner;
  ASSERT_EQ(p.move_relative(40e-6), Refusal::None);
  ASSERT_EQ(rig.run(), MotionState::Idle);
  const double before = p.status().position_m;
  const drivers::CountOrigin origin = rig.link->count_origin(0);
  EXPECT_TRUE(origin.has_epoch);
  EXPECT_EQ(origin.offset_counts, 0);
  rig.sim->power_cycle();  // the device restarts counting from its start position
  rig.run_for(0.01);
  rig.sim->reconnect();
  rig.run_for(0.5);
  // Positions continue from the last good reading (not re-based to the device's new zero), and
  // the axis stays in fault: a reset must acknowledge that counts may have been lost.
  EXPECT_TRUE(p.status().position_valid);
  EXPECT_NEAR(p.status().position_m, before, 2 * p.count_m());
  EXPECT_EQ(p.status().fault, MotionFault::DeviceLost);
  // The count's origin says so: a new epoch, and the link's offset is the 40 um it re-based.
  const drivers::CountOrigin after = rig.link->count_origin(0);
  EXPECT_TRUE(after.has_epoch);
  EXPECT_NE(after.epoch, origin.epoch);
  EXPECT_NEAR(static_cast<double>(after.offset_counts) * p.count_m(), before, 2 * p.count_m());
}

TEST(Positioner, ASimulatedDeviceCountsAfreshInEveryProcessAndSaysSo) {
  // Two devices built alike (as two runs of idmd would build them) have different epochs: the
  // simulated stage lives in idmd, so a reference saved by one run never holds in the next.
  Rig a(ideal_map(), ideal_device()), b(ideal_map(), ideal_device());
  EXPECT_NE(a.link->count_origin(0).epoch, b.link->count_origin(0).epoch);
  a.link->continue_count(0, 1234);
  EXPECT_EQ(a.link->count_origin(0).offset_counts, 1234);
  a.run_for(0.05);
  EXPECT_NEAR(a.positioner->status().position_m, 1234 * a.positioner->count_m(),
              2 * a.positioner->count_m());
}

// The controller on its own, fed by hand: no device, no link. What it asks of the output, and
// what it makes of what the output reports.
TEST(Positioner, IsPureEventsInRequestsOut) {
  AxisDeviceInfo device;
  device.count_m = 9.8906e-9;
  device.max_velocity_m_s = 1.0;
  Positioner p(ideal_map(), PlannerConfig{}, PositionerConfig{}, device);
  using Kind = model::AxisEvent::Kind;
  const auto reading = [](double t, double x) {
    model::AxisEvent e;
    e.kind = Kind::Reading;
    e.t_s = t;
    e.position_m = x;
    return e;
  };
  model::OutputRequest r;
  EXPECT_FALSE(p.tick(0.0, r));  // nothing to say at rest
  p.on_event(reading(0.0, 1e-6));
  EXPECT_TRUE(p.status().position_valid);
  EXPECT_DOUBLE_EQ(p.status().target_m, 1e-6);  // VAL = RBV before the first move
  ASSERT_EQ(p.move_relative(50e-6), Refusal::None);
  // It wants fresh readings taken after the command, then plays a chunk toward the target.
  ASSERT_TRUE(p.tick(0.001, r));
  EXPECT_EQ(r.kind, model::OutputRequest::Kind::Read);
  const int words = PositionerConfig{}.latch_words;
  EXPECT_EQ(r.readings, static_cast<std::uint32_t>(words));
  EXPECT_FALSE(p.tick(0.0011, r));
  for (int i = 0; i < words; ++i) p.on_event(reading(0.0012, 1e-6));
  ASSERT_TRUE(p.tick(0.0013, r));
  ASSERT_EQ(r.kind, model::OutputRequest::Kind::Play);
  EXPECT_GT(r.segment.cycles, 0u);
  EXPECT_GT(r.segment.duty, 0.5);  // this stage moves positive with a slow extension
  EXPECT_EQ(p.status().state, MotionState::Moving);
  // The output fails that segment: a driver fault, and the output is told to stop.
  model::AxisEvent failed;
  failed.kind = Kind::OutputFailed;
  failed.seq = r.seq;
  p.on_event(failed);
  EXPECT_EQ(p.status().state, MotionState::Fault);
  EXPECT_EQ(p.status().fault, MotionFault::Driver);
  ASSERT_TRUE(p.tick(0.002, r));
  EXPECT_EQ(r.kind, model::OutputRequest::Kind::Stop);
  // An event about an older segment changes nothing.
  p.reset_fault();
  failed.seq = 12345;
  p.on_event(failed);
  EXPECT_EQ(p.status().state, MotionState::Idle);
}

TEST(Positioner, RetryLimitFaultsWhenTheStageNeverArrives) {
  // The map believes steps are 4x smaller than the plant makes them (alpha 0.25 vs 1): the
  // last bursts always overshoot; without retries left that is a fault, not an endless loop.
  static const RegionMap wrong(test_rig::rig_map_config(0.25));
  PositionerConfig cfg;
  cfg.max_retries = 1;
  cfg.approach_uncertainty = 0;
  Rig rig(wrong, ideal_device(), cfg);
  Positioner& p = *rig.positioner;
  ASSERT_EQ(p.move_relative(3e-7), Refusal::None);
  EXPECT_EQ(rig.run(), MotionState::Fault);
  EXPECT_EQ(p.status().fault, MotionFault::RetryLimit);
  EXPECT_EQ(p.status().corrections, 1u);
  EXPECT_EQ(rig.sim->commanded_elongation_m(), 0.0);
}

}  // namespace

namespace {

// A map that predicts a third of what the stage moves (the bench's alpha 0.35 on the ideal
// plant, as config/idmd-modbus.yaml against idm-simdev): its finest rungs are seeded under
// min_step_counts, yet move about a count. The ladder scales the seeds of the rungs it has not
// played by what the played ones showed, so the first move of a fresh ladder lands (the seeds
// as they were ping-ponged 2-3 counts around the target until retry_limit: 1 move in 30 on
// the Modbus device).
TEST(Positioner, AMapThatUnderpredictsTheStageThreefoldStillLandsTheFirstMove) {
  static const RegionMap under(test_rig::rig_map_config(0.35));
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> log_distance(std::log(2e-6), std::log(60e-6));
  int faults = 0;
  for (int i = 0; i < 16; ++i) {
    Rig rig(under, ideal_device());
    Positioner& p = *rig.positioner;
    const double distance = std::exp(log_distance(rng)) * (i % 2 == 0 ? 1 : -1);
    const double target = p.status().position_m + 0.37 * p.count_m() * i + distance;
    ASSERT_EQ(p.move_absolute(target), Refusal::None);
    const MotionState end = rig.run();
    faults += end != MotionState::Idle;
    EXPECT_EQ(end, MotionState::Idle)
        << "move " << i << " of " << distance << ": " << motion_fault_name(p.status().fault)
        << " after " << p.status().corrections << " corrections";
    EXPECT_LE(std::fabs(p.status().position_m - target), 0.5 * p.count_m()) << "move " << i;
  }
  EXPECT_EQ(faults, 0);
}

const RegionMap& realistic_map() {
  static const RegionMap map(test_rig::realistic_map_config());
  return map;
}

// On the realistic plant the map's predictions are off by 0.3x .. 0.8x and its finest cells do
// not move at all; the ladder learns which rungs move and how far.
TEST(PositionerRealistic, ConvergesWithinOneCount) {
  Calibration cal(realistic_map().config().stage);
  Rig rig(realistic_map(), test_rig::realistic_device(3), {}, &cal);
  Positioner& p = *rig.positioner;
  const double distances[] = {-2.3e-6, 47e-9, 180e-6, -31e-9, 12.5e-6, -0.6e-6, 3.1e-3, -90e-9};
  for (double d : distances) {
    const double target = p.status().position_m + d;
    ASSERT_EQ(p.move_absolute(target), Refusal::None);
    ASSERT_EQ(rig.run(), MotionState::Idle) << d << ": " << motion_fault_name(p.status().fault);
    EXPECT_LE(std::fabs(p.status().position_m - target), p.count_m())
        << d << ": " << move_result_name(p.status().result);
    EXPECT_LE(std::fabs(rig.sim->true_position_m() - target), 3 * p.count_m()) << d;
    EXPECT_EQ(rig.sim->commanded_elongation_m(), 0.0);
  }
}

// A move that ends OK has the slider within the window, however noisy the reading: on a
// lambda/128 stage (one count 4.9 nm) read with 3.5 nm rms of noise, the mean of latch_words (8)
// readings has a standard error of 1.2 nm against the 2.5 nm from the landing's edge to the
// window's, and said arrived with the slider more than a count off in 3 of 8 seeds of 80 moves
// (1.01-1.09 counts). The mean that says arrived is read until the window's edge lies 4 standard
// errors beyond it (the scatter pooled over the batches: 8 readings alone misjudge it).
TEST(Positioner, AMoveThatEndsOkHasTheSliderWithinTheWindowUnderANoisyReading) {
  const char* env = std::getenv("IDM_TEST_SEED");
  const std::uint64_t seed =
      env != nullptr ? std::strtoull(env, nullptr, 10) : std::random_device{}();
  std::mt19937_64 rng(seed);
  drivers::sim::SimDeviceConfig dev = test_rig::ideal_device();
  dev.sim.noise_m = 3.5e-9;
  dev.sim.seed = seed;
  dev.interferometer.word.optics = drivers::Optics::PlaneMirror;
  Rig rig(ideal_map(), dev);
  Positioner& p = *rig.positioner;
  int ok = 0;
  for (int k = 0; k < 80; ++k) {
    const double d =
        std::exp(std::uniform_real_distribution<double>(std::log(20e-9), std::log(30e-6))(rng));
    const double target = rng() % 2 ? d : -d;  // about 0: well inside the soft limits
    ASSERT_EQ(p.move_absolute(target), Refusal::None);
    rig.run();
    if (p.status().result != MoveResult::Ok) {
      std::printf("move %d to %.4g m: %s %s\n", k, target, move_result_name(p.status().result),
                  motion_fault_name(p.status().fault));
      p.reset_fault();
      continue;
    }
    ++ok;
    EXPECT_LE(std::fabs(rig.sim->true_position_m() - target), p.count_m())
        << "move " << k << " to " << target << " m ended OK "
        << (rig.sim->true_position_m() - target) / p.count_m() << " counts off; seed " << seed;
  }
  EXPECT_GE(ok, 50) << "seed " << seed;
}

TEST(PositionerRealistic, DeadRungsAreSkippedAndTheMoveConverges) {
  Rig rig(realistic_map(), test_rig::realistic_device(5));
  Positioner& p = *rig.positioner;
  // Short moves both ways: the map's finest rungs (0.1 um stroke) do not move on this plant.
  for (int i = 0; i < 8; ++i) {
    const double target = p.status().position_m + (i % 2 == 0 ? 60e-9 : -45e-9);
    ASSERT_EQ(p.move_absolute(target), Refusal::None);
    ASSERT_EQ(rig.run(), MotionState::Idle) << i << ": " << motion_fault_name(p.status().fault);
    EXPECT_LE(std::fabs(p.status().position_m - target), p.count_m()) << i;
  }
  std::size_t dead = 0, proven = 0;
  for (int dir : {-1, 1}) {
    for (std::size_t i = 0; i < p.rung_count(dir); ++i) {
      dead += p.rung(dir, i).dead;
      proven += p.rung(dir, i).proven;
    }
  }
  EXPECT_GT(dead, 0u) << "some rungs of the map do not move here";
  EXPECT_GT(proven, 0u);
  // Mark the most used rung of each direction dead (as if it had stopped moving): the move goes
  // on with the others, and still converges.
  for (int dir : {-1, 1}) {
    std::size_t most = 0;
    for (std::size_t i = 0; i < p.rung_count(dir); ++i)
      if (p.rung(dir, i).chunks > p.rung(dir, most).chunks) most = i;
    p.mark_rung_dead(dir, most);
    EXPECT_TRUE(p.rung(dir, most).dead);
  }
  const double target = p.status().position_m + 0.8e-6;
  ASSERT_EQ(p.move_absolute(target), Refusal::None);
  ASSERT_EQ(rig.run(), MotionState::Idle) << motion_fault_name(p.status().fault);
  EXPECT_LE(std::fabs(p.status().position_m - target), p.count_m());
}

// Calibration on the realistic plant: the second round of the same moves needs fewer chunks and
// cycles than the first (the rung estimates start from what the first round measured). Summed
// over three stretches of guide (device seeds 11-13): on one alone the landing's tries vary by
// tens of per cent. The seeds are fixed: on this plant about one move in 30 of drawn seeds ends
// at retry_limit (before the landing plan too: seeds 20 and 80 of 8 x 30 moves; with it, 52),
// which is bench/stages_bench's business, not this test's.
TEST(PositionerRealistic, CalibrationMakesTheSecondRoundCheaper) {
  constexpr unsigned long long base = 11;
  std::uint64_t chunks[2] = {0, 0}, cycles[2] = {0, 0};
  std::uint32_t corrections[2] = {0, 0};
  for (std::uint64_t device_seed = base; device_seed < base + 3; ++device_seed) {
    Calibration cal(realistic_map().config().stage);
    Rig rig(realistic_map(), test_rig::realistic_device(device_seed), {}, &cal);
    Positioner& p = *rig.positioner;
    const double targets[] = {25.3e-6, -3.21e-6, 412e-9, -61.7e-6, 1.9e-6};
    for (int round = 0; round < 2; ++round) {
      for (double target : targets) {
        for (double t : {target, 0.0}) {
          ASSERT_EQ(p.move_absolute(t), Refusal::None) << "device seed " << device_seed;
          ASSERT_EQ(rig.run(), MotionState::Idle)
              << motion_fault_name(p.status().fault) << ", device seed " << device_seed;
          EXPECT_LE(std::fabs(p.status().position_m - t), p.count_m())
              << "device seed " << device_seed;
          chunks[round] += p.move_chunks();
          cycles[round] += p.move_cycles();
          corrections[round] += p.status().corrections;
        }
      }
    }
    EXPECT_GT(cal.state().rung_count[0] + cal.state().rung_count[1], 0);
  }
  std::printf(
      "realistic plant, device seeds %llu-%llu: chunks %llu -> %llu, cycles %llu -> %llu, "
      "corrections %u -> %u\n",
      base, base + 2, static_cast<unsigned long long>(chunks[0]),
      static_cast<unsigned long long>(chunks[1]), static_cast<unsigned long long>(cycles[0]),
      static_cast<unsigned long long>(cycles[1]), corrections[0], corrections[1]);
  // Chunks are the reads-and-corrections of a move (the motor record's retries count only the
  // final chunks played whole, which a rung with a learned scatter plays more often).
  EXPECT_LT(chunks[1] * 10, chunks[0] * 8) << "at least 20 % fewer chunks; seed " << base;
  EXPECT_LT(cycles[1], cycles[0]) << "seed " << base;
}

}  // namespace
