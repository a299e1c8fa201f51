// The motion gate (control/motion_gate.h), against a judge written here from its rule: the
// positions a request may reach stay within the soft limits, or, from outside them, never farther
// out; checked over generated positions, limits and bursts.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "control/motion_gate.h"

using namespace idm::control;

TEST(MotionGate, ABurstsExcursionHoldsItsNominalAndGrownEndsAndASlipEitherWay) {
  std::mt19937 rng(21);
  std::uniform_real_distribution<double> step(-5e-6, 5e-6), share(0, 0.5), slip(0, 3e-6);
  for (int k = 0; k < 10000; ++k) {
    const std::uint64_t n = 1 + rng() % 1000;
    const double s = step(rng), u = share(rng), m = slip(rng);
    const Excursion e = burst_excursion(n, s, u, m);
    const double nominal = static_cast<double>(n) * s, grown = nominal * (1 + u);
    for (const double x : {0.0, nominal, grown}) {
      EXPECT_LE(e.lo_m, x - m + 1e-18);
      EXPECT_GE(e.hi_m, x + m - 1e-18);
    }
    // And no wider than that.
    EXPECT_NEAR(e.lo_m, std::min({0.0, nominal, grown}) - m, 1e-15);
    EXPECT_NEAR(e.hi_m, std::max({0.0, nominal, grown}) + m, 1e-15);
  }
}

TEST(MotionGate, ARequestMayNeverReachFartherOutThanTheLimitsOrItsStart) {
  std::mt19937 rng(22);
  std::uniform_real_distribution<double> pos(-2e-3, 2e-3), half(1e-6, 1e-3), ext(0, 5e-4);
  int allowed = 0, refused = 0, from_outside = 0;
  for (int k = 0; k < 100000; ++k) {
    const double centre = pos(rng), w = half(rng);
    const double lower = centre - w, upper = centre + w;
    const double p = pos(rng);
    // Either way, or one way only (a burst of a known direction).
    const int way = static_cast<int>(rng() % 3);
    const Excursion e{way == 1 ? 0.0 : -ext(rng), way == 2 ? 0.0 : ext(rng)};
    // The judge: every reachable point x in [p + lo, p + hi] must satisfy
    // lower' <= x <= upper' with lower' = min(lower, p), upper' = max(upper, p).
    const bool ok = p + e.lo_m >= std::min(lower, p) && p + e.hi_m <= std::max(upper, p);
    EXPECT_EQ(excursion_allowed(p, e, lower, upper), ok);
    (ok ? allowed : refused) += 1;
    from_outside += (p < lower || p > upper) && ok;
    // A reading: allowed exactly where the excursion's rule allows a point.
    const double x = p + (e.lo_m + (e.hi_m - e.lo_m) * (rng() % 1000) / 999.0);
    EXPECT_EQ(reading_allowed(x, p, lower, upper, 0.0),
              x >= std::min(lower, p) && x <= std::max(upper, p));
  }
  EXPECT_GT(allowed, 1000);
  EXPECT_GT(refused, 1000);
  EXPECT_GT(from_outside, 100);  // recovery from outside was exercised
}

TEST(MotionGate, NothingNotFiniteIsAllowed) {
  const double nan = std::nan("");
  EXPECT_FALSE(excursion_allowed(nan, {0, 0}, -1, 1));
  EXPECT_FALSE(excursion_allowed(0, {nan, 0}, -1, 1));
  EXPECT_FALSE(reading_allowed(nan, 0, -1, 1, 0));
  EXPECT_FALSE(target_allowed(nan, -1, 1));
  EXPECT_TRUE(target_allowed(1, -1, 1));
  EXPECT_FALSE(target_allowed(1.0000001, -1, 1));
}
