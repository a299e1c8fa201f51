// The position a client sees at rest (the mean of the latest readings) and what a run of chunks
// that did not move says (never an end of travel when the slider moved back), on the pure
// interface: the positioner fed by hand.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "positioner_rig.h"

using namespace idm;
using namespace idm::control;
using idm::control::test_rig::ideal_map;

namespace {

// One valid reading of x_m at t_s, as the device link delivers it.
void feed_reading(Positioner& p, double t_s, double x_m, bool in_segment = false) {
  model::AxisEvent e;
  e.kind = model::AxisEvent::Kind::Reading;
  e.t_s = t_s;
  e.position_m = x_m;
  e.in_segment = in_segment;
  p.on_event(e);
}

TEST(RestMean, TheMeanOfTheLatestWordsWithoutDrift) {
  RestMean m;
  m.reset(4);
  EXPECT_DOUBLE_EQ(m.add(1.0), 1.0);
  EXPECT_DOUBLE_EQ(m.add(2.0), 1.5);
  EXPECT_DOUBLE_EQ(m.add(3.0), 2.0);
  EXPECT_DOUBLE_EQ(m.add(4.0), 2.5);
  EXPECT_DOUBLE_EQ(m.add(5.0), 3.5);  // the oldest left
  EXPECT_EQ(m.count(), 4);
  // Large values then small ones: the running sum would keep their rounding, the mean does not.
  for (int i = 0; i < 1001; ++i) m.add(1e3 + 0.1 * i);
  // (the sum is summed afresh once a round: a round after the last large value, none is left).
  for (int i = 0; i < 8; ++i) m.add(1e-9 * (i + 1));
  EXPECT_NEAR(m.add(9e-9), 7.5e-9, 1e-22);
  m.reset(0);  // clamped to one word
  m.add(7.0);
  EXPECT_DOUBLE_EQ(m.add(8.0), 8.0);
  m.reset(1 << 20);  // clamped to kMaxWords
  for (int i = 0; i < RestMean::kMaxWords + 10; ++i) m.add(i < 10 ? 1e6 : 2.0);
  EXPECT_EQ(m.count(), RestMean::kMaxWords);
  EXPECT_DOUBLE_EQ(m.add(2.0), 2.0);
  // A shift of the frame moves every reading held, the partial ring too: the mean goes on in the
  // new frame (a reference that set the offset while fresh readings were held).
  m.reset(4);
  m.add(1.0);
  m.add(3.0);
  m.shift(10.0);
  EXPECT_DOUBLE_EQ(m.add(12.0), 12.0);   // 11, 13, 12
  EXPECT_DOUBLE_EQ(m.add(16.0), 13.0);   // 11, 13, 12, 16
  EXPECT_DOUBLE_EQ(m.add(16.0), 14.25);  // the oldest (11) left
}

// At rest the position shown is the mean of the latest latch_words readings (a slider at a
// count's edge reads one count or the next: the mean does not jump); moving, the latest reading;
// a motion starts the mean over.
TEST(Positioner, AtRestThePositionShownIsTheMeanOfTheLatestReadings) {
  AxisDeviceInfo device;
  device.count_m = 9.8906e-9;
  device.max_velocity_m_s = 1.0;
  PositionerConfig cfg;
  cfg.latch_words = 4;
  Positioner p(ideal_map(), PlannerConfig{}, cfg, device);
  const auto reading = [&p](double t, double x, bool in_segment = false) {
    feed_reading(p, t, x, in_segment);
  };
  const double a = 1e-6, b = a + device.count_m;
  reading(0.0, a);
  EXPECT_DOUBLE_EQ(p.status().position_m, a);
  reading(0.001, b);
  EXPECT_DOUBLE_EQ(p.status().position_m, 0.5 * (a + b));
  reading(0.002, b);
  reading(0.003, b);
  EXPECT_DOUBLE_EQ(p.status().position_m, 0.25 * (a + 3 * b));
  reading(0.004, b);  // the first reading has left the mean
  EXPECT_DOUBLE_EQ(p.status().position_m, b);
  // A move: its readings are shown as they come.
  ASSERT_EQ(p.move_relative(50e-6), Refusal::None);
  model::OutputRequest r;
  ASSERT_TRUE(p.tick(0.005, r));
  ASSERT_EQ(r.kind, model::OutputRequest::Kind::Read);
  for (int i = 0; i < 4; ++i) reading(0.0051, b);
  ASSERT_TRUE(p.tick(0.0052, r));
  ASSERT_EQ(r.kind, model::OutputRequest::Kind::Play);
  reading(0.006, 3e-6, true);
  EXPECT_DOUBLE_EQ(p.status().position_m, 3e-6);
  reading(0.007, 4e-6, true);
  EXPECT_DOUBLE_EQ(p.status().position_m, 4e-6);
  // Stopped: at rest again, the mean starts from the readings at rest: the fresh ones the end of
  // the motion asked for (after the settle) are its first, none of the move's.
  p.stop();
  model::AxisEvent done;
  done.kind = model::AxisEvent::Kind::SegmentDone;
  done.seq = r.seq;
  done.t_s = 0.008;
  p.on_event(done);
  const double c = device.count_m;
  std::vector<double> at_rest;  // every reading at rest since the stop, in order
  const auto mean_of_latest_four = [&at_rest] {
    double sum = 0;
    for (std::size_t i = at_rest.size() - 4; i < at_rest.size(); ++i) sum += at_rest[i];
    return sum / 4;
  };
  for (double t = 0.008; t < 0.05 && !p.at_rest(); t += 0.001) {
    if (p.tick(t, r) && r.kind == model::OutputRequest::Kind::Read)
      for (std::uint32_t i = 0; i < r.readings; ++i) {
        at_rest.push_back(5e-6 + static_cast<double>(at_rest.size() % 2) * c);
        reading(t, at_rest.back());
      }
  }
  ASSERT_TRUE(p.at_rest());
  ASSERT_GE(at_rest.size(), 4u);
  // Right at the end: the mean of the latest four fresh readings (two at 5 um, two a count on),
  // not the last single word; then the mean goes on over the readings at rest.
  EXPECT_DOUBLE_EQ(p.status().position_m, mean_of_latest_four());
  EXPECT_NEAR(p.status().position_m, 5e-6 + 0.5 * c, 1e-15);
  for (int k = 0; k < 4; ++k) {
    at_rest.push_back(5e-6 + c);
    reading(0.06 + 0.001 * k, at_rest.back());
    EXPECT_DOUBLE_EQ(p.status().position_m, mean_of_latest_four()) << k;
  }
  EXPECT_DOUBLE_EQ(p.status().position_m, 5e-6 + c);
}

// A scripted stage on the pure interface: every chunk played moves the slider by what
// `moved_by(segment)` says; readings at rest answer the positioner's requests.
struct ScriptedStage {
  Positioner& p;
  double x_m = 1e-6;
  double t_s = 0;
  void reading(bool in_segment = false) { feed_reading(p, t_s, x_m, in_segment); }
  template <class MovedBy>
  void run(MovedBy&& moved_by) {
    model::OutputRequest r;
    for (int k = 0; k < 200000 && !(k > 0 && p.at_rest()); ++k) {
      t_s += 1e-4;
      if (!p.tick(t_s, r)) continue;
      if (r.kind == model::OutputRequest::Kind::Read) {
        for (std::uint32_t i = 0; i < r.readings; ++i) reading();
      } else if (r.kind == model::OutputRequest::Kind::Play) {
        x_m += moved_by(r.segment);
        model::AxisEvent done;
        done.kind = model::AxisEvent::Kind::SegmentDone;
        done.seq = r.seq;
        done.t_s = t_s;
        p.on_event(done);
      }
    }
  }
};

// Mid-travel the stage creeps the wrong way on every chunk one way (friction along the guide
// defeating the cells the ladder tries): the rungs are left out, and the move ends as a
// stall or with every rung gone, never as an end of travel (which would refuse every later move
// that way though nothing stops the slider there).
TEST(Positioner, CreepingTheWrongWayIsNotAnEndOfTravel) {
  AxisDeviceInfo device;
  device.count_m = 9.8906e-9;
  device.max_velocity_m_s = 1.0;
  Positioner p(ideal_map(), PlannerConfig{}, PositionerConfig{}, device);
  ScriptedStage stage{p};
  stage.reading();
  // Negative moves work at first (the slider has moved that way).
  const auto as_predicted = [&](const model::Segment& seg) {
    const RegionMap& map = ideal_map();
    for (const RegionCell& c : map.cells())
      if (c.freq_hz == seg.freq_hz && c.duty == seg.duty && c.stroke_m == seg.stroke_m)
        return c.step_m * static_cast<double>(seg.cycles);
    return 0.0;
  };
  ASSERT_EQ(p.move_absolute(stage.x_m - 30e-6), Refusal::None);
  stage.run(as_predicted);
  ASSERT_EQ(p.status().result, MoveResult::Ok) << motion_fault_name(p.status().fault);
  // Then every negative chunk creeps the wrong way, 3 nm a cycle (more than eot_step_m: a slider
  // at a stop does not move, a slider moving back is not at one).
  ASSERT_EQ(p.move_absolute(stage.x_m - 2e-6), Refusal::None);
  stage.run([](const model::Segment& seg) { return 3e-9 * static_cast<double>(seg.cycles); });
  EXPECT_NE(p.status().result, MoveResult::Ok);
  EXPECT_NE(p.status().result, MoveResult::EndOfTravel);
  EXPECT_EQ(p.status().eot, 0);
}

}  // namespace

// In position follows the readings at rest: after a move arrived, a push (or a drift, or a sweep's
// trial) that takes the mean of the latest readings out of the window clears it, and MOVE:REL
// then counts from the reading, not from the target the slider left (a MOVE:REL 1e-6 after a
// 100 um push moved the stage back by all of it). Pushes of generated sizes, inside and outside
// the window.
TEST(Positioner, InPositionIsRecomputedFromEveryReadingAtRest) {
  AxisDeviceInfo device;
  device.count_m = 9.8906e-9;
  device.max_velocity_m_s = 1.0;
  PositionerConfig cfg;
  cfg.latch_words = 4;
  cfg.tolerance_m = 50e-9;
  std::mt19937 rng(17);
  std::uniform_real_distribution<double> push_m(-200e-9, 200e-9);
  for (int k = 0; k < 60; ++k) {
    Positioner p(ideal_map(), PlannerConfig{}, cfg, device);
    ScriptedStage stage{p};
    for (int i = 0; i < 4; ++i) stage.reading();
    const double target = stage.x_m + 20e-6;
    ASSERT_EQ(p.move_absolute(target), Refusal::None);
    stage.run([&](const model::Segment&) { return target - stage.x_m; });  // lands exactly
    ASSERT_EQ(p.status().result, MoveResult::Ok);
    ASSERT_TRUE(p.status().in_window);
    const double push = k == 0 ? 100e-6 : push_m(rng);
    stage.x_m += push;
    for (int i = 0; i < 4; ++i) {
      stage.t_s += 1e-3;
      stage.reading();
    }
    const bool inside = std::fabs(push) <= cfg.tolerance_m;
    EXPECT_EQ(p.status().in_window, inside) << push;
    ASSERT_EQ(p.move_relative(1e-6), Refusal::None);
    const double base = inside ? target : stage.x_m;
    EXPECT_NEAR(p.requested_target_m(), base + 1e-6, 1e-12) << push;
  }
}

// The device link's I/O thread sleeps while the link is idle (drivers::DeviceLink::idle_until_s):
// never while a segment plays or a request waits, never past one poll interval, and at rest
// until the next rest latch. Drawn moves and steps on the ideal plant, every tick checked.
TEST(LinkIdle, IdleOnlyWhenNothingPlaysOrWaitsAndNeverPastOnePollInterval) {
  test_rig::Rig rig(ideal_map(), test_rig::ideal_device());
  const double poll_s = drivers::LinkConfig{}.poll_interval_s;
  std::mt19937_64 rng(7);
  int idle_ticks = 0, busy_ticks = 0, moving_ticks = 0;
  const auto check = [&] {
    const double now = rig.sim->now_s();
    const double until = rig.link->idle_until_s(now);
    ASSERT_GE(until, now);
    ASSERT_LE(until, now + poll_s + 1e-12);
    const bool waiting = !rig.link->port(0).requests.empty();
    if (waiting) {
      ASSERT_EQ(until, now) << "a queued request must not wait";
    }
    (until > now ? idle_ticks : busy_ticks) += 1;
    if (rig.positioner->status().state == MotionState::Moving) ++moving_ticks;
  };
  for (int k = 0; k < 12; ++k) {
    const double here = rig.positioner->status().position_m;
    const Refusal r = rng() % 3 == 0
                          ? rig.positioner->step_open_loop(rng() % 2 ? 40 : -40)
                          : rig.positioner->move_absolute(
                                here + std::uniform_real_distribution<double>(-2e-4, 2e-4)(rng));
    ASSERT_EQ(r, Refusal::None);
    // Right after the command, the request is queued or playing: the link is not idle.
    step_axis(rig.link->port(0), *rig.positioner, rig.sim->now_s(), rig.pending);
    ASSERT_EQ(rig.link->idle_until_s(rig.sim->now_s()), rig.sim->now_s());
    for (int t = 0; t < 200000 && !rig.positioner->at_rest(); ++t) {
      rig.sim->advance_s(1e-4);
      rig.tick();
      check();
    }
    ASSERT_TRUE(rig.positioner->at_rest());
    for (int t = 0; t < 50; ++t) {  // at rest: idle between the latches
      rig.sim->advance_s(1e-4);
      rig.tick();
      check();
    }
    EXPECT_GT(rig.link->idle_until_s(rig.sim->now_s()), rig.sim->now_s());
    // A controller in a motion (the daemon's loop says so between chunks) keeps the link awake.
    rig.link->port(0).controller_active.store(true);
    EXPECT_EQ(rig.link->idle_until_s(rig.sim->now_s()), rig.sim->now_s());
    rig.link->port(0).controller_active.store(false);
  }
  EXPECT_GT(idle_ticks, 500);
  EXPECT_GT(busy_ticks, 100);
  EXPECT_GT(moving_ticks, 100);
}
