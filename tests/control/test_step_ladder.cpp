// The step ladder (control/step_ladder.h) on its own, without the positioner: on drawn stages, the
// rungs it builds, the promises of each choice, what it learns from a stage that steps g times the
// map's prediction, and its answers when nothing can move or land. The plant here is written
// apart from the ladder: a chunk of n cycles of a rung moves g (offset + n step) of the rung's
// seed (the map's own burst prediction), plus a drawn scatter.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <random>
#include <sstream>
#include <string>

#include "control/step_ladder.h"

namespace idm::control {
namespace {

std::uint64_t seed() {
  const char* s = std::getenv("IDM_TEST_SEED");
  return s != nullptr ? std::strtoull(s, nullptr, 10) : std::random_device{}();
}

constexpr double kCountM = 9.8906e-9;

// A stage drawn from the ranges the config can describe (issue 31: slider 0.05-0.5 kg, counter
// mass 0.02-0.2 kg, mu 0.15-0.7, stroke 5-50 um), on a coarse grid (10 Hz steps would take
// seconds a map): 50 Hz x duty 0.01 x 4 strokes down to 0.1 um.
RegionMapConfig drawn_stage(std::mt19937_64& rng, std::string& what) {
  std::uniform_real_distribution<double> u(0, 1);
  RegionMapConfig c;
  c.stage.slider_mass_kg = 0.05 + 0.45 * u(rng);
  c.stage.counter_mass_kg = 0.02 + 0.18 * u(rng);
  c.stage.friction_coefficient = 0.15 + 0.55 * u(rng);
  c.stage.stroke_m = 5e-6 + 45e-6 * u(rng);
  c.stage.step_correction = 0.3 + 0.7 * u(rng);
  c.limits.min_stroke_m = 0.1e-6;
  c.limits.max_stroke_m = c.stage.stroke_m;
  c.grid = RegionGrid::covering(c.limits, 50, 0.01, 4);
  std::ostringstream o;
  o << "M " << c.stage.slider_mass_kg << " m " << c.stage.counter_mass_kg << " mu "
    << c.stage.friction_coefficient << " S " << c.stage.stroke_m;
  what = o.str();
  return c;
}

ChunkLimits buffered_limits(const RegionMap& map) {
  ChunkLimits l;
  l.buffered = true;
  l.max_chunk_samples = 1u << 16;
  l.max_burst_cycles = map.config().limits.max_burst_cycles;
  return l;
}

// The plant: what a chunk of `cycles` of rung (dir, i) moves, signed.
double plant_move_m(const StepLadder& ladder, int dir, int i, std::uint64_t cycles, double gain,
                    double scatter, std::mt19937_64& rng) {
  const RungEstimate& s = ladder.at(dir, static_cast<std::size_t>(i)).seed;
  std::normal_distribution<double> n(0, 1);
  const double along = gain * s.predict_m(cycles) * (1 + scatter * n(rng));
  return dir * std::max(along, 0.0);
}

TEST(StepLadder, RungsAreUsableCellsOfTheirDirectionCoarseToFine) {
  std::mt19937_64 rng(seed());
  for (int k = 0; k < 4; ++k) {
    std::string what;
    const RegionMap map(drawn_stage(rng, what));
    const PositionerConfig config;
    StepLadder ladder(map, config, nullptr);
    ladder.build(kCountM, buffered_limits(map));
    for (int dir : {-1, 1}) {
      ASSERT_GT(ladder.size(dir), 0u) << what;
      EXPECT_LE(ladder.size(dir), static_cast<std::size_t>(CalibrationState::kMaxRungs));
      for (std::size_t i = 0; i < ladder.size(dir); ++i) {
        const StepLadder::Rung& r = ladder.at(dir, i);
        const RegionCell& cell = map.cells().at(r.cell);
        bool usable = false;
        for (std::size_t c : map.usable_cells()) usable = usable || c == r.cell;
        EXPECT_TRUE(usable) << what << " rung " << i;
        EXPECT_EQ(cell.direction(), dir) << what;
        EXPECT_DOUBLE_EQ(r.seed.step_m, std::fabs(cell.step_m)) << what;
        // The seed predicts the map's whole burst: single_burst_m + (n - 1) step_m, along dir.
        EXPECT_NEAR(r.seed.predict_m(5), dir * (cell.single_burst_m + 4 * cell.step_m),
                    1e-12 * std::fabs(cell.step_m) * 10)
            << what;
        if (i > 0) {
          EXPECT_GE(ladder.at(dir, i - 1).seed.step_m, r.seed.step_m) << what;
        }
        EXPECT_FALSE(r.dead);
        EXPECT_FALSE(r.proven);
      }
    }
  }
}

// Every choice toward a drawn target keeps to what step_ladder.h says of it, and on a stage that
// steps g times the map (g drawn in [0.3, 3], 10 % scatter a chunk) the moves it plans arrive. A
// calibration carries what the rungs learned from one move to the next, as in the daemon.
TEST(StepLadder, ChoicesKeepTheirPromisesAndMovesArriveOnAStageOfAnotherAlpha) {
  const std::uint64_t s = seed();
  std::mt19937_64 rng(s);
  std::uniform_real_distribution<double> u(0, 1);
  int arrived = 0, moves_total = 0;
  std::ostringstream misses;
  for (int k = 0; k < 3; ++k) {
    std::string what;
    const RegionMap map(drawn_stage(rng, what));
    PositionerConfig config;
    config.soft_lower_m = -5e-3;
    config.soft_upper_m = 5e-3;
    Calibration calibration(map.config().stage);
    StepLadder ladder(map, config, &calibration);
    ladder.build(kCountM, buffered_limits(map));
    const double gain = std::exp(std::log(0.3) + u(rng) * std::log(10.0));
    what += " g " + std::to_string(gain) + " seed " + std::to_string(s);
    const double landing = 0.5 * kCountM;
    double position = 0;
    for (int move = 0; move < 25; ++move) {
      ++moves_total;
      const double d = std::exp(std::log(10e-9) + u(rng) * std::log(5e-3 / 10e-9));
      double target = position + (u(rng) < 0.5 ? -d : d);
      if (std::fabs(target) > 4e-3) target = position - (target - position);
      ladder.start_move();
      // The reading: the position quantized to a count (no noise: the plant repeats itself).
      const auto reading = [&] { return std::round(position / kCountM) * kCountM; };
      int chunks = 0;
      for (; chunks < 400; ++chunks) {
        const double error = target - reading();
        if (std::fabs(error) <= landing) break;
        const StepLadder::Choice c =
            ladder.next_chunk(error, position, landing, true, static_cast<std::uint64_t>(move));
        ASSERT_EQ(c.kind, StepLadder::Choice::Kind::Play) << what;
        const int sign = error > 0 ? 1 : -1;
        // Toward the target, but for a back-off or a vernier's first chunk (neither a try).
        if (c.back_off || c.vernier) {
          ASSERT_FALSE(c.final_chunk) << what;
        }
        if (c.back_off) {
          ASSERT_EQ(c.direction, -sign) << what;
        } else if (!c.vernier) {
          ASSERT_EQ(c.direction, sign) << what;
        }
        ASSERT_GE(c.rung, 0) << what;
        ASSERT_LT(static_cast<std::size_t>(c.rung), ladder.size(c.direction)) << what;
        const StepLadder::Rung& r = ladder.at(c.direction, static_cast<std::size_t>(c.rung));
        ASSERT_FALSE(r.dead) << what;
        ASSERT_GE(c.cycles, 1u) << what;
        const std::uint64_t max_cycles = map.cells()[r.cell].max_cycles;
        if (max_cycles > 0) {
          ASSERT_LE(c.cycles, max_cycles) << what;
        }
        ASSERT_GT(c.final_step_m, 0) << what;
        // An approach chunk stops short of the target by the rung's own estimate.
        if (!c.final_chunk && !c.back_off && !c.vernier) {
          ASSERT_LT(r.est.predict_m(c.cycles), std::fabs(error)) << what;
        }
        const double predicted = r.est.predict_m(c.cycles);
        const double moved = plant_move_m(ladder, c.direction, c.rung, c.cycles, gain, 0.1, rng);
        ladder.judge(c.direction, c.rung, c.cycles, predicted, moved, false,
                     static_cast<std::uint64_t>(move));
        position += moved;
      }
      if (std::fabs(target - reading()) <= landing) {
        ++arrived;
      } else {
        misses << "\n  " << what << ": move " << move << " ends " << (target - reading()) / kCountM
               << " counts off after " << chunks << " chunks";
      }
    }
    // What the ladder learned of the stage: the gain of its learned rungs, near g (within the
    // ladder's [1/4, 4]).
    EXPECT_NEAR(std::log(ladder.gain()), std::log(std::clamp(gain, 0.25, 4.0)), 0.25) << what;
  }
  // Landing within half a count of a 10 % scatter takes tries; 400 chunks are plenty. (A rung
  // whose first cycles move nothing once planned chunks predicted to move nothing, forever: 6 of
  // 75 moves on seed 13.)
  EXPECT_GE(arrived, moves_total * 95 / 100) << "seed " << s << misses.str();
}

TEST(StepLadder, ARungThatDoesNotMoveIsLeftOutThenTriedAgain) {
  std::mt19937_64 rng(seed());
  std::string what;
  const RegionMap map(drawn_stage(rng, what));
  PositionerConfig config;
  config.dead_rung_moves = 7;
  StepLadder ladder(map, config, nullptr);
  ladder.build(kCountM, buffered_limits(map));
  ladder.start_move();
  // A long move's first chunk: a coarse rung toward +.
  const StepLadder::Choice c = ladder.next_chunk(4e-3, 0, 0.5 * kCountM, true, 0);
  ASSERT_EQ(c.kind, StepLadder::Choice::Kind::Play) << what;
  ASSERT_FALSE(c.final_chunk) << what;
  const double predicted = ladder.at(1, static_cast<std::size_t>(c.rung)).est.predict_m(c.cycles);
  ASSERT_GT(predicted, 3 * kCountM) << what;
  const StepLadder::Judgement j = ladder.judge(1, c.rung, c.cycles, predicted, 0.0, false, 0);
  EXPECT_TRUE(j.failed) << what;
  EXPECT_TRUE(ladder.at(1, static_cast<std::size_t>(c.rung)).dead);
  // Left out for dead_rung_moves moves: never chosen again before then.
  for (std::uint64_t move = 1; move < 7; ++move) {
    ladder.start_move();
    const StepLadder::Choice again = ladder.next_chunk(4e-3, 0, 0.5 * kCountM, true, move);
    EXPECT_NE(again.rung, c.rung) << what << " move " << move;
  }
  // Then tried again from its seed.
  ladder.start_move();
  const StepLadder::Choice back = ladder.next_chunk(4e-3, 0, 0.5 * kCountM, true, 7);
  EXPECT_EQ(back.rung, c.rung) << what;
  EXPECT_FALSE(ladder.at(1, static_cast<std::size_t>(c.rung)).dead);
}

TEST(StepLadder, SaysSoWhenNoRungThatWayMoves) {
  std::mt19937_64 rng(seed());
  std::string what;
  const RegionMap map(drawn_stage(rng, what));
  const PositionerConfig config;
  StepLadder ladder(map, config, nullptr);
  ladder.build(kCountM, buffered_limits(map));
  ladder.start_move();
  for (std::size_t i = 0; i < ladder.size(1); ++i) ladder.kill(1, i, 0);
  EXPECT_EQ(ladder.finest_live_step_m(1), 0.0);
  EXPECT_GT(ladder.finest_live_step_m(-1), 0.0);
  for (double error : {1e-8, 1e-6, 1e-3}) {
    EXPECT_EQ(ladder.next_chunk(error, 0, 0.5 * kCountM, true, 0).kind,
              StepLadder::Choice::Kind::NoLiveRung)
        << what;
    const StepLadder::Choice other = ladder.next_chunk(-error, 0, 0.5 * kCountM, true, 0);
    EXPECT_EQ(other.kind, StepLadder::Choice::Kind::Play) << what;
    EXPECT_EQ(other.direction, -1) << what;
  }
}

// A rung whose shortest chunk is far longer than its step (a large first-cycle offset) cannot
// land from nearer than that chunk: the ladder backs off (a correction of its own), or says it is
// out of tries when no more corrections are allowed.
TEST(StepLadder, BacksOffWhenNothingLandsFromHereOrSaysItIsOutOfTries) {
  std::mt19937_64 rng(seed());
  std::string what;
  const RegionMap map(drawn_stage(rng, what));
  const PositionerConfig config;
  StepLadder ladder(map, config, nullptr);
  ladder.build(kCountM, buffered_limits(map));
  ladder.start_move();
  // Keep the finest rung toward + of at least a count; leave the others out.
  std::size_t keep = 0;
  for (std::size_t i = 0; i < ladder.size(1); ++i)
    if (ladder.at(1, i).seed.step_m >= kCountM) keep = i;
  for (std::size_t i = 0; i < ladder.size(1); ++i)
    if (i != keep) ladder.kill(1, i, 0);
  // Teach it its seed's step b and an offset of 10 b (the seed's is within a step or so): chunks
  // of 2..29 cycles, 1 % scatter.
  const double b = ladder.at(1, keep).seed.step_m;
  const int rung = static_cast<int>(keep);
  std::normal_distribution<double> noise(0, 0.01);
  for (int round = 0; round < 10; ++round)
    for (std::uint64_t n = 2; n < 30; ++n) {
      const double predicted = ladder.at(1, keep).est.predict_m(n);
      const double moved = (10 * b + static_cast<double>(n) * b) * (1 + noise(rng));
      ladder.judge(1, rung, n, predicted, moved, false, 0);
    }
  const RungEstimate& learned = ladder.at(1, keep).est;
  ASSERT_TRUE(ladder.at(1, keep).proven) << what;
  ASSERT_GT(learned.offset_m, 4 * learned.step_m) << what;
  // 0.4 of its shortest chunk to go, a window of +/- 0.6 of its step: that chunk ends farther
  // from the target than it started.
  const double error = 0.4 * learned.predict_m(1), landing = 0.6 * learned.step_m;
  const StepLadder::Choice out = ladder.next_chunk(error, 0, landing, false, 0);
  EXPECT_EQ(out.kind, StepLadder::Choice::Kind::OutOfTries) << what;
  const StepLadder::Choice back = ladder.next_chunk(error, 0, landing, true, 0);
  ASSERT_EQ(back.kind, StepLadder::Choice::Kind::Play) << what;
  EXPECT_TRUE(back.back_off) << what;
  EXPECT_EQ(back.direction, -1) << what;
  // Far enough back that the kept rung's shortest chunk (offset and a step) lands: its end half a
  // step beyond the target.
  const double back_m =
      ladder.at(-1, static_cast<std::size_t>(back.rung)).est.predict_m(back.cycles);
  EXPECT_GE(error + back_m, (learned.predict_m(1) + 0.5 * learned.step_m) * (1 - 1e-9)) << what;
}

}  // namespace
}  // namespace idm::control
