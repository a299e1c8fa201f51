// Refractive index of air for interferometer wavelength compensation: the modified Edlen
// equation in the form of Birch and Downs (Metrologia 30, 155 (1993); correction Metrologia 31,
// 315 (1994)), with the saturation vapour pressure of IAPWS (over water at and above 0 C, over
// ice below) to turn relative humidity into the partial pressure of water vapour.
//
// sigma = 1 / lambda_vac in 1/um, S = sigma^2
//   (n - 1)_s  * 1e8 = 8342.54 + 2406147 / (130 - S) + 15998 / (38.9 - S)
//                      (standard air: 15 C, 101325 Pa, dry, 450 ppm CO2)
//   (n - 1)_x        = (n - 1)_s * (1 + 0.534e-6 * (x_co2_ppm - 450))
//   (n - 1)_tp       = p * (n - 1)_x * (1 + 1e-8 * (0.601 - 0.00972 t) * p) / (96095.43 (1 +
//   0.003661 t)) n_tpf - n_tp     = -f * (3.7345 - 0.0401 S) * 1e-10
// with p in Pa, t in C and f the water vapour partial pressure in Pa.
#pragma once

#include <string>

namespace idm::drivers {

inline constexpr double kHeNeVacuumWavelength_m = 632.991e-9;

struct AirConditions {
  double temperature_c = 20.0;          // -40 .. 60 C
  double pressure_pa = 101325.0;        // 50e3 .. 120e3 Pa
  double relative_humidity_pct = 50.0;  // 0 .. 100 %
  double co2_ppm = 450.0;               // 0 .. 2000 ppm; 450 is the equation's standard air
};

// Throws InputError naming the field and the allowed range.
void validate(const AirConditions& air, const std::string& where = "air");

// Saturation vapour pressure in Pa: IAPWS-IF97 over liquid water for t >= 0 C, IAPWS 2011
// sublimation over ice for t < 0 C. Valid -40 .. 60 C (InputError outside).
double saturation_vapour_pressure_pa(double temperature_c);

// n_air at the vacuum wavelength lambda_vac_m (350 .. 1100 nm, InputError outside).
double air_refractive_index(const AirConditions& air,
                            double lambda_vac_m = kHeNeVacuumWavelength_m);

// Dead-path correction. The interferometer counts changes of optical path n * (D + x), where D
// (the dead path) is the distance from the interferometer to the reflector at the position where
// the count was zeroed. A position computed with the present index n_now then contains the
// apparent travel D * (n_now - n_at_zero) / n_now; this returns position_m with it removed.
double dead_path_corrected_m(double position_m, double dead_path_m, double air_index_at_zero,
                             double air_index_now);

}  // namespace idm::drivers
