// The DAC signature: levels full_scale / 2^bits apart, a staircase on the update clock whatever
// the plant's step, clamping at the ends of the span, and near identity at 24 bits and a fast
// clock.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <set>

#include "model/effects/quantization.h"
#include "model/stage.h"
#include "model/waveform.h"

using namespace idm::model;

TEST(Quantization, LevelSpacing) {
  const double fs = 2.0 * 20.35e-6;
  Quantization dac({12, 1e6, fs});
  const double q = fs / 4096.0;
  EXPECT_DOUBLE_EQ(dac.level_spacing_m(), q);  // about 9.9 nm
  EXPECT_EQ(dac.quantize(0.0), 0.0);
  EXPECT_EQ(dac.quantize(0.4 * q), 0.0);
  EXPECT_DOUBLE_EQ(dac.quantize(0.6 * q), q);
  EXPECT_DOUBLE_EQ(dac.quantize(-7.3 * q), -7.0 * q);
  // A slow ramp over 20 levels at the DAC's clock: every output a level, consecutive distinct
  // outputs one level apart, each level visited.
  dac.reset(0.0);
  std::set<long> codes;
  double prev = 0.0;
  for (int k = 1; k <= 2000; ++k) {
    const double y = dac.step(20.0 * q * k / 2000.0, 1e-6);
    const double code = y / q;
    ASSERT_NEAR(code, std::round(code), 1e-9);
    ASSERT_TRUE(y == prev || std::abs(y - prev - q) < 1e-9 * q) << "step " << k;
    codes.insert(std::lround(code));
    prev = y;
  }
  EXPECT_EQ(codes.size(), 21u);
}

TEST(Quantization, StaircaseOnTheUpdateClock) {
  // 10 kHz updates, plant steps of 2 us (50 per update) and 3 us (updates inside steps).
  for (double dt : {2e-6, 3e-6}) {
    const double update_hz = 1e4;
    const double rate = 0.005;  // m/s: 0.5 um per update period, within the span
    Quantization dac({16, update_hz, 2.0 * 20.35e-6});
    dac.reset(0.0);
    int changes = 0;
    double prev = 0.0;
    for (long k = 1; k <= 1000; ++k) {
      const double t = k * dt;
      const double y = dac.step(rate * t, dt);
      // The value of the last update at or before t, sampled exactly at its instant.
      const double last_update_s = std::floor(t * update_hz + 1e-9) / update_hz;
      ASSERT_DOUBLE_EQ(y, dac.quantize(rate * last_update_s)) << "dt " << dt << " step " << k;
      if (y != prev) ++changes;
      prev = y;
    }
    EXPECT_EQ(changes, static_cast<int>(std::floor(1000 * dt * update_hz + 1e-9))) << "dt " << dt;
  }
}

TEST(Quantization, ClampsToTheSpan) {
  const double fs = 40e-6;
  Quantization dac({8, 1e6, fs});
  const double q = fs / 256.0;
  dac.reset(0.0);
  EXPECT_DOUBLE_EQ(dac.step(30e-6, 1e-6), fs / 2 - q);  // top code: one level below +fs/2
  EXPECT_DOUBLE_EQ(dac.step(-30e-6, 1e-6), -fs / 2);
  EXPECT_DOUBLE_EQ(dac.quantize(1.0), fs / 2 - q);
  EXPECT_DOUBLE_EQ(dac.quantize(-1.0), -fs / 2);
  Quantization one_bit({1, 1e6, fs});
  EXPECT_DOUBLE_EQ(one_bit.quantize(15e-6), 0.0);
  EXPECT_DOUBLE_EQ(one_bit.quantize(-15e-6), -fs / 2);
}

TEST(Quantization, TwentyFourBitsAndAFastClockAreNearIdentity) {
  const TriangleWave wave{500.0, 0.1, 20.35e-6, 2};
  Quantization dac({24, 1e8, 2.0 * 20.35e-6});
  dac.reset(0.0);
  double worst = 0.0;
  for (long k = 1; k <= 5000; ++k) {
    const double x = wave.xi_m(k * 1e-6);
    worst = std::max(worst, std::abs(dac.step(x, 1e-6) - x));
  }
  EXPECT_LT(worst, 1e-11);  // half a level is 1.2e-12 m
}

TEST(Quantization, ResetHoldsTheQuantizedRestValue) {
  Quantization dac({4, 1e3, 16e-6});  // 1 um levels, 1 ms clock
  dac.reset(2.4e-6);
  EXPECT_DOUBLE_EQ(dac.step(5e-6, 0.5e-3), 2e-6);  // no update yet
  EXPECT_DOUBLE_EQ(dac.step(5e-6, 0.5e-3), 5e-6);  // the update at 1 ms
}

TEST(Quantization, ParamsValidation) {
  auto message = [](Quantization::Params p) {
    try {
      p.validate();
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_EQ(message({0, 1e6, 1e-5}),
            "quantization.bits: 0 is out of range, allowed an integer in [1, 24]");
  EXPECT_EQ(message({12, 0.0, 1e-5}),
            "quantization.update_rate_hz: 0 is out of range, allowed (0, 1e9]");
  EXPECT_EQ(message({12, 1e6, -1e-5}),
            "quantization.full_scale_m: -1e-5 is out of range, allowed (0, 0.01]");
  EXPECT_EQ(message({}), "");
}
