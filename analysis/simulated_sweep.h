// A characterization sweep run on the simulated stage and written in the sweep dataset format:
// the paper's experiment (a grid of frequency, duty and stroke, several trials per cell, each on a
// different stretch of the guide) for idm-model sweep and idm-gap validate.
//
// The stage is driven by the ideal triangle (every corner stepped to exactly), whatever the rate
// the interferometer is sampled at: a lab's DAC need not update at the sensor's rate, and a 10 kHz
// sensor does not turn the command into a staircase. Under an actuator chain the plant runs at
// `plant_rate_hz`; without one it takes steps of at most `max_step_s` (velocity-dependent friction
// and friction that varies along the guide are integrated on that grid).
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "model/simulation.h"
#include "model/stage.h"
#include "recording/dataset.h"

namespace idm::analysis {

// Something the library does not model, for validate (validate.h): it changes the command on its
// way to the actuator chain (an actuator defect) and/or the reading of the slider (a sensor
// defect). One object per trial; stateless between trials.
class HiddenDistortion {
 public:
  virtual ~HiddenDistortion() = default;
  // A trial starts: its waveform and where on the guide the slider sits.
  virtual void start(double freq_hz, double duty, double stroke_m, double guide_pos_m) = 0;
  // The command the actuator receives for the commanded elongation xi_m at time t_s.
  virtual double command_m(double t_s, double xi_m) const = 0;
};

struct SweepPlan {
  std::vector<double> freqs_hz;
  std::vector<double> duties;
  std::vector<double> strokes_m;  // empty: the stage's stroke
  int trials = 3;
  int cycles = 12;
  double sample_rate_hz = 20e3;
  std::uint64_t seed = 1;
  double guide_length_m = 40e-3;           // trials start anywhere on the guide
  double rest_before_s = 0.5e-3;           // command at rest before t = 0
  int rest_cycles_after = 2;               // settling after the burst, in periods
  double plant_rate_hz = 4e6;              // plant rate under an actuator chain
  double max_step_s = 1e-6;                // longest plant step without one
  HiddenDistortion* distortion = nullptr;  // validate's effect outside the library
};

// Checks the plan; throws model::InputError naming the field and the allowed range.
void validate(const SweepPlan& plan);

// Runs the plan on the simulated stage (a fresh start per trial) and hands every trial to `sink`
// in plan order (stroke, frequency, duty, trial); no files. Returns the number of trials.
std::size_t simulate_sweep(
    const model::StageFile& stage, const model::SimConfig& sim, const SweepPlan& plan,
    const std::function<void(const recording::TrialInfo&, recording::TrialSeries&&)>& sink);

// Runs the plan on a fresh simulated stage per trial and writes DATASET `out_dir` (crash-safe,
// trial by trial). Returns the number of trials written.
std::size_t run_simulated_sweep(const model::StageFile& stage, const model::SimConfig& sim,
                                const SweepPlan& plan, const std::string& out_dir);

}  // namespace idm::analysis
