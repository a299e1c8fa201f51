#include "model/friction.h"

#include <cmath>

namespace idm::model {

namespace {
// SplitMix64: a fast, well-mixed hash of (seed, index).
std::uint64_t mix(std::uint64_t z) {
  z += 0x9e3779b97f4a7c15ULL;
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}
double unit_open(std::uint64_t bits) {
  return (static_cast<double>(bits >> 11) + 0.5) * 0x1.0p-53;
}
}  // namespace

GuideProfile::GuideProfile(double relative_sd, double correlation_m, std::uint64_t seed,
                           double mean_shift)
    : relative_sd_(relative_sd),
      mean_shift_(mean_shift),
      correlation_m_(correlation_m),
      seed_(seed) {}

double GuideProfile::node_value(std::int64_t index) const {
  const std::uint64_t h = mix(seed_ ^ mix(static_cast<std::uint64_t>(index)));
  // Box-Muller from two independent uniforms
  const double u1 = unit_open(h), u2 = unit_open(mix(h));
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * M_PI * u2);
}

double GuideProfile::varying_multiplier(double x_m) const {
  const double s = x_m / correlation_m_;
  const double k = std::floor(s);
  const double w = s - k;
  const auto i = static_cast<std::int64_t>(k);
  // Linear between nodes, rescaled so the variance is 1 everywhere.
  const double n =
      ((1 - w) * node_value(i) + w * node_value(i + 1)) / std::sqrt((1 - w) * (1 - w) + w * w);
  const double m = 1.0 + mean_shift_ + relative_sd_ * n;
  return m > 0.05 ? m : 0.05;  // friction never vanishes or turns negative
}

double FrictionLaw::sliding_at(double speed_m_s, double x_m) const {
  const double mu_k = kinetic_at(x_m);
  if (!velocity_dependent()) return speed_m_s == 0.0 ? static_over_kinetic * mu_k : mu_k;
  const double r = speed_m_s / stribeck_velocity_m_s;
  return mu_k * (1.0 + (static_over_kinetic - 1.0) * std::exp(-r * r));
}

}  // namespace idm::model
