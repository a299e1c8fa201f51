// The hysteresis signature: a loop of width ratio * S through (0, 0) and (S, S), closed from the
// first full cycle, the same at 10 Hz and 1 kHz, identity at ratio 0, bounded output.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "model/effects/hysteresis.h"
#include "model/stage.h"

using namespace idm::model;

namespace {

// A symmetric triangle 0 -> S -> 0 with `half` samples per half cycle, dt = half_period / half.
// Returns the output at every sample (index 0: the rest state), `cycles` cycles.
std::vector<double> run_cycles(Hysteresis& h, double stroke_m, long half, int cycles, double dt_s) {
  h.reset(0.0);
  std::vector<double> y{0.0};
  for (int c = 0; c < cycles; ++c) {
    for (long k = 1; k <= half; ++k) y.push_back(h.step(stroke_m * k / half, dt_s));
    for (long k = half - 1; k >= 0; --k) y.push_back(h.step(stroke_m * k / half, dt_s));
  }
  return y;
}

}  // namespace

TEST(Hysteresis, LoopWidthIsRatioTimesStroke) {
  const double s = 20.35e-6;
  const long half = 1000;
  for (double ratio : {0.02, 0.15, 0.3, 0.5}) {
    Hysteresis h({ratio, s});
    const std::vector<double> y = run_cycles(h, s, half, 3, 1e-6);
    // Second cycle: ascending sample k and descending sample (2 half - k) have the same input.
    const long base = 2 * half;
    double width = 0.0;
    for (long k = 0; k <= half; ++k) width = std::max(width, y[base + 2 * half - k] - y[base + k]);
    EXPECT_NEAR(width, ratio * s, 0.03 * ratio * s) << "ratio " << ratio;
    // Turning points: (S, S) and back to (0, 0); the loop is closed.
    for (int c = 0; c < 3; ++c) {
      EXPECT_NEAR(y[c * 2 * half + half], s, 0.01 * s) << "ratio " << ratio << " cycle " << c;
      EXPECT_NEAR(y[(c + 1) * 2 * half], 0.0, 1e-12 * s) << "ratio " << ratio << " cycle " << c;
    }
    EXPECT_NEAR(y[4 * half], y[2 * half], 1e-15);
    // The ascending branch lags: below the input in the middle of the stroke.
    EXPECT_LT(y[base + half / 2], 0.5 * s);
    EXPECT_GT(y[base + 2 * half - half / 2], 0.5 * s);
  }
}

TEST(Hysteresis, RateIndependent) {
  // The same loop at 10 Hz and 1 kHz with the same step: 50000 and 500 samples per half cycle.
  const double s = 20.35e-6;
  const double dt = 1e-6;
  Hysteresis slow_h({0.15, s});
  Hysteresis fast_h({0.15, s});
  const std::vector<double> slow = run_cycles(slow_h, s, 50000, 2, dt);
  const std::vector<double> fast = run_cycles(fast_h, s, 500, 2, dt);
  double worst = 0.0;
  for (std::size_t k = 0; k < fast.size(); ++k)
    worst = std::max(worst, std::abs(fast[k] - slow[100 * k]));
  EXPECT_LT(worst, 1e-12 * s);
}

TEST(Hysteresis, RatioZeroIsIdentity) {
  Hysteresis h({0.0, 20.35e-6});
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-30e-6, 30e-6);
  h.reset(1e-6);
  for (int k = 0; k < 10000; ++k) {
    const double x = u(rng);
    EXPECT_EQ(h.step(x, 1e-6), x);
  }
}

TEST(Hysteresis, OutputBoundedByTheMajorLoop) {
  // Any input within 0..S from rest at 0 stays inside the major loop: output within 0..S and at
  // most ratio S / 2 from the input.
  const double s = 20.35e-6;
  const double ratio = 0.2;
  Hysteresis h({ratio, s});
  h.reset(0.0);
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(0.0, s);
  double lo = 0.0;
  double hi = 0.0;
  double worst = 0.0;
  for (int k = 0; k < 200000; ++k) {
    const double x = u(rng);
    const double y = h.step(x, 1e-6);
    lo = std::min(lo, y);
    hi = std::max(hi, y);
    worst = std::max(worst, std::abs(y - x));
  }
  EXPECT_GE(lo, -1e-15);
  EXPECT_LE(hi, s + 1e-15);
  EXPECT_LE(worst, 0.5 * ratio * s + 1e-15);
  EXPECT_GT(worst, 0.25 * ratio * s);  // the hysteresis is there
}

TEST(Hysteresis, ResetIsRestAtTheGivenPoint) {
  Hysteresis h({0.15, 20e-6});
  h.reset(5e-6);
  for (int k = 0; k < 10; ++k) EXPECT_NEAR(h.step(5e-6, 1e-6), 5e-6, 1e-20);
  // A full stroke from there: turning points (5, 5) and (25, 25) um.
  double y = 0.0;
  for (int k = 1; k <= 100; ++k) y = h.step(5e-6 + 20e-6 * k / 100, 1e-6);
  EXPECT_NEAR(y, 25e-6, 1e-18);
  for (int k = 99; k >= 0; --k) y = h.step(5e-6 + 20e-6 * k / 100, 1e-6);
  EXPECT_NEAR(y, 5e-6, 1e-18);
}

TEST(Hysteresis, ParamsValidation) {
  auto message = [](Hysteresis::Params p) {
    try {
      p.validate();
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_EQ(message({0.6, 20e-6}), "hysteresis.ratio: 0.6 is out of range, allowed [0, 0.5]");
  EXPECT_EQ(message({0.1, 0.0}), "hysteresis.stroke_m: 0 is out of range, allowed (0, 0.001]");
  EXPECT_EQ(message({}), "");
}
