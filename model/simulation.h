// The simulated stage: command -> actuator effects -> plant -> interferometer, as one object.
//
// This is what idm-model simulate/sweep, the `sim` driver and the gap diagnosis run. The plant is
// named (impulse | rigid | mck) and the effects are the library of docs/gap-report.md, each off
// unless configured, with the names and parameters used everywhere in the project.
#pragma once

#include <yaml-cpp/yaml.h>

#include <cstdint>
#include <limits>
#include <map>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "model/effects/actuator_effect.h"
#include "model/param_table.h"
#include "model/plant.h"
#include "model/stage.h"
#include "model/waveform.h"

namespace idm::model {

enum class PlantKind { Impulse, Rigid, MassDamperSpring };
const char* plant_name(PlantKind kind);
PlantKind parse_plant_name(const std::string& name);  // "impulse" | "rigid" | "mck"

struct EffectSpec {
  std::string name;
  std::map<std::string, double> params;
};

// The effect library: names, parameters (unit in the name), defaults and allowed ranges.
struct EffectParamInfo {
  const char* name;
  double default_value;
  double lo, hi;
  const char* meaning;
};
struct EffectInfo {
  const char* name;
  const char* what;
  std::vector<EffectParamInfo> params;
};
const std::vector<EffectInfo>& effect_library();
// Fills defaults, checks names and ranges; throws InputError naming effect, key and range.
EffectSpec complete_effect(const EffectSpec& spec, const std::string& where);
// "NAME:key=value,key=value" (the idm-model --effect form).
EffectSpec parse_effect_arg(const std::string& text);

struct SimConfig {
  PlantKind plant = PlantKind::Rigid;
  std::vector<EffectSpec> effects;  // completed (defaults filled)
  std::uint64_t seed = 1;
  double noise_m = 0.0;           // interferometer noise, rms (before quantization)
  double internal_rate_hz = 1e6;  // plant rate when actuator effects smooth the command
  // Where the simulated slider is and what bounds it (the daemon's simulated device):
  double start_position_m = 0.0;  // at rest here when the device is first opened
  double end_stop_low_m = std::numeric_limits<double>::quiet_NaN();  // hard stops (NaN: none)
  double end_stop_high_m = std::numeric_limits<double>::quiet_NaN();
  double reference_mark_m = std::numeric_limits<double>::quiet_NaN();  // an index mark (NaN: none)
  bool has(const std::string& effect) const;
  const EffectSpec* find(const std::string& effect) const;
};
// The `sim:` section's keys (the reader's table; config/README.md's rows).
const ParamTable<SimConfig>& sim_params();
// The `sim:` section: plant, effects {NAME: {PARAM: value}}, seed, noise_m, internal_rate_hz,
// start_position_m, end_stops_m [low, high], reference_mark_m. Unknown keys: errors.
SimConfig parse_sim_yaml(const YAML::Node& node, const std::string& file);

// One trial's time series, as in docs/sweep-dataset.md.
struct TrialSamples {
  std::vector<double> t_s, xi_cmd_m, x_m;
};

class SimulatedStage {
 public:
  SimulatedStage(const StageParams& stage, const InterferometerParams& ifm,
                 const SimConfig& config);
  SimulatedStage(const SimulatedStage&) = delete;
  SimulatedStage& operator=(const SimulatedStage&) = delete;
  ~SimulatedStage() = default;

  // Slider at rest at x_m (absolute guide position), actuator at 0; reseeds the sensor noise.
  void reset(double x_m, std::uint64_t noise_seed);
  // Advances dt_s with the command moving linearly to xi_cmd_end_m (no allocation).
  void step(double dt_s, double xi_cmd_end_m);
  // A burst from rest, sampled at sample_rate_hz from -pre_s to duration + post_s; samples
  // appended to out. Corners of the ideal triangle are integrated exactly.
  void run_burst(const TriangleWave& wave, double sample_rate_hz, double pre_s, double post_s,
                 TrialSamples& out);

  double position_m() const { return plant_->position_m(); }  // true position
  // An external push: the slider moves by dx_m at once (then the end stops hold it).
  void displace(double dx_m);
  double velocity_m_s() const { return plant_->velocity_m_s(); }
  double measured_m();  // interferometer reading: noise, then quantized to one count
  Plant& plant() { return *plant_; }
  const SimConfig& config() const { return config_; }
  const StageParams& stage() const { return stage_; }
  bool smooths_command() const { return !chain_.empty(); }
  // With a chain whose every effect is piecewise linear (hysteresis): for a command moving at
  // rate_m_s, the time until the actuator's slope next changes; negative when the chain is not
  // piecewise linear. Steps that end at these kinks (with internal_rate_hz low enough not to
  // subdivide them) give the plant the chain's output exactly.
  double next_kink_s(double rate_m_s) const;

 private:
  void advance(double dt_s, double xi_cmd_end_m);
  StageParams stage_;
  InterferometerParams ifm_;
  SimConfig config_;
  std::unique_ptr<Plant> plant_;
  std::vector<std::unique_ptr<ActuatorEffect>> chain_;
  double xi_cmd_m_ = 0;
  std::mt19937_64 noise_rng_;
  std::normal_distribution<double> normal_{0.0, 1.0};
};

// The stage the plant sees once actuator_compliance (K, C) is applied.
StageParams effective_stage(const StageParams& stage, const SimConfig& config);
FrictionLaw friction_law(const StageParams& stage, const SimConfig& config);

}  // namespace idm::model
