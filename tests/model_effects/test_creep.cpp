// The creep signature: a flat drift per decade of time after a step, linear in the step, none at
// rest, independent of the step size.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "model/effects/creep.h"
#include "model/stage.h"

using namespace idm::model;

namespace {

// Output at each of `times_s` after an input step of size a at t = 0 (a 10 ns ramp), the input
// then held. 1000 steps between consecutive times.
std::vector<double> step_response(double per_decade, double a, const std::vector<double>& times_s) {
  Creep creep({per_decade});
  creep.reset(0.0);
  const double ramp_s = 1e-8;
  creep.step(a, ramp_s);
  double t = ramp_s;
  std::vector<double> out;
  for (double target : times_s) {
    const double dt = (target - t) / 1000.0;
    double y = 0.0;
    for (int k = 0; k < 1000; ++k) y = creep.step(a, dt);
    t = target;
    out.push_back(y);
  }
  return out;
}

}  // namespace

TEST(Creep, DriftPerDecadeIsFlat) {
  const double per_decade = 0.02;
  const double a = 1e-6;
  const std::vector<double> times{1e-3, 1e-2, 1e-1, 1.0, 10.0, 100.0};
  const std::vector<double> y = step_response(per_decade, a, times);
  for (std::size_t i = 0; i + 1 < y.size(); ++i) {
    EXPECT_NEAR(y[i + 1] - y[i], per_decade * a, 0.1 * per_decade * a)
        << "decade " << times[i] << " .. " << times[i + 1] << " s";
  }
  // The immediate response is the step itself; the drift comes on top.
  Creep creep({per_decade});
  creep.reset(0.0);
  EXPECT_NEAR(creep.step(a, 1e-8), a, 1e-3 * a);
}

TEST(Creep, Linear) {
  const std::vector<double> times{1e-3, 1e-1, 10.0};
  const std::vector<double> one = step_response(0.01, 1e-6, times);
  const std::vector<double> three = step_response(0.01, 3e-6, times);
  const std::vector<double> down = step_response(0.01, -2e-6, times);
  for (std::size_t i = 0; i < times.size(); ++i) {
    EXPECT_NEAR(three[i], 3.0 * one[i], 1e-12 * std::abs(three[i]));
    EXPECT_NEAR(down[i], -2.0 * one[i], 1e-12 * std::abs(down[i]));
  }
}

TEST(Creep, NoDriftAtRest) {
  Creep creep({0.05});
  creep.reset(5e-6);
  for (int k = 0; k < 100000; ++k) ASSERT_EQ(creep.step(5e-6, 1e-4), 5e-6);
}

TEST(Creep, DriftsBackAfterReturningToRest) {
  // Held at A for 10 s and back to 0: the output then drifts back down towards 0.
  Creep creep({0.02});
  creep.reset(0.0);
  for (int k = 0; k < 10000; ++k) creep.step(1e-6, 1e-3);
  const double back = creep.step(0.0, 1e-6);
  EXPECT_GT(back, 0.0);  // the slow part is still extended
  double y = back;
  for (int k = 0; k < 100000; ++k) y = creep.step(0.0, 1e-2);
  EXPECT_LT(y, 0.2 * back);
  EXPECT_GE(y, 0.0);
}

TEST(Creep, ResultDoesNotDependOnTheStepSize) {
  // A ramp up and a hold, corners on both grids.
  auto run = [](double dt) {
    Creep creep({0.02});
    creep.reset(0.0);
    const long n = std::lround(0.2 / dt);
    std::vector<double> out;
    for (long k = 1; k <= n; ++k) {
      const double t = k * dt;
      out.push_back(creep.step(t < 0.05 ? 2e-4 * t : 1e-5, dt));
    }
    return out;
  };
  const std::vector<double> coarse = run(1e-4);
  const std::vector<double> fine = run(2.5e-5);
  for (std::size_t k = 0; k < coarse.size(); ++k)
    ASSERT_NEAR(coarse[k], fine[4 * k + 3], 1e-9 * 1e-5) << "step " << k;
}

TEST(Creep, ParamsValidation) {
  try {
    Creep::Params{-0.01}.validate();
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_STREQ(e.what(), "creep.per_decade: -0.01 is out of range, allowed [0, 0.1]");
  }
}
