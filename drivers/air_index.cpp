#include "drivers/air_index.h"

#include <cmath>

#include "model/range.h"

namespace idm::drivers {

namespace {

using model::check_range;

void check_temperature(double temperature_c, const std::string& where) {
  check_range(temperature_c >= -40.0 && temperature_c <= 60.0, where, "temperature_c",
              temperature_c, "[-40, 60] C");
}

// IAPWS-IF97 region 4 saturation pressure over liquid water (T in K, result in Pa).
double saturation_over_water_pa(double temperature_k) {
  constexpr double n1 = 0.11670521452767e4, n2 = -0.72421316703206e6, n3 = -0.17073846940092e2,
                   n4 = 0.12020824702470e5, n5 = -0.32325550322333e7, n6 = 0.14915108613530e2,
                   n7 = -0.48232657361591e4, n8 = 0.40511340542057e6, n9 = -0.23855557567849,
                   n10 = 0.65017534844798e3;
  const double theta = temperature_k + n9 / (temperature_k - n10);
  const double a = theta * theta + n1 * theta + n2;
  const double b = n3 * theta * theta + n4 * theta + n5;
  const double c = n6 * theta * theta + n7 * theta + n8;
  const double ratio = 2.0 * c / (-b + std::sqrt(b * b - 4.0 * a * c));
  return 1e6 * ratio * ratio * ratio * ratio;  // MPa -> Pa
}

// IAPWS (2011) sublimation pressure over ice Ih (T in K, result in Pa).
double saturation_over_ice_pa(double temperature_k) {
  constexpr double triple_point_k = 273.16, triple_point_pa = 611.657;
  constexpr double a1 = -0.212144006e2, a2 = 0.273203819e2, a3 = -0.610598130e1;
  constexpr double b1 = 0.333333333e-2, b2 = 0.120666667e1, b3 = 0.170333333e1;
  const double theta = temperature_k / triple_point_k;
  const double sum = a1 * std::pow(theta, b1) + a2 * std::pow(theta, b2) + a3 * std::pow(theta, b3);
  return triple_point_pa * std::exp(sum / theta);
}

}  // namespace

void validate(const AirConditions& air, const std::string& where) {
  check_temperature(air.temperature_c, where);
  check_range(air.pressure_pa >= 50e3 && air.pressure_pa <= 120e3, where, "pressure_pa",
              air.pressure_pa, "[50e3, 120e3] Pa");
  check_range(air.relative_humidity_pct >= 0.0 && air.relative_humidity_pct <= 100.0, where,
              "relative_humidity_pct", air.relative_humidity_pct, "[0, 100] %");
  check_range(air.co2_ppm >= 0.0 && air.co2_ppm <= 2000.0, where, "co2_ppm", air.co2_ppm,
              "[0, 2000] ppm");
}

double saturation_vapour_pressure_pa(double temperature_c) {
  check_temperature(temperature_c, "saturation_vapour_pressure");
  const double temperature_k = temperature_c + 273.15;
  return temperature_c >= 0.0 ? saturation_over_water_pa(temperature_k)
                              : saturation_over_ice_pa(temperature_k);
}

double air_refractive_index(const AirConditions& air, double lambda_vac_m) {
  validate(air);
  check_range(lambda_vac_m >= 350e-9 && lambda_vac_m <= 1100e-9, "air", "lambda_vac_m",
              lambda_vac_m, "[350e-9, 1100e-9] m");
  const double sigma_per_um = 1e-6 / lambda_vac_m;
  const double s = sigma_per_um * sigma_per_um;
  const double t = air.temperature_c;
  const double p = air.pressure_pa;

  const double standard = (8342.54 + 2406147.0 / (130.0 - s) + 15998.0 / (38.9 - s)) * 1e-8;
  const double with_co2 = standard * (1.0 + 0.534e-6 * (air.co2_ppm - 450.0));
  const double density =
      p * (1.0 + 1e-8 * (0.601 - 0.00972 * t) * p) / (96095.43 * (1.0 + 0.003661 * t));
  const double water_vapour_pa =
      air.relative_humidity_pct / 100.0 * saturation_vapour_pressure_pa(t);
  const double water = water_vapour_pa * (3.7345 - 0.0401 * s) * 1e-10;
  return 1.0 + with_co2 * density - water;
}

double dead_path_corrected_m(double position_m, double dead_path_m, double air_index_at_zero,
                             double air_index_now) {
  check_range(dead_path_m >= 0.0 && dead_path_m <= 100.0, "dead_path", "dead_path_m", dead_path_m,
              "[0, 100] m");
  check_range(air_index_at_zero >= 1.0 && air_index_at_zero <= 1.01, "dead_path",
              "air_index_at_zero", air_index_at_zero, "[1, 1.01]");
  check_range(air_index_now >= 1.0 && air_index_now <= 1.01, "dead_path", "air_index_now",
              air_index_now, "[1, 1.01]");
  return position_m - dead_path_m * (air_index_now - air_index_at_zero) / air_index_now;
}

}  // namespace idm::drivers
