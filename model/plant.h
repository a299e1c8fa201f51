// The time-domain plant: the slider on its guide driven by the actuator and the counter mass.
//
// Two actuator kinds behind one interface:
// * RigidPlant: the counter mass follows the actuator length exactly. Between samples the length
//   is linear, so the only forces are friction and gravity, and a change of actuator rate at a
//   sample is a momentum-exact impulse on the slider, -m/(M+m) times the change (eqs 1-3).
// * CompliantPlant: the mass-damper-spring model of eq 30 (stiffness K, damping C). Integrated
//   exactly: within a sample and a friction state the equations are linear with constant input, and
//   the closed-form solution is evaluated; stick<->slip switches are found as roots within the
//   step. Friction that depends on the speed (Stribeck) is held over segments short enough that
//   the speed moves by at most a share (kStribeckSpeedShare) of the Stribeck velocity, at its
//   value at the segment's middle speed.
// Both use the same friction law: Coulomb slip, stick while the force needed to hold the slider is
// at most mu_s N, N = (M+m) g cos(tilt). A slider at rest stays exactly at rest (no creep, no
// chatter).
#pragma once

#include <cmath>
#include <complex>
#include <limits>
#include <memory>

#include "model/friction.h"
#include "model/stage.h"

namespace idm::model {

enum class ActuatorKind { Rigid, MassDamperSpring };

// With the middle speed's friction, a share of 0.3 keeps a step within 2 nm of 0.005 (validate's
// compliance + Stribeck stage), 1 within 5 nm.
constexpr double kStribeckSpeedShare = 0.3;

class Plant {
 public:
  virtual ~Plant() = default;
  // At rest at x_m with the actuator at xi_m (counter mass at rest, spring relaxed).
  virtual void reset(double x_m, double xi_m) = 0;
  // Advances dt_s while the actuator command moves linearly to xi_end_m.
  virtual void step(double dt_s, double xi_end_m) = 0;
  virtual double position_m() const = 0;
  virtual double velocity_m_s() const = 0;
  // Actual actuator length (counter mass relative to slider); equals the command when rigid.
  virtual double actuator_length_m() const = 0;
  // An external push: the slider, and the counter mass with it, moves by dx_m at once.
  virtual void displace(double dx_m) = 0;
  // Hard end stops: the slider cannot pass them; one that reaches a stop stays on it with its
  // velocity into the stop gone. NaN for none (the default).
  void set_end_stops(double low_m, double high_m) {
    stop_low_m_ = low_m;
    stop_high_m_ = high_m;
  }
  double stop_low_m() const { return stop_low_m_; }
  double stop_high_m() const { return stop_high_m_; }
  // A held (stalled) slider does not move whatever the forces: identification, fault injection.
  void set_slider_held(bool held) { held_ = held; }
  bool slider_held() const { return held_; }
  // How far the speed may move, as a share of the Stribeck velocity, while one friction holds
  // (the compliant plant; the rigid plant's steps are its caller's). Coarser for a search.
  void set_stribeck_speed_share(double share) { stribeck_speed_share_ = share; }
  FrictionLaw& friction() { return friction_; }
  const FrictionLaw& friction() const { return friction_; }

 protected:
  Plant(const StageParams& stage, const FrictionLaw& friction)
      : stage_(stage), friction_(friction) {}
  // After a step: a slider past a stop is put on it and its velocity into the stop is dropped.
  // Returns true when it is on a stop.
  bool apply_end_stops(double& x_m, double& v_m_s) const;
  double stribeck_speed_share_ = kStribeckSpeedShare;
  StageParams stage_;
  FrictionLaw friction_;
  bool held_ = false;
  double stop_low_m_ = std::numeric_limits<double>::quiet_NaN();
  double stop_high_m_ = std::numeric_limits<double>::quiet_NaN();
};

std::unique_ptr<Plant> make_plant(ActuatorKind kind, const StageParams& stage,
                                  const FrictionLaw& friction);

class RigidPlant final : public Plant {
 public:
  RigidPlant(const StageParams& stage, const FrictionLaw& friction);
  void reset(double x_m, double xi_m) override;
  void step(double dt_s, double xi_end_m) override;
  double position_m() const override { return x_m_; }
  double velocity_m_s() const override { return v_m_s_; }
  double actuator_length_m() const override { return xi_m_; }
  void displace(double dx_m) override { x_m_ += dx_m; }

 private:
  void slide(double dt_s);
  // sin and cos of the friction law's tilt, computed again only when the tilt changes
  void update_tilt();
  double x_m_ = 0, v_m_s_ = 0, xi_m_ = 0, rate_m_s_ = 0;
  double tilt_rad_ = 0, sin_tilt_ = 0, cos_tilt_ = 1;
};

// e'' + c1 e' + c0 e = c: closed-form value, rate and first two time integrals of e.
class DampedOscillator {
 public:
  struct State {
    double e, w, integral, double_integral;
  };
  void set(double c0, double c1);
  // `reuse`: t_s is the plant's regular step; its coefficients are kept for the next call.
  State at(double e0, double w0, double c, double t_s, bool reuse = false) const;
  double c0() const { return c0_; }
  double c1() const { return c1_; }
  // An eighth of the period of the undamped oscillation: steps up to this long cannot hide a
  // turn of it.
  double probe_s() const { return 2.0 * 3.14159265358979323846 / std::sqrt(c0_) / 8.0; }
  // A bound on |x| * sqrt(c0) and |x'| for all later times, x = e - c / c0: the energy
  // x'^2 + c0 x^2 never grows (it falls by 2 c1 x'^2).
  double energy_bound(double e, double w, double c) const {
    const double x = e - c / c0_;
    return std::sqrt(w * w + c0_ * x * x);
  }

 private:
  // The state at t is linear in (e0 - ep, w0): four real coefficient pairs, cached for the last t
  // (the plant's fixed step), so a regular step costs a few multiplications.
  struct Transition {
    double e[2], w[2], integral[2], double_integral[2];
  };
  Transition transition(double t_s) const;
  double c0_ = 1, c1_ = 0;
  std::complex<double> l1_, l2_;
  // two slots: the plant's regular step and a probe step (compliant plant) alternate
  mutable double cached_t_s_[2] = {-1, -1};
  mutable Transition cached_[2]{};
  mutable int next_slot_ = 0;
};

class CompliantPlant final : public Plant {
 public:
  CompliantPlant(const StageParams& stage, const FrictionLaw& friction);
  void reset(double x_m, double xi_m) override;
  void step(double dt_s, double xi_end_m) override;
  double position_m() const override { return x_m_; }
  double velocity_m_s() const override { return v_m_s_; }
  double actuator_length_m() const override { return xi_m_ + e_m_; }
  void displace(double dx_m) override { x_m_ += dx_m; }
  double spring_force_n() const;

 private:
  struct SlipState {
    double e, w, v, x;
  };
  // from the current state, sliding with force f_slip_n_
  SlipState slip_at(double t_s, bool reuse = false) const {
    return slip_from({e_m_, w_m_s_, v_m_s_, x_m_}, t_s, reuse);
  }
  // from `start`, sliding with force f_slip_n_
  SlipState slip_from(const SlipState& start, double t_s, bool reuse = false) const;
  double hold_force_n(double e, double w) const;  // friction force needed to hold the slider
  double slip_friction_n(double direction) const;
  // Probes a long stuck step for a break-away (the end of its interval, lo_s its start; -1 none).
  double breakaway_probe(double remaining_s, double c_stuck, double limit_n, double& lo_s) const;
  void advance_stuck(double& remaining_s);
  void advance_sliding(double& remaining_s);
  void advance_sliding_for(double& remaining_s);  // one segment of constant friction
  // How long one friction holds when it depends on the speed: until the speed has moved by
  // stribeck_speed_share_ of the Stribeck velocity, an eighth of the ringing at most, within
  // remaining_s; end_speed_m_s: the speed along the slide at its end under the current friction.
  double velocity_span_s(double remaining_s, double& end_speed_m_s) const;
  // The first probe time (every eighth of the sliding oscillation) at which the velocity has
  // reached 0, or -1; lo and v_lo: the last probe before it that still moved, v_hi at the probe.
  double first_stop_probe(double remaining_s, double& lo_s, double& v_lo, double& v_hi) const;

  double gravity_along_m_s2_ = 0;  // g sin(tilt)
  double tilt_force_n_ = 0;        // M g sin(tilt), along -x on the slider
  double normal_force_n_ = 0;
  DampedOscillator stuck_, sliding_;
  // state
  double x_m_ = 0, v_m_s_ = 0;
  double xi_m_ = 0, rate_m_s_ = 0;  // command and its rate in the current step
  double e_m_ = 0, w_m_s_ = 0;      // spring deflection x - xi and its rate
  double direction_ = 0;            // +1/-1 while sliding, 0 while stuck
  double f_slip_n_ = 0;             // friction force on the slider while sliding
  double span_hint_s_ = std::numeric_limits<double>::infinity();  // the last velocity_span_s
};

}  // namespace idm::model
