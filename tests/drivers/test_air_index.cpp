#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "drivers/air_index.h"
#include "drivers/position_word.h"
#include "model/stage.h"

using namespace idm::drivers;
using idm::model::InputError;

namespace {

std::string error_of(const AirConditions& air) {
  try {
    air_refractive_index(air);
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(AirIndex, ReferenceValues) {
  // 633 nm HeNe, 20 C, 101325 Pa, 50 % RH.
  EXPECT_NEAR(air_refractive_index(AirConditions{20.0, 101325.0, 50.0, 450.0}, 632.991e-9),
              1.000271374, 2e-9);
  EXPECT_NEAR(air_refractive_index(AirConditions{20.0, 101325.0, 50.0, 450.0}, 633e-9), 1.000271374,
              2e-9);
  // Standard air of the equation: 15 C, 101325 Pa, dry, 450 ppm CO2.
  EXPECT_NEAR(air_refractive_index(AirConditions{15.0, 101325.0, 0.0, 450.0}), 1.000276529, 2e-9);
  // The defaults are the first case.
  EXPECT_NEAR(air_refractive_index(AirConditions{}), 1.000271374, 2e-9);
}

TEST(AirIndex, DependsOnConditionsTheRightWay) {
  const AirConditions base{20.0, 101325.0, 50.0, 450.0};
  const double n0 = air_refractive_index(base) - 1.0;
  auto n = [&](AirConditions a) { return air_refractive_index(a) - 1.0; };
  // The textbook sensitivities near 20 C, 1 atm, 633 nm: -0.93e-6 per K in dry air (-0.95e-6
  // at a constant 50 % RH, as warmer air then holds more water), +2.68e-9 per Pa, about
  // -8.5e-9 per % RH.
  AirConditions a = base;
  a.temperature_c = 21.0;
  EXPECT_NEAR(n(a) - n0, -0.954e-6, 0.005e-6);
  AirConditions dry = base;
  dry.relative_humidity_pct = 0.0;
  a = dry;
  a.temperature_c = 21.0;
  EXPECT_NEAR(n(a) - n(dry), -0.93e-6, 0.01e-6);
  a = base;
  a.pressure_pa += 100.0;
  EXPECT_NEAR((n(a) - n0) / 100.0, 2.68e-9, 0.03e-9);
  a = base;
  a.relative_humidity_pct = 60.0;
  EXPECT_NEAR((n(a) - n0) / 10.0, -8.6e-9, 0.4e-9);
  // 50 ppm less CO2 scales the dry-air refractivity by 1 - 0.534e-6 * 50: 7.25e-9 lower.
  a = base;
  a.co2_ppm = 400.0;
  EXPECT_NEAR(n(a) - n0, -7.25e-9, 0.02e-9);
  // Normal dispersion: shorter wavelength, higher index.
  EXPECT_GT(air_refractive_index(base, 532e-9), air_refractive_index(base, 633e-9));
}

TEST(AirIndex, SaturationVapourPressure) {
  EXPECT_NEAR(saturation_vapour_pressure_pa(20.0), 2339.2, 0.2);  // IAPWS
  EXPECT_NEAR(saturation_vapour_pressure_pa(0.0), 611.2, 0.1);
  EXPECT_NEAR(saturation_vapour_pressure_pa(60.0), 19946.0, 5.0);
  EXPECT_NEAR(saturation_vapour_pressure_pa(-10.0), 259.87, 0.05);  // over ice
  EXPECT_NEAR(saturation_vapour_pressure_pa(-0.001), 611.15, 0.1);  // ice meets water at 0 C
  EXPECT_THROW(saturation_vapour_pressure_pa(61.0), InputError);
}

TEST(AirIndex, RangeChecksNameTheField) {
  EXPECT_EQ(error_of(AirConditions{}), "");
  EXPECT_NE(error_of(AirConditions{-41.0, 101325.0, 50.0, 450.0})
                .find("air.temperature_c: -41 is out of range, allowed [-40, 60] C"),
            std::string::npos)
      << error_of(AirConditions{-41.0, 101325.0, 50.0, 450.0});
  EXPECT_NE(error_of(AirConditions{60.5, 101325.0, 50.0, 450.0}).find("air.temperature_c"),
            std::string::npos);
  EXPECT_NE(error_of(AirConditions{20.0, 49e3, 50.0, 450.0})
                .find("air.pressure_pa: 49000 is out of range, allowed [50e3, 120e3] Pa"),
            std::string::npos);
  EXPECT_NE(error_of(AirConditions{20.0, 121e3, 50.0, 450.0}).find("air.pressure_pa"),
            std::string::npos);
  EXPECT_NE(error_of(AirConditions{20.0, 101325.0, 101.0, 450.0})
                .find("air.relative_humidity_pct: 101 is out of range, allowed [0, 100] %"),
            std::string::npos);
  EXPECT_NE(error_of(AirConditions{20.0, 101325.0, -1.0, 450.0}).find("relative_humidity_pct"),
            std::string::npos);
  EXPECT_NE(error_of(AirConditions{NAN, 101325.0, 50.0, 450.0}).find("temperature_c"),
            std::string::npos);
  EXPECT_NE(error_of(AirConditions{20.0, 101325.0, 50.0, -5.0}).find("air.co2_ppm"),
            std::string::npos);
  try {
    validate(AirConditions{20.0, 30e3, 50.0, 450.0}, "idmd.yaml:7: interferometer.air");
    FAIL() << "no throw";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("idmd.yaml:7: interferometer.air.pressure_pa"),
              std::string::npos)
        << e.what();
  }
  EXPECT_THROW(air_refractive_index(AirConditions{}, 10.6e-6), InputError);
  // The extremes of the range are accepted.
  EXPECT_NO_THROW(air_refractive_index(AirConditions{-40.0, 50e3, 0.0, 0.0}));
  EXPECT_NO_THROW(air_refractive_index(AirConditions{60.0, 120e3, 100.0, 2000.0}));
}

TEST(AirIndex, DeadPathCorrection) {
  // A stationary reflector 0.3 m beyond the dead path of 0.2 m; the air warms by 1 K after
  // zeroing. The interferometer counts the change of n * (D + x); decoding with the new index
  // shows apparent travel that the dead-path correction removes.
  const double dead_path_m = 0.2;
  const double x_m = 0.3;
  const double n_zero = air_refractive_index(AirConditions{20.0, 101325.0, 50.0, 450.0});
  const double n_now = air_refractive_index(AirConditions{21.0, 101325.0, 50.0, 450.0});
  // Optical path change since zeroing (when the reflector was at x = 0), in metres of vacuum path.
  const double optical_m = n_now * (dead_path_m + x_m) - n_zero * dead_path_m;
  const double measured_m = optical_m / n_now;     // what the decoder gives with count_m at n_now
  EXPECT_GT(std::fabs(measured_m - x_m), 150e-9);  // ~0.19 um of apparent travel
  EXPECT_NEAR(dead_path_corrected_m(measured_m, dead_path_m, n_zero, n_now), x_m, 1e-15);
  // No change in air: nothing to correct.
  EXPECT_EQ(dead_path_corrected_m(0.123, dead_path_m, n_zero, n_zero), 0.123);
  EXPECT_THROW(dead_path_corrected_m(0.0, -1.0, n_zero, n_now), InputError);
  EXPECT_THROW(dead_path_corrected_m(0.0, 0.1, 0.5, n_now), InputError);

  // Through the codec: counts of the optical path, decoded at n_now, then corrected.
  PositionWordConfig c;
  c.width = WordWidth::Bits36;
  c.air_index = n_now;
  c.max_velocity_m_s = 100.0;  // the whole move in one sample is allowed
  c.sample_interval_s = 1.0;
  const double vacuum_count_m = c.lambda_vac_m / c.effective_divisor();
  PositionDecoder d(c);
  d.reset(0);
  ASSERT_TRUE(d.decode(encode_position_word(12345, WordWidth::Bits36)).valid());
  const auto counts = static_cast<std::int64_t>(std::llround(optical_m / vacuum_count_m));
  const PositionSample s = d.decode(encode_position_word(12345 + counts, WordWidth::Bits36));
  ASSERT_TRUE(s.valid());
  EXPECT_NEAR(dead_path_corrected_m(s.position_m, dead_path_m, n_zero, n_now), x_m, d.count_m());
}
