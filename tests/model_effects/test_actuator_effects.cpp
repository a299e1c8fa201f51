// The factory: effects by the gap report's names and keys, defaults for missing keys, errors that
// name the effect and the key.
#include <gtest/gtest.h>

#include <map>
#include <string>

#include "model/effects/actuator_effects.h"
#include "model/effects/amplifier.h"
#include "model/effects/creep.h"
#include "model/effects/hysteresis.h"
#include "model/effects/quantization.h"
#include "model/stage.h"

using namespace idm::model;

namespace {

std::string error_of(const std::string& name, const std::map<std::string, double>& params) {
  try {
    make_actuator_effect(name, params);
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(ActuatorEffects, BuildsEachByName) {
  auto amp = make_actuator_effect("amplifier", {{"order", 2}, {"cutoff_hz", 2400}});
  ASSERT_NE(dynamic_cast<Amplifier*>(amp.get()), nullptr);
  EXPECT_EQ(dynamic_cast<Amplifier&>(*amp).params().order, 2);
  EXPECT_EQ(dynamic_cast<Amplifier&>(*amp).params().cutoff_hz, 2400.0);
  EXPECT_EQ(dynamic_cast<Amplifier&>(*amp).params().slew_rate_m_s, 0.0);

  auto hyst = make_actuator_effect("hysteresis", {{"ratio", 0.1}});
  ASSERT_NE(dynamic_cast<Hysteresis*>(hyst.get()), nullptr);
  EXPECT_EQ(dynamic_cast<Hysteresis&>(*hyst).params().ratio, 0.1);
  EXPECT_EQ(dynamic_cast<Hysteresis&>(*hyst).params().stroke_m, 20.35e-6);

  auto creep = make_actuator_effect("creep", {{"per_decade", 0.02}});
  ASSERT_NE(dynamic_cast<Creep*>(creep.get()), nullptr);
  EXPECT_EQ(dynamic_cast<Creep&>(*creep).params().per_decade, 0.02);

  auto dac = make_actuator_effect("quantization", {{"bits", 10}, {"update_rate_hz", 2e5}});
  ASSERT_NE(dynamic_cast<Quantization*>(dac.get()), nullptr);
  EXPECT_EQ(dynamic_cast<Quantization&>(*dac).params().bits, 10);
  EXPECT_EQ(dynamic_cast<Quantization&>(*dac).params().update_rate_hz, 2e5);
  EXPECT_EQ(dynamic_cast<Quantization&>(*dac).params().full_scale_m, 2.0 * 20.35e-6);
}

TEST(ActuatorEffects, MissingKeysKeepTheDefaults) {
  auto amp = make_actuator_effect("amplifier", {});
  const Amplifier::Params defaults;
  EXPECT_EQ(dynamic_cast<Amplifier&>(*amp).params().order, defaults.order);
  EXPECT_EQ(dynamic_cast<Amplifier&>(*amp).params().cutoff_hz, defaults.cutoff_hz);
  auto dac = make_actuator_effect("quantization", {});
  EXPECT_EQ(dynamic_cast<Quantization&>(*dac).params().bits, 12);
  EXPECT_NE(make_actuator_effect("creep", {}), nullptr);
  EXPECT_NE(make_actuator_effect("hysteresis", {}), nullptr);
}

TEST(ActuatorEffects, OtherNamesAreNotActuatorEffects) {
  EXPECT_EQ(make_actuator_effect("stribeck", {{"static_over_kinetic", 1.2}}), nullptr);
  EXPECT_EQ(make_actuator_effect("tilt", {}), nullptr);
  EXPECT_EQ(make_actuator_effect("Amplifier", {}), nullptr);
  EXPECT_EQ(actuator_effect_names(),
            (std::vector<std::string>{"amplifier", "hysteresis", "creep", "quantization"}));
  EXPECT_TRUE(actuator_effect_keys("tilt").empty());
}

TEST(ActuatorEffects, ErrorsNameTheEffectAndTheKey) {
  EXPECT_EQ(error_of("amplifier", {{"gain", 2.0}}),
            "amplifier.gain: unknown parameter, allowed order, cutoff_hz, slew_rate_m_s");
  EXPECT_EQ(error_of("quantization", {{"update_rate", 1e5}}),
            "quantization.update_rate: unknown parameter, did you mean 'update_rate_hz'? allowed "
            "bits, update_rate_hz, full_scale_m");
  EXPECT_EQ(error_of("amplifier", {{"cutoff_hz", -3}}),
            "amplifier.cutoff_hz: -3 is out of range, allowed (0, 1000000]");
  EXPECT_EQ(error_of("amplifier", {{"order", 1.5}}),
            "amplifier.order: 1.5 is out of range, allowed an integer in [1, 2]");
  EXPECT_EQ(error_of("quantization", {{"bits", 25}}),
            "quantization.bits: 25 is out of range, allowed an integer in [1, 24]");
  EXPECT_EQ(error_of("hysteresis", {{"ratio", -0.1}}),
            "hysteresis.ratio: -0.1 is out of range, allowed [0, 0.5]");
  EXPECT_EQ(error_of("creep", {{"per_decade", 1.0}}),
            "creep.per_decade: 1 is out of range, allowed [0, 0.1]");
}
