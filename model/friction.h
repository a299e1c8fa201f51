// Friction between the slider and the guide, and gravity along a tilted guide.
//
// Coulomb friction mu_k N while sliding; sticking holds while the force needed to hold the slider
// is at most mu_s N (mu_s = static_over_kinetic * mu_k). Optional effects (docs/gap-report.md):
// stribeck (mu falls from mu_s at rest to mu_k over stribeck_velocity_m_s), friction_spread
// (mu_k varies smoothly along the guide, relative_sd, seeded), tilt (gravity along the axis).
#pragma once

#include <cstdint>

#include "model/stage.h"

namespace idm::model {

// A smooth random multiplier 1 + mean_shift + relative_sd * n(x) along the guide; n has unit
// variance and is linear between independent normal values every correlation_m. Seeded,
// deterministic, unbounded. mean_shift (default 0): the stretch in use is on average that much off
// the nominal mu (a short guide's few correlation lengths do not average to the nominal).
class GuideProfile {
 public:
  GuideProfile() = default;
  GuideProfile(double relative_sd, double correlation_m, std::uint64_t seed,
               double mean_shift = 0.0);
  double multiplier(double x_m) const { return flat() ? 1.0 : varying_multiplier(x_m); }
  double relative_sd() const { return relative_sd_; }
  bool flat() const { return relative_sd_ == 0.0 && mean_shift_ == 0.0; }

 private:
  double varying_multiplier(double x_m) const;
  double node_value(std::int64_t index) const;
  double relative_sd_ = 0.0;
  double mean_shift_ = 0.0;
  double correlation_m_ = 1e-3;
  std::uint64_t seed_ = 0;
};

struct FrictionLaw {
  double kinetic_coefficient = 0.4;
  double static_over_kinetic = 1.0;
  double stribeck_velocity_m_s = 0.0;  // 0: the coefficient drops to kinetic at any motion
  double tilt_rad = 0.0;               // > 0: the positive direction is uphill
  GuideProfile profile;

  static FrictionLaw coulomb(const StageParams& stage) {
    FrictionLaw f;
    f.kinetic_coefficient = stage.friction_coefficient;
    return f;
  }
  double kinetic_at(double x_m) const { return kinetic_coefficient * profile.multiplier(x_m); }
  double static_at(double x_m) const { return static_over_kinetic * kinetic_at(x_m); }
  // Sliding coefficient at a speed (Stribeck curve); at speed 0 it is the static coefficient.
  double sliding_at(double speed_m_s, double x_m) const;
  bool velocity_dependent() const {
    return static_over_kinetic != 1.0 && stribeck_velocity_m_s > 0.0;
  }
};

}  // namespace idm::model
