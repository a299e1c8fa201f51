#include <gtest/gtest.h>

#include <cmath>

#include "model/stage.h"
#include "model/waveform.h"

using namespace idm::model;

TEST(Waveform, ShapeAndCorners) {
  const TriangleWave w{200.0, 0.1, 20e-6, 3};
  EXPECT_DOUBLE_EQ(w.period_s(), 5e-3);
  EXPECT_EQ(w.xi_m(-1e-4), 0.0);
  EXPECT_EQ(w.xi_m(0.0), 0.0);
  EXPECT_NEAR(w.xi_m(0.5e-3), 20e-6, 1e-18);            // top of the first extension
  EXPECT_NEAR(w.xi_m(0.25e-3), 10e-6, 1e-18);           // halfway up
  EXPECT_NEAR(w.xi_m(0.5e-3 + 2.25e-3), 10e-6, 1e-17);  // halfway down
  EXPECT_NEAR(w.xi_m(5e-3), 0.0, 1e-18);                // cycle end
  EXPECT_EQ(w.xi_m(15e-3), 0.0);
  EXPECT_EQ(w.xi_m(20e-3), 0.0);
  EXPECT_DOUBLE_EQ(w.rate_m_s(0.1e-3), 20e-6 / 0.5e-3);
  EXPECT_DOUBLE_EQ(w.rate_m_s(1e-3), -20e-6 / 4.5e-3);
  EXPECT_EQ(w.rate_m_s(16e-3), 0.0);
  const auto c = w.corner_times_s();
  ASSERT_EQ(c.size(), 7u);
  EXPECT_DOUBLE_EQ(c[1], 0.5e-3);
  EXPECT_DOUBLE_EQ(c[3], 5.5e-3);
  EXPECT_DOUBLE_EQ(c[6], 15e-3);
}

TEST(Waveform, ReverseDutyHasSlowExtension) {
  const TriangleWave w{100.0, 0.9, 10e-6, 1};
  EXPECT_LT(w.extension_rate_m_s(), -w.retraction_rate_m_s());
  EXPECT_NEAR(w.xi_m(9e-3), 10e-6, 1e-18);
}

TEST(Waveform, SampledAtADeviceClock) {
  const TriangleWave w{1000.0, 0.25, 8e-6, 2};
  std::vector<double> s;
  sample(w, 8000.0, -0.5e-3, 24, s);
  ASSERT_EQ(s.size(), 24u);
  // t = -0.5 ms .. : four zeros, then 0, 4, 8(top at 0.25 ms), 6.67, ...
  EXPECT_EQ(s[0], 0.0);
  EXPECT_EQ(s[4], 0.0);
  EXPECT_NEAR(s[5], 4e-6, 1e-18);
  EXPECT_NEAR(s[6], 8e-6, 1e-18);
  EXPECT_NEAR(s[7], 8e-6 * (0.625 / 0.75), 1e-18);
  double peak = 0;
  for (double v : s) peak = std::max(peak, v);
  EXPECT_NEAR(peak, 8e-6, 1e-18);
}

TEST(Waveform, ValidationNamesTheArgument) {
  auto err = [](TriangleWave w) {
    try {
      validate(w);
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_EQ(err({100, 1.0, 1e-5, 1}), "duty: 1 is out of range, allowed (0, 1)");
  EXPECT_EQ(err({100, 0.0, 1e-5, 1}), "duty: 0 is out of range, allowed (0, 1)");
  EXPECT_EQ(err({-5, 0.1, 1e-5, 1}), "freq_hz: -5 is out of range, allowed (0, 1e6]");
  EXPECT_NE(err({NAN, 0.1, 1e-5, 1}).find("freq_hz"), std::string::npos);
  EXPECT_EQ(err({100, 0.1, 1e-5, 3}), "");
}
