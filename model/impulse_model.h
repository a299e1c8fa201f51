// The impulse model of Yang, Jeng, Chieng (2011): impulse ratio, regions, step sizes,
// first-cycle velocities, and an exact event simulation of the ideal model.
//
// Sign convention (the paper's): an actuator velocity jump dxi gives the slider dX' = -m/(M+m) dxi,
// so duty < 0.5 moves the slider in the negative direction and duty > 0.5 in the positive one.
#pragma once

#include <vector>

#include "model/stage.h"
#include "model/waveform.h"

namespace idm::model {

enum class Region { Cutoff, OneStep, MultiStep };

// The one table of region names: "cutoff", "one-step", "multi-step" (the specs, idm-model, the
// calibration file) and the protocol's words "CUTOFF", "ONESTEP", "MULTISTEP" (REGion?).
const char* region_name(Region region);
const char* region_protocol_name(Region region);

// beta = m S / ((M+m) mu g T^2), eq 18.
double impulse_ratio(const StageParams& stage, double freq_hz, double stroke_m);

// The four boundaries of eqs 19/23, 26-29 for 0 < duty < 0.5.
struct RegionBoundaries {
  double cutoff;        // (1-d) d^2        eqs 19, 23
  double stop_in_ext;   // d^2              eq 25: the slider stops inside the first extension
  double first_rest_a;  // (1-d)(1-2d)      eq 26
  double first_rest_b;  // (1-d)^2 d        eq 27
};
RegionBoundaries region_boundaries(double duty);

// Region of (beta, duty) for 0 < duty < 0.5 by the paper's closed form, as docs/model.md writes it.
Region region_closed_form(double beta, double duty);

// Region for any 0 < duty < 1: the closed form below 0.5, the exact event simulation from 0.5 on
// (a burst from rest, actuator at 0, extension first; cut-off = no motion after the first two
// cycles, one-step = at rest at t = T with a non-zero steady step).
Region region(double beta, double duty);

// Region of the ideal model by the event simulation alone (any duty), for checks.
Region region_by_event_simulation(double beta, double duty, int max_cycles = 400);

// Steady step of the ideal model, eq 21, in m; 0 in cut-off. For duty > 0.5 the mirror of
// duty' = 1 - duty with the sign flipped. duty = 0.5 gives 0.
double steady_step_ideal_m(const StageParams& stage, double freq_hz, double duty, double stroke_m);
// eq 22: alpha times eq 21 (the stage's step_correction).
double steady_step_corrected_m(const StageParams& stage, double freq_hz, double duty,
                               double stroke_m);

// Slider velocities of the first cycle from rest (eqs 25-27), for 0 < duty < 0.5, m/s.
struct FirstCycleVelocities {
  double end_of_extension_m_s;  // X'(duty T-), eq 25
  double end_of_cycle_m_s;      // X'(T-), eqs 26-27
};
FirstCycleVelocities first_cycle_velocities(const StageParams& stage, double freq_hz, double duty,
                                            double stroke_m);

// Everything about one (f, duty, stroke) cell.
struct ImpulseCell {
  double beta = 0;
  Region region = Region::Cutoff;
  double step_ideal_m = 0;  // eq 21
  double step_m = 0;        // eq 22
};
ImpulseCell impulse_cell(const StageParams& stage, double freq_hz, double duty, double stroke_m);

// Exact event simulation of the ideal impulse model: velocity jumps at actuator corners (eqs 1-3),
// constant Coulomb deceleration mu g between them, rest is kept once reached.
class ImpulseEventSimulator {
 public:
  explicit ImpulseEventSimulator(const StageParams& stage);
  void reset(double position_m = 0, double velocity_m_s = 0, double actuator_rate_m_s = 0);
  // The actuator rate jumps to new_rate_m_s now: the slider gets -m/(M+m) times the jump.
  void corner(double new_rate_m_s);
  // Slides for dt_s under friction at the current actuator rate.
  void advance(double dt_s);
  // One whole burst: corners and phases of the waveform.
  void run(const TriangleWave& wave);

  double position_m() const { return position_m_; }
  double velocity_m_s() const { return velocity_m_s_; }

 private:
  double mass_ratio_;
  double decel_m_s2_;
  double position_m_ = 0;
  double velocity_m_s_ = 0;
  double rate_m_s_ = 0;
};

// Slider positions at t = T, 2T, ..., N T of a burst from rest (actuator at 0, extension first).
std::vector<double> cycle_end_positions_m(const StageParams& stage, const TriangleWave& wave);

// Exact motion under a constant deceleration until rest (used by the event simulation and by the
// rigid plant): advances x and v by dt, v stays exactly 0 once reached.
inline void coulomb_slide(double& x_m, double& v_m_s, double decel_m_s2, double dt_s) {
  if (v_m_s == 0.0 || dt_s <= 0.0) return;
  const double speed = v_m_s > 0 ? v_m_s : -v_m_s;
  const double sign = v_m_s > 0 ? 1.0 : -1.0;
  const double t_stop = speed / decel_m_s2;
  if (t_stop > dt_s) {
    x_m += sign * (speed * dt_s - 0.5 * decel_m_s2 * dt_s * dt_s);
    v_m_s = sign * (speed - decel_m_s2 * dt_s);
  } else {
    x_m += sign * 0.5 * speed * t_stop;
    v_m_s = 0.0;
  }
}

}  // namespace idm::model
