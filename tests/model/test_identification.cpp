// WRLS identification of K and C (eqs 32-34) from simulated held-slider triangle data.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "model/identification.h"
#include "model/simulation.h"

using namespace idm::model;

namespace {
// Held slider, triangle command at `f`, counter mass read by the interferometer (quantized, noisy).
void held_slider_data(const StageParams& s, double f, double ts, double seconds, double noise_m,
                      std::vector<double>& xi, std::vector<double>& x) {
  CompliantPlant plant(s, FrictionLaw::coulomb(s));
  plant.reset(0, 0);
  plant.set_slider_held(true);
  const TriangleWave w{f, 0.3, s.stroke_m, static_cast<int>(seconds * f)};
  std::mt19937_64 rng(3);
  std::normal_distribution<double> n(0, 1);
  const double res = 632.991e-9 / 64;
  const int count = static_cast<int>(seconds / ts);
  for (int k = 1; k <= count; ++k) {
    const double cmd = w.xi_m(k * ts);
    plant.step(ts, cmd);
    xi.push_back(cmd);
    x.push_back(std::round((plant.actuator_length_m() + noise_m * n(rng)) / res) * res);
  }
}
}  // namespace

TEST(WeightedRls, RecoversALinearModelExactlyWithoutNoise) {
  WeightedRls rls(2, 0.995, 1.0);
  Eigen::VectorXd h(2);
  for (int i = 0; i < 4000; ++i) {
    h << std::sin(0.1 * i), std::cos(0.37 * i);
    rls.update(h, 2.5 * h(0) - 0.75 * h(1));
  }
  EXPECT_NEAR(rls.estimate()(0), 2.5, 1e-6);
  EXPECT_NEAR(rls.estimate()(1), -0.75, 1e-6);
}

TEST(Identification, RecoversKAndCWithinFivePercentFromQuantizedNoisyData) {
  const StageParams s;  // K 5.7e6 N/m, C 230 N s/m
  std::vector<double> xi, x;
  held_slider_data(s, 1000.0, 10e-6, 0.5, 2e-9, xi, x);
  const StiffnessEstimate e = identify_stiffness(xi, x, 10e-6, s.counter_mass_kg);
  EXPECT_NEAR(e.stiffness_n_m, 5.7e6, 0.05 * 5.7e6);
  EXPECT_NEAR(e.damping_n_s_m, 230, 0.05 * 230);
}

TEST(Identification, WorksForAnotherStage) {
  StageParams s;
  s.counter_mass_kg = 0.02;
  s.stiffness_n_m = 2e6;
  s.damping_n_s_m = 60;
  std::vector<double> xi, x;
  held_slider_data(s, 700.0, 10e-6, 0.5, 2e-9, xi, x);
  const StiffnessEstimate e = identify_stiffness(xi, x, 10e-6, s.counter_mass_kg);
  EXPECT_NEAR(e.stiffness_n_m, 2e6, 0.05 * 2e6);
  EXPECT_NEAR(e.damping_n_s_m, 60, 0.05 * 60);
}

TEST(Identification, ThePapersBackwardDifferencesAreBiasedAtThisRate) {
  const StageParams s;
  std::vector<double> xi, x;
  held_slider_data(s, 1000.0, 10e-6, 0.2, 0.0, xi, x);
  const StiffnessEstimate central =
      identify_stiffness(xi, x, 10e-6, s.counter_mass_kg, 0.995, Differences::Central);
  const StiffnessEstimate backward =
      identify_stiffness(xi, x, 10e-6, s.counter_mass_kg, 0.995, Differences::Backward);
  EXPECT_LT(std::fabs(central.damping_n_s_m - 230), std::fabs(backward.damping_n_s_m - 230));
}
