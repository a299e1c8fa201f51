// The amplifier's signature: -3 dB and -45/-90 degrees at cutoff, Butterworth overshoot, unity DC
// gain, results independent of the step size, slew limit, rounded velocity corners.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <vector>

#include "model/effects/amplifier.h"
#include "model/stage.h"
#include "model/waveform.h"

using namespace idm::model;

namespace {

struct SineResponse {
  double gain;
  double phase_deg;
};

// Drives a sine at freq_hz, lets the transient die out, and projects the last periods of the
// output on sin and cos.
SineResponse sine_response(Amplifier& amp, double freq_hz, double dt_s) {
  const double w = 2.0 * std::numbers::pi * freq_hz;
  const double amplitude_m = 1e-6;
  const long per_period = std::lround(1.0 / (freq_hz * dt_s));
  const long settle = 30 * per_period;
  const long measure = 10 * per_period;
  amp.reset(0.0);
  double s = 0.0;
  double c = 0.0;
  for (long k = 1; k <= settle + measure; ++k) {
    const double t = k * dt_s;
    const double y = amp.step(amplitude_m * std::sin(w * t), dt_s);
    if (k > settle) {
      s += y * std::sin(w * t);
      c += y * std::cos(w * t);
    }
  }
  s *= 2.0 / measure;
  c *= 2.0 / measure;
  return {std::hypot(s, c) / amplitude_m, std::atan2(c, s) * 180.0 / std::numbers::pi};
}

std::vector<double> run_triangle(Amplifier& amp, const TriangleWave& wave, double dt_s,
                                 double until_s) {
  amp.reset(0.0);
  const long n = std::lround(until_s / dt_s);
  std::vector<double> out(n + 1, 0.0);
  for (long k = 1; k <= n; ++k) out[k] = amp.step(wave.xi_m(k * dt_s), dt_s);
  return out;
}

}  // namespace

TEST(Amplifier, MinusThreeDecibelsAndPhaseAtCutoff) {
  for (int order : {1, 2}) {
    Amplifier amp({order, 3000.0, 0.0});
    const SineResponse r = sine_response(amp, 3000.0, 1e-6);
    EXPECT_NEAR(r.gain, std::sqrt(0.5), 0.01 * std::sqrt(0.5)) << "order " << order;
    EXPECT_NEAR(r.phase_deg, order == 1 ? -45.0 : -90.0, 1.0) << "order " << order;
  }
}

TEST(Amplifier, PassbandAndStopband) {
  // Butterworth: |H| = 1 / sqrt(1 + (f/fc)^(2n)).
  for (int order : {1, 2}) {
    Amplifier amp({order, 1000.0, 0.0});
    for (double f : {100.0, 4000.0}) {
      const double expected = 1.0 / std::sqrt(1.0 + std::pow(f / 1000.0, 2 * order));
      EXPECT_NEAR(sine_response(amp, f, 2e-6).gain, expected, 0.01 * expected)
          << "order " << order << " at " << f << " Hz";
    }
  }
}

TEST(Amplifier, SecondOrderStepOvershootIsButterworth) {
  Amplifier amp({2, 1000.0, 0.0});
  amp.reset(0.0);
  const double a = 10e-6;
  double peak = 0.0;
  for (int k = 0; k < 5000; ++k) peak = std::max(peak, amp.step(a, 1e-6));
  // exp(-pi zeta / sqrt(1 - zeta^2)) with zeta = 1/sqrt(2): exp(-pi) = 4.32 %.
  EXPECT_NEAR(peak / a - 1.0, std::exp(-std::numbers::pi), 0.001);

  Amplifier first({1, 1000.0, 0.0});
  first.reset(0.0);
  double peak1 = 0.0;
  for (int k = 0; k < 5000; ++k) peak1 = std::max(peak1, first.step(a, 1e-6));
  EXPECT_LE(peak1, a * (1.0 + 1e-12));  // no overshoot at order 1
}

TEST(Amplifier, UnityDcGainAndRestAfterReset) {
  for (int order : {1, 2}) {
    Amplifier amp({order, 500.0, 0.0});
    amp.reset(3e-6);
    for (int k = 0; k < 100; ++k) EXPECT_NEAR(amp.step(3e-6, 1e-5), 3e-6, 1e-18);
    double y = 0.0;
    for (int k = 0; k < 20000; ++k) y = amp.step(-7e-6, 1e-5);
    EXPECT_NEAR(y, -7e-6, 1e-15) << "order " << order;
  }
}

TEST(Amplifier, ResultDoesNotDependOnTheStepSize) {
  // Corners at multiples of 10 us: the input is piecewise linear on both grids.
  const TriangleWave wave{500.0, 0.1, 20e-6, 3};
  for (int order : {1, 2}) {
    for (double slew : {0.0, 0.05}) {
      Amplifier coarse({order, 3000.0, slew});
      Amplifier fine({order, 3000.0, slew});
      const std::vector<double> a = run_triangle(coarse, wave, 10e-6, 8e-3);
      const std::vector<double> b = run_triangle(fine, wave, 2.5e-6, 8e-3);
      double worst = 0.0;
      for (std::size_t k = 0; k < a.size(); ++k) worst = std::max(worst, std::abs(a[k] - b[4 * k]));
      if (slew == 0.0) {
        EXPECT_LT(worst, 1e-9 * wave.stroke_m) << "order " << order;  // exact up to rounding
      } else {
        EXPECT_LT(worst, 1e-3 * wave.stroke_m) << "order " << order << ", slew limited";
      }
    }
  }
}

TEST(Amplifier, CoefficientsFollowAChangeOfStepSize) {
  Amplifier mixed({2, 2000.0, 0.0});
  Amplifier fine({2, 2000.0, 0.0});
  mixed.reset(0.0);
  fine.reset(0.0);
  double t = 0.0;
  double y_mixed = 0.0;
  for (int k = 0; k < 100; ++k) {  // alternating 4 us and 1 us steps on a ramp
    const double dt = (k % 2 == 0) ? 4e-6 : 1e-6;
    t += dt;
    y_mixed = mixed.step(10.0 * t * 1e-3, dt);
  }
  double y_fine = 0.0;
  for (int k = 1; k <= 250; ++k) y_fine = fine.step(10.0 * k * 1e-6 * 1e-3, 1e-6);
  EXPECT_NEAR(y_mixed, y_fine, 1e-9 * std::abs(y_fine));
}

TEST(Amplifier, SlewLimitCapsTheOutputRate) {
  const double slew = 0.01;  // m/s
  const double dt = 1e-6;
  Amplifier amp({1, 100e3, slew});
  amp.reset(0.0);
  double y_prev = 0.0;
  double max_rate = 0.0;
  long reached = -1;
  for (long k = 1; k <= 3000; ++k) {
    const double y = amp.step(10e-6, dt);
    max_rate = std::max(max_rate, std::abs(y - y_prev) / dt);
    if (reached < 0 && y >= 0.999 * 10e-6) reached = k;
    y_prev = y;
  }
  EXPECT_LE(max_rate, slew * (1.0 + 1e-9));
  EXPECT_GT(max_rate, 0.999 * slew);
  // 10 um at 0.01 m/s takes 1 ms.
  ASSERT_GT(reached, 0);
  EXPECT_NEAR(reached * dt, 1e-3, 0.05e-3);
  EXPECT_NEAR(y_prev, 10e-6, 1e-12);

  // A slow input is not touched by the limit.
  Amplifier limited({1, 3000.0, 0.05});
  Amplifier free({1, 3000.0, 0.0});
  const TriangleWave slow{100.0, 0.5, 20e-6, 1};  // 4 mm/s
  EXPECT_EQ(run_triangle(limited, slow, 1e-5, 12e-3), run_triangle(free, slow, 1e-5, 12e-3));
}

TEST(Amplifier, RoundsTheVelocityCornersOfATriangle) {
  // 20 um triangle, 200 Hz, duty 0.1: at t = 0.5 ms the velocity jumps from +40 to -4.4 mm/s.
  // The amplifier spreads the jump over about 1/cutoff instead of one step.
  const TriangleWave wave{200.0, 0.1, 20e-6, 2};
  const double dt = 1e-6;
  const double corner_s = wave.extension_s();
  const double v_before = wave.extension_rate_m_s();
  const double v_after = wave.retraction_rate_m_s();
  for (int order : {1, 2}) {
    const double cutoff = 3000.0;
    Amplifier amp({order, cutoff, 0.0});
    const std::vector<double> y = run_triangle(amp, wave, dt, 2e-3);
    auto velocity = [&](long k) { return (y[k] - y[k - 1]) / dt; };
    const long k_corner = std::lround(corner_s / dt);
    // Fraction of the jump done at each step after the corner.
    auto done = [&](long k) { return (v_before - velocity(k)) / (v_before - v_after); };
    long k10 = -1;
    long k90 = -1;
    for (long k = k_corner + 1; k < static_cast<long>(y.size()); ++k) {
      if (k10 < 0 && done(k) >= 0.1) k10 = k;
      if (k90 < 0 && done(k) >= 0.9) k90 = k;
    }
    ASSERT_GT(k90, 0);
    const double t10 = (k10 - k_corner) * dt;
    const double t90 = (k90 - k_corner) * dt;
    // Order 1: 10-90 % of an exponential with tau = 1/(2 pi fc) takes 0.35/fc; order 2 a bit
    // longer. Without the amplifier it would take one step (1 us).
    EXPECT_GT(t90 - t10, 0.25 / cutoff) << "order " << order;
    EXPECT_LT(t90, 1.0 / cutoff) << "order " << order;
    // The rounded corner: at the corner instant the actuator lags the command by several percent
    // of the stroke, and its top comes later, by a fraction of 1/cutoff.
    EXPECT_LT(y[k_corner], 0.95 * wave.stroke_m) << "order " << order;
    const long k_top = std::max_element(y.begin(), y.end()) - y.begin();
    EXPECT_GT((k_top - k_corner) * dt, 0.2 / cutoff) << "order " << order;
    EXPECT_LT((k_top - k_corner) * dt, 1.0 / cutoff) << "order " << order;
    // Without the amplifier the jump takes one step.
    Amplifier wide({1, 1e6, 0.0});
    const std::vector<double> z = run_triangle(wide, wave, dt, 2e-3);
    EXPECT_NEAR((z[k_corner + 2] - z[k_corner + 1]) / dt, v_after, 0.01 * (v_before - v_after));
  }
}

TEST(Amplifier, ParamsValidation) {
  auto message = [](Amplifier::Params p) {
    try {
      p.validate();
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_EQ(message({1, -3.0, 0.0}),
            "amplifier.cutoff_hz: -3 is out of range, allowed (0, 1000000]");
  EXPECT_EQ(message({3, 3000.0, 0.0}),
            "amplifier.order: 3 is out of range, allowed an integer in [1, 2]");
  EXPECT_EQ(message({1, 3000.0, -1.0}),
            "amplifier.slew_rate_m_s: -1 is out of range, allowed [0, 1000]");
  EXPECT_EQ(message({}), "");
  EXPECT_THROW(Amplifier({2, 0.0, 0.0}), InputError);
}
