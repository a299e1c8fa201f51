#include <gtest/gtest.h>

#include <cstdio>
#include <fstream>

#include "model/stage.h"

using namespace idm::model;

TEST(Stage, DefaultsAreTable1) {
  const StageParams s;
  EXPECT_DOUBLE_EQ(s.slider_mass_kg, 0.16557);
  EXPECT_DOUBLE_EQ(s.counter_mass_kg, 0.05761);
  EXPECT_DOUBLE_EQ(s.friction_coefficient, 0.4);
  EXPECT_DOUBLE_EQ(s.gravity_m_s2, 9.8);
  EXPECT_DOUBLE_EQ(s.stroke_m, 20.35e-6);
  EXPECT_DOUBLE_EQ(s.step_correction, 0.35);
  EXPECT_DOUBLE_EQ(s.stiffness_n_m, 5.7e6);
  EXPECT_DOUBLE_EQ(s.damping_n_s_m, 230);
  EXPECT_NO_THROW(validate(s));
}

// The sample sweep's stage.yaml (tests/data/README.md: idm-model sweep on the Table 1 stage,
// --noise 2e-9).
TEST(Stage, ReadsTheSampleDatasetStageFile) {
  const StageFile f = load_stage_file(std::string(IDM_SAMPLE_SWEEP_DIR) + "/stage.yaml",
                                      {.strict = false, .require_dataset_keys = true});
  EXPECT_DOUBLE_EQ(f.stage.slider_mass_kg, 0.16557);
  EXPECT_DOUBLE_EQ(f.interferometer.resolution_m, 9.8906e-09);
  EXPECT_DOUBLE_EQ(f.interferometer.noise_m, 2e-9);
}

// A dataset's stage.yaml from elsewhere may hold only the keys the format requires
// (docs/sweep-dataset.md): the optional ones keep their defaults.
TEST(Stage, ADatasetStageFileNeedsOnlyTheRequiredKeys) {
  const StageFile f =
      parse_stage_yaml(YAML::Load("stage:\n"
                                  "  slider_mass_kg: 0.2\n"
                                  "  counter_mass_kg: 0.07\n"
                                  "  friction_coefficient: 0.45\n"
                                  "  gravity_m_s2: 9.81\n"
                                  "  stroke_m: 15e-6\n"
                                  "  step_correction: 0.5\n"
                                  "interferometer:\n"
                                  "  resolution_m: 5e-9\n"),
                       "stage.yaml", {.strict = false, .require_dataset_keys = true});
  EXPECT_EQ(f.stage.friction_coefficient, 0.45);
  EXPECT_EQ(f.stage.step_correction, 0.5);
  EXPECT_EQ(f.interferometer.resolution_m, 5e-9);
  EXPECT_EQ(f.stage.stiffness_n_m, StageParams{}.stiffness_n_m);
  EXPECT_EQ(f.stage.damping_n_s_m, StageParams{}.damping_n_s_m);
  EXPECT_EQ(f.interferometer.noise_m, 0.0);
}

TEST(Stage, RoundTripsThroughYaml) {
  StageFile f;
  f.stage.slider_mass_kg = 0.2345678901234567;
  f.stage.stiffness_n_m = 1.25e7;
  f.interferometer.noise_m = 2e-9;
  const StageFile g = parse_stage_yaml(YAML::Load(to_yaml(f)), "mem");
  EXPECT_EQ(g.stage.slider_mass_kg, f.stage.slider_mass_kg);
  EXPECT_EQ(g.stage.stiffness_n_m, f.stage.stiffness_n_m);
  EXPECT_EQ(g.interferometer.noise_m, f.interferometer.noise_m);
}

static std::string error_of(const std::string& yaml, StageYamlOptions o = {}) {
  try {
    parse_stage_yaml(YAML::Load(yaml), "stage.yaml", o);
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

TEST(Stage, BadValuesNameFileLineKeyAndRange) {
  EXPECT_EQ(error_of("stage:\n  slider_mass_kg: -1\n"),
            "stage.yaml:2: stage.slider_mass_kg: -1 is out of range, allowed [1e-06, 1000]");
  EXPECT_EQ(error_of("stage:\n  counter_mass_kg: 0.05\n  friction_coefficient: abc\n"),
            "stage.yaml:3: stage.friction_coefficient: 'abc' is not a number");
  EXPECT_NE(error_of("stage:\n  stroke_m: .nan\n").find("stage.stroke_m: must be finite"),
            std::string::npos);
  EXPECT_EQ(error_of("stage:\n  wobble: 1\n", {.strict = true}),
            "stage.yaml:2: stage.wobble: unknown key, allowed counter_mass_kg, damping_n_s_m, "
            "friction_coefficient, gravity_m_s2, slider_mass_kg, step_correction, stiffness_n_m, "
            "stroke_m, travel_m");
  EXPECT_NE(
      error_of("stage:\n  strok_m: 1e-5\n", {.strict = true}).find("did you mean 'stroke_m'?"),
      std::string::npos);
  EXPECT_EQ(error_of("stage:\n  wobble: 1\n"), "");  // ignored unless strict
  EXPECT_NE(error_of("stage:\n  slider_mass_kg: 0.1\n", {.require_dataset_keys = true})
                .find("missing required key"),
            std::string::npos);
}

TEST(Stage, MissingFileIsAnInputError) {
  EXPECT_THROW(load_stage_file("/nonexistent/stage.yaml"), InputError);
}
