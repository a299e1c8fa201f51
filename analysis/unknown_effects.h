// Effects the library does not have, made here for idm-gap validate: a sweep generated with one
// of them must be diagnosed as an unexplained gap, never as a library effect. Each acts on the
// command on its way to the actuator (simulated_sweep.h, HiddenDistortion).
//
// * stroke_saturation: the actuator cannot extend past a fraction of the nominal stroke; beyond
//   it the elongation bends over smoothly (a knee of width 0.1 S) and flattens. A triangle that
//   reaches the knee loses its fast corner at the top: the velocity falls to zero on the way up
//   and comes back only on the way down. Only the larger strokes reach it.
// * thermal_stroke: the stroke falls with the power the stack dissipates, which grows with the
//   drive frequency: S (1 - loss f / f_ref), f_ref the sweep's highest frequency. Every corner of
//   a cell is scaled alike, so no rounding and no loop: a gain that depends on the cell's
//   frequency.
#pragma once

#include <map>
#include <memory>
#include <string>
#include <vector>

#include "analysis/simulated_sweep.h"

namespace idm::analysis {

// The names validate can hide ("stroke_saturation", "thermal_stroke").
const std::vector<std::string>& unknown_effect_names();

// The distortion `name` with its strength drawn from `u01` (in [0, 1]) for a sweep whose largest
// stroke is `max_stroke_m` and highest frequency `max_freq_hz`; its parameters in `params`.
// Throws std::invalid_argument for another name.
std::unique_ptr<HiddenDistortion> make_unknown_effect(const std::string& name, double u01,
                                                      double max_stroke_m, double max_freq_hz,
                                                      std::map<std::string, double>& params);

}  // namespace idm::analysis
