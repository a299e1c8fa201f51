#include "analysis/unknown_effects.h"

#include <stdexcept>

namespace idm::analysis {

namespace {

class StrokeSaturation final : public HiddenDistortion {
 public:
  StrokeSaturation(double knee_m, double width_m) : knee_m_(knee_m), width_m_(width_m) {}
  void start(double, double, double, double) override {}
  double command_m(double, double xi_m) const override {
    // y = xi up to the knee, then y = xi - (xi - knee)^2 / (4 w) (slope falling to 0), then flat
    const double over = xi_m - knee_m_;
    if (over <= 0) return xi_m;
    if (over >= 2 * width_m_) return knee_m_ + width_m_;
    return xi_m - over * over / (4 * width_m_);
  }

 private:
  double knee_m_, width_m_;
};

class ThermalStroke final : public HiddenDistortion {
 public:
  ThermalStroke(double loss, double ref_hz) : loss_(loss), ref_hz_(ref_hz) {}
  void start(double freq_hz, double, double, double) override {
    gain_ = 1.0 - loss_ * freq_hz / ref_hz_;
  }
  double command_m(double, double xi_m) const override { return gain_ * xi_m; }

 private:
  double loss_, ref_hz_, gain_ = 1.0;
};

}  // namespace

const std::vector<std::string>& unknown_effect_names() {
  static const std::vector<std::string> names = {"stroke_saturation", "thermal_stroke"};
  return names;
}

std::unique_ptr<HiddenDistortion> make_unknown_effect(const std::string& name, double u01,
                                                      double max_stroke_m, double max_freq_hz,
                                                      std::map<std::string, double>& params) {
  if (name == "stroke_saturation") {
    const double knee = (0.7 + 0.15 * u01) * max_stroke_m;
    params = {{"knee_over_stroke", knee / max_stroke_m}, {"knee_width_over_stroke", 0.1}};
    return std::make_unique<StrokeSaturation>(knee, 0.05 * max_stroke_m);
  }
  if (name == "thermal_stroke") {
    const double loss = 0.05 + 0.1 * u01;
    params = {{"stroke_loss_at_highest_frequency", loss}};
    return std::make_unique<ThermalStroke>(loss, max_freq_hz);
  }
  throw std::invalid_argument("no effect '" + name + "' outside the library");
}

}  // namespace idm::analysis
