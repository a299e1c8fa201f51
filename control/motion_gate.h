// The motion gate: one check that every request able to move a slider passes before anything
// plays (a move, a STEP, a hold's correction, a sweep's trial; a reference alone drives to an end
// stop by design). It judges the positions the request may reach, worst case, from where the
// slider is measured now: they must stay within the soft limits (which lie within the travel,
// stage.travel_m). A slider already outside (limits just narrowed, a push) may move back, never
// farther out. Pure functions, real-time safe.
#pragma once

#include <cstdint>

namespace idm::control {

// The displacements a request may cause, relative to its start, worst case: lo_m <= 0 <= hi_m
// when it may move either way.
struct Excursion {
  double lo_m = 0;
  double hi_m = 0;
};

// An open-loop burst of `cycles` cycles of a cell whose predicted step is `step_m` (signed), the
// step model wrong by up to `uncertainty` of it (a share), and one cycle able to slip up to
// `slip_m` either way beyond that (a cell near a region boundary, a step the model does not see).
Excursion burst_excursion(std::uint64_t cycles, double step_m, double uncertainty, double slip_m);

// Whether a request from `position_m` with `excursion` stays where it may: every position it can
// reach within [soft_lower_m, soft_upper_m], or, from outside them, no farther out than it is.
bool excursion_allowed(double position_m, const Excursion& excursion, double soft_lower_m,
                       double soft_upper_m);

// A reading taken while a request plays, judged the same way: false once the slider is beyond
// the soft limits (by more than `tolerance_m`) and farther out than where it started. The request
// is then stopped at once.
bool reading_allowed(double reading_m, double start_m, double soft_lower_m, double soft_upper_m,
                     double tolerance_m);

// A closed-loop move's target: inside the soft limits (a move ends where it was sent).
bool target_allowed(double target_m, double soft_lower_m, double soft_upper_m);

}  // namespace idm::control
