// What one trial of a sweep shows: the slider at every cycle end, the first and the steady step,
// their spread, how long the transient lasts, how far the slider went the wrong way, and the region
// the trial falls in. Works on any sweep in the dataset format (any sample rate, quantized and
// noisy positions): cycle-end positions are read from the samples around t = kT, never assumed to
// be on the time grid.
#pragma once

#include <string>
#include <vector>

#include "recording/dataset.h"
#include "model/impulse_model.h"

namespace idm::analysis {

// The dataset format lives one layer down (recording/), shared with the daemon's recorder.
using recording::Dataset;
using recording::TrialInfo;
using recording::TrialSeries;
using model::InputError;

struct TrialFeatures {
  std::vector<double> cycle_end_m;  // x(kT) - x(0), k = 1..N (last sample at or before kT)
  // Steps between the instants where the steady cycle rests (before each fast corner: kT for
  // duty < 0.5, kT + duty T for duty >= 0.5, whose first "step" is the slow first extension).
  double first_step_m = 0;
  double steady_step_m = 0;         // median step over the second half of the burst
  double steady_sd_m = 0;           // spread of those steps
  int transient_cycles = 0;         // steps (from the first) that differ from the steady step
  double reverse_m = 0;             // largest excursion against the net direction, >= 0
  model::Region region = model::Region::Cutoff;
};

// `resolution_m` is one count of the position word; `noise_m` the sensor's rms noise (0 if
// unknown). Tolerances scale with both. Throws InputError (naming the trial) when the trial does not
// cover its burst (t from <= 0 to >= cycles / freq).
TrialFeatures trial_features(const TrialInfo& info, const TrialSeries& series, double resolution_m,
                             double noise_m);

// The median (the mean of the middle two for an even count); 0 for none.
double median(std::vector<double> values);

// The position at time t by linear interpolation between the samples around it.
double position_at(const TrialSeries& series, double t_s);

// The committee vote of the paper: the region most trials show (ties: the later of cut-off,
// one-step, multi-step, i.e. the more cautious label).
model::Region majority_region(const std::vector<model::Region>& regions);

}  // namespace idm::analysis
