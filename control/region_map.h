// The region map: for the configured stage and output device, the impulse model's region, the
// predicted step and the margin to the one-step boundary under a stated uncertainty of the friction
// coefficient, for every (frequency, duty, stroke) cell of a grid.
//
// Sign convention (model/'s): duty < 0.5 moves the slider in the negative direction, duty > 0.5 in
// the positive one. A cell is "robustly one-step" when it is one-step for every mu in
// [mu (1-u), mu (1+u)]; beta scales as 1/mu, so that is beta in [beta/(1+u), beta/(1-u)].
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "model/impulse_model.h"
#include "model/stage.h"
#include "model/waveform.h"

namespace idm::control {

// What the output device can play. The daemon fills it from the driver's capabilities and the
// `control:` config; control/ never asks a device itself.
struct DeviceLimits {
  double min_freq_hz = 1.0;
  double max_freq_hz = 2000.0;
  // Clock of a buffered output. A burst is played as samples at k / rate, so a cell is playable
  // only when its period is a whole number P of samples and its extension a whole number k of them
  // (duty = k / P): the corners then fall on samples. 0: a device configured by parameters
  // (function generator), which plays any frequency and duty.
  double output_sample_rate_hz = 1e5;
  double min_stroke_m = 1e-6;
  double max_stroke_m = 20.35e-6;
  std::uint64_t max_burst_cycles = 1000000;
  // Most samples in one burst (N P + 1: the cycles and the final 0); 0: no limit.
  std::uint64_t max_burst_samples = 0;
};

// Throws model::InputError naming the key and the allowed range.
void validate(const DeviceLimits& limits, const std::string& where = "limits");

// Why a cell cannot be played (bit flags of RegionCell::limit_violations).
namespace limit_violation {
inline constexpr unsigned kFreqBelowMin = 1u << 0;
inline constexpr unsigned kFreqAboveMax = 1u << 1;
inline constexpr unsigned kOffSampleClock = 1u << 2;  // period or extension not whole samples
inline constexpr unsigned kStrokeOutOfRange = 1u << 3;
inline constexpr unsigned kBurstTooLong = 1u << 4;  // not even one cycle fits a burst
}  // namespace limit_violation

// "frequency above max, off sample clock" (empty for 0).
std::string describe_limit_violations(unsigned flags);

using model::ClockedWave;
using model::snap_to_sample_clock;

// The grid of the map.
struct RegionGrid {
  std::vector<double> freqs_hz;
  double duty_step = 0.005;  // duties duty_step, 2 duty_step, ... < 1, without 0.5 (no motion)
  std::vector<double> strokes_m;

  std::vector<double> duties() const;

  // min_hz, min_hz + step_hz, ... up to max_hz.
  static std::vector<double> frequency_steps(double min_hz, double max_hz, double step_hz);
  // `count` strokes spaced geometrically from max_m down to min_m (one when they are equal).
  static std::vector<double> stroke_steps(double min_m, double max_m, int count);
  // Frequencies every freq_step_hz from the device's lowest (at least freq_step_hz) to its
  // highest, and stroke_count strokes over its stroke range.
  static RegionGrid covering(const DeviceLimits& limits, double freq_step_hz = 10.0,
                             double duty_step = 0.005, int stroke_count = 4);
};

void validate(const RegionGrid& grid, const std::string& where = "grid");

struct RegionMapConfig {
  model::StageParams stage;
  DeviceLimits limits;
  RegionGrid grid = RegionGrid::covering(DeviceLimits{});
  // Relative uncertainty u of the friction coefficient: mu may lie anywhere in [mu(1-u), mu(1+u)].
  double friction_uncertainty = 0.15;
  // The one-step boundary is looked for by sampling the relative change of mu at this spacing
  // (and at exactly +/-u), then refined by bisection to 1e-12.
  double margin_scan_step = 0.005;
  // Margins are searched, and reported, up to this relative change of mu (< 1).
  double margin_search_limit = 0.5;
};

void validate(const RegionMapConfig& config, const std::string& where = "region_map");

// One (frequency, duty, stroke) cell.
struct RegionCell {
  // The waveform as played (snapped to the sample clock in a map).
  double freq_hz = 0;
  double duty = 0;
  double stroke_m = 0;
  std::uint32_t period_samples = 0;     // P; 0 without a sample clock or off it
  std::uint32_t extension_samples = 0;  // k
  unsigned limit_violations = 0;        // limit_violation flags
  std::uint64_t max_cycles = 0;         // most cycles in one burst of this cell the device plays

  // The impulse model at the nominal mu.
  double beta = 0;
  model::Region region = model::Region::Cutoff;
  double step_m = 0;  // steady step, eq 22 (the stage's step_correction), signed
  // A one-cycle burst from rest (actuator 0 -> 0, slider back at rest): the exact event simulation
  // of the ideal model times step_correction, signed. See burst_displacement_m.
  double single_burst_m = 0;

  // Over mu in [mu(1-u), mu(1+u)]: eq 22 at the two ends (it is linear in mu) and the one-cycle
  // burst at nine points. Meaningful where the cell stays one-step over the interval.
  double step_min_m = 0;
  double step_max_m = 0;
  double single_burst_min_m = 0;
  double single_burst_max_m = 0;

  // The relative change of mu (increase: toward cut-off for beta; decrease: toward multi-step)
  // that moves the cell out of one-step, up to margin_search_limit; 0 when the cell is not
  // one-step at the nominal mu.
  double margin_mu_increase = 0;
  double margin_mu_decrease = 0;
  bool robust_one_step = false;  // one-step, moving, and both margins > u

  bool within_limits() const { return limit_violations == 0; }
  // What a plan may use: robustly one-step and playable.
  bool usable() const { return robust_one_step && within_limits(); }
  double margin() const {
    return margin_mu_increase < margin_mu_decrease ? margin_mu_increase : margin_mu_decrease;
  }
  // +1: moves the slider positive (duty > 0.5); -1: negative.
  int direction() const { return duty > 0.5 ? 1 : -1; }
  double period_s() const { return 1.0 / freq_hz; }
  // Predicted displacement of a burst of `cycles` >= 1 cycles from rest, at the nominal mu:
  // single_burst_m + (cycles - 1) step_m. Exact for the ideal model times step_correction when the
  // cell is one-step (every cycle after the first is then the steady one).
  double burst_displacement_m(std::uint64_t cycles) const {
    return single_burst_m + static_cast<double>(cycles - 1) * step_m;
  }
};

// The ideal model's displacement of a burst of `cycles` cycles from rest, ending with the actuator
// at 0 and the slider at rest again (exact event simulation, including the slide after the last
// corner). Not scaled by step_correction.
double burst_displacement_ideal_m(const model::StageParams& stage, double freq_hz, double duty,
                                  double stroke_m, int cycles);

// Evaluates one cell at exactly (freq_hz, duty, stroke_m) (no snapping; off-clock values are
// flagged kOffSampleClock).
RegionCell evaluate_cell(const RegionMapConfig& config, double freq_hz, double duty,
                         double stroke_m);

class RegionMap {
 public:
  // Validates the config (model::InputError) and evaluates every grid cell.
  explicit RegionMap(RegionMapConfig config);

  const RegionMapConfig& config() const { return config_; }
  const std::vector<double>& freqs_hz() const { return config_.grid.freqs_hz; }
  const std::vector<double>& duties() const { return duties_; }
  const std::vector<double>& strokes_m() const { return config_.grid.strokes_m; }

  // Every grid cell, index (i_stroke * freqs + i_freq) * duties + i_duty, each at its snapped
  // waveform.
  const std::vector<RegionCell>& cells() const { return cells_; }
  const RegionCell& cell(std::size_t i_freq, std::size_t i_duty, std::size_t i_stroke) const;

  // The cell at any (freq_hz, duty, stroke_m), evaluated as given.
  RegionCell at(double freq_hz, double duty, double stroke_m) const;
  // The cell the device would play for (freq_hz, duty, stroke_m): snapped to the sample clock.
  RegionCell playable(double freq_hz, double duty, double stroke_m) const;

  // Indices into cells() of the usable cells (robustly one-step and within the limits), each
  // played waveform once (grid points that snap to the same waveform are merged), ascending.
  const std::vector<std::size_t>& usable_cells() const { return usable_; }
  template <class Fn>
  void for_each_usable_cell(Fn&& fn) const {
    for (std::size_t i : usable_) fn(cells_[i]);
  }
  std::size_t count(model::Region region) const;

 private:
  RegionMapConfig config_;
  std::vector<double> duties_;
  std::vector<RegionCell> cells_;
  std::vector<std::size_t> usable_;
};

}  // namespace idm::control
