// What one trial of a sweep shows: the slider at every cycle end, the first and the steady step,
// their spread, how long the transient lasts, how far the slider went the wrong way, and the region
// the trial falls in. Works on any sweep in the dataset format (any sample rate, quantized and
// noisy positions): rest positions are read from the samples around the rest instants, never
// assumed to be on the time grid.
//
// Steps are read where the steady cycle rests: just before each fast corner (the end of the slow
// phase), at t = kT for duty < 0.5 and t = kT + duty T for duty >= 0.5, from the last sample at or
// before that instant (the next one may already carry the jump of the corner). A model is read by
// the same rule (features_from_marks) at the same sample instants, so model and measurement are
// compared by one procedure.
#pragma once

#include <string>
#include <vector>

#include "model/impulse_model.h"
#include "recording/dataset.h"

namespace idm::analysis {

// The dataset format lives one layer down (recording/), shared with the daemon's recorder.
using model::InputError;
using recording::Dataset;
using recording::TrialInfo;
using recording::TrialSeries;

struct TrialFeatures {
  std::vector<double> cycle_end_m;  // x(kT) - x(0), k = 1..N (last sample at or before kT)
  // Steps between the rest instants; for duty >= 0.5 the first "step" is the slow first extension.
  double first_step_m = 0;
  double steady_step_m = 0;  // median step over the second half of the burst
  double steady_sd_m = 0;    // spread of those steps
  int transient_cycles = 0;  // steps (from the first) that differ from the steady step
  double reverse_m = 0;      // largest excursion against the net direction, >= 0
  model::Region region = model::Region::Cutoff;
};

// The nominal rest instants of a burst: 0, then (duty >= 0.5) duty T, then k T + anchor for every
// cycle that has one. marks[0] is the start.
std::vector<double> rest_instants(double freq_hz, double duty, int cycles);

// The features of a burst from its positions at the rest instants (relative to the start, so
// marks[0] = 0). `resolution_m` is one count of the position word, `noise_m` the sensor's rms noise
// (0 if unknown); the tolerances scale with both. Leaves cycle_end_m and reverse_m empty.
TrialFeatures features_from_marks(const std::vector<double>& marks_m, double resolution_m,
                                  double noise_m);

// Every feature of a measured trial. Throws InputError (naming the trial) when the trial does not
// cover its burst (t from <= 0 to >= cycles / freq).
TrialFeatures trial_features(const TrialInfo& info, const TrialSeries& series, double resolution_m,
                             double noise_m);

// The sample instants a trial's rest positions are read at: for each rest instant, the time of the
// last sample at or before it (the instants a model is read at to compare like with like).
std::vector<double> read_instants(const TrialInfo& info, const TrialSeries& series);

// The tolerance on a step: four reading noises of a difference and 2 % of the step.
double step_tolerance_m(double step_m, double resolution_m, double noise_m);

// The median (the mean of the middle two for an even count); 0 for none.
double median(std::vector<double> values);

// The position at time t by linear interpolation between the samples around it.
double position_at(const TrialSeries& series, double t_s);

// The committee vote of the paper: the region most trials show (ties: the later of cut-off,
// one-step, multi-step, i.e. the more cautious label).
model::Region majority_region(const std::vector<model::Region>& regions);

}  // namespace idm::analysis
