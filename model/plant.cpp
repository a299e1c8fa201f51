#include "model/plant.h"

#include <algorithm>
#include <cmath>

namespace idm::model {

std::unique_ptr<Plant> make_plant(ActuatorKind kind, const StageParams& stage,
                                  const FrictionLaw& friction) {
  if (kind == ActuatorKind::Rigid) return std::make_unique<RigidPlant>(stage, friction);
  return std::make_unique<CompliantPlant>(stage, friction);
}

// ---------------------------------------------------------------------------------------------
// Rigid actuator

bool Plant::apply_end_stops(double& x_m, double& v_m_s) const {
  if (x_m < stop_low_m_) {  // false for NaN: no stop
    x_m = stop_low_m_;
    v_m_s = std::max(v_m_s, 0.0);
    return true;
  }
  if (x_m > stop_high_m_) {
    x_m = stop_high_m_;
    v_m_s = std::min(v_m_s, 0.0);
    return true;
  }
  return false;
}

RigidPlant::RigidPlant(const StageParams& stage, const FrictionLaw& friction)
    : Plant(stage, friction) {}

void RigidPlant::reset(double x_m, double xi_m) {
  x_m_ = x_m;
  v_m_s_ = 0;
  xi_m_ = xi_m;
  rate_m_s_ = 0;
}

void RigidPlant::update_tilt() {
  if (friction_.tilt_rad == tilt_rad_) return;
  tilt_rad_ = friction_.tilt_rad;
  sin_tilt_ = std::sin(tilt_rad_);
  cos_tilt_ = std::cos(tilt_rad_);
}

void RigidPlant::step(double dt_s, double xi_end_m) {
  if (!(dt_s > 0)) return;
  update_tilt();
  const double rate = (xi_end_m - xi_m_) / dt_s;
  const double jump = rate - rate_m_s_;
  rate_m_s_ = rate;
  xi_m_ = xi_end_m;
  if (held_) {
    v_m_s_ = 0;
    return;
  }
  const double g = stage_.gravity_m_s2;
  if (jump != 0.0) {
    if (v_m_s_ == 0.0) {
      // A rate change spread over the step is a force -m jump/dt; static friction holds it when it
      // can (a smooth command does not creep the slider), a velocity corner breaks it loose.
      const double force_per_mass = -stage_.mass_ratio() * jump / dt_s - g * sin_tilt_;
      if (std::fabs(force_per_mass) > friction_.static_at(x_m_) * g * cos_tilt_)
        v_m_s_ = -stage_.mass_ratio() * jump;
    } else {
      v_m_s_ -= stage_.mass_ratio() * jump;
    }
  }
  slide(dt_s);
  // On a stop the slider stays, but its slip velocity into the stop is kept (friction still
  // takes it down): the return corner's jump then cancels it as it would in free motion, instead
  // of launching the slider off the stop (the stop takes the slip phase's displacement, not the
  // momentum exchange between the two masses that the corners make).
  const double v_into = v_m_s_;
  if (apply_end_stops(x_m_, v_m_s_)) v_m_s_ = v_into;
}

void RigidPlant::slide(double dt_s) {
  const double g = stage_.gravity_m_s2;
  const double g_along = g * sin_tilt_;  // pulls towards -x
  const double g_normal = g * cos_tilt_;
  double remaining = dt_s;
  for (int segment = 0; segment < 4 && remaining > 0; ++segment) {
    if (v_m_s_ == 0.0) {
      if (std::fabs(g_along) <= friction_.static_at(x_m_) * g_normal) return;  // sticks
      // too steep to hold: slides downhill
      const double a = -g_along + (g_along > 0 ? 1 : -1) * friction_.kinetic_at(x_m_) * g_normal;
      x_m_ += 0.5 * a * remaining * remaining;
      v_m_s_ = a * remaining;
      return;
    }
    const double dir = v_m_s_ > 0 ? 1.0 : -1.0;
    const double mu = friction_.sliding_at(std::fabs(v_m_s_), x_m_);
    const double a = -g_along - dir * mu * g_normal;
    if (a * dir >= 0) {  // downhill steeper than friction: keeps sliding
      x_m_ += v_m_s_ * remaining + 0.5 * a * remaining * remaining;
      v_m_s_ += a * remaining;
      return;
    }
    const double t_stop = -v_m_s_ / a;
    if (t_stop > remaining) {
      x_m_ += v_m_s_ * remaining + 0.5 * a * remaining * remaining;
      v_m_s_ += a * remaining;
      return;
    }
    x_m_ += 0.5 * v_m_s_ * t_stop;
    v_m_s_ = 0.0;
    remaining -= t_stop;
  }
}

// ---------------------------------------------------------------------------------------------
// Damped oscillator in closed form

namespace {
using cplx = std::complex<double>;
// phi1(z) = (e^z - 1)/z, phi2(z) = (e^z - 1 - z)/z^2, by series near 0.
cplx phi1(cplx z, cplx ez) {
  if (std::abs(z) < 1e-2)
    return 1.0 + z * (1.0 / 2 + z * (1.0 / 6 + z * (1.0 / 24 + z * (1.0 / 120 + z / 720.0))));
  return (ez - 1.0) / z;
}
cplx phi2(cplx z, cplx ez) {
  if (std::abs(z) < 1e-2)
    return 0.5 + z * (1.0 / 6 + z * (1.0 / 24 + z * (1.0 / 120 + z * (1.0 / 720 + z / 5040.0))));
  return (ez - 1.0 - z) / (z * z);
}
}  // namespace

void DampedOscillator::set(double c0, double c1) {
  double disc = c1 * c1 - 4 * c0;
  // Critical damping has a double root: nudge the damping so the two roots stay distinct.
  if (std::fabs(disc) < 1e-8 * c1 * c1) {
    c1 *= 1 + 1e-4;
    disc = c1 * c1 - 4 * c0;
  }
  c0_ = c0;
  c1_ = c1;
  if (disc < 0) {
    l1_ = cplx(-c1 / 2, std::sqrt(-disc) / 2);
    l2_ = std::conj(l1_);
  } else {
    // the root closer to 0 without cancellation
    const double q = -0.5 * (c1 + std::sqrt(disc));
    l1_ = cplx(q, 0);
    l2_ = cplx(c0 / q, 0);
  }
  cached_t_s_[0] = cached_t_s_[1] = -1;
}

DampedOscillator::Transition DampedOscillator::transition(double t) const {
  const cplx z1 = l1_ * t, z2 = l2_ * t;
  const cplx exp1 = std::exp(z1), exp2 = std::exp(z2);
  const cplx p11 = phi1(z1, exp1), p12 = phi1(z2, exp2);
  const cplx p21 = phi2(z1, exp1), p22 = phi2(z2, exp2);
  Transition x;
  // basis: (d, w0) = (1, 0) and (0, 1); a1 = (w0 - l2 d)/(l1 - l2), a2 = d - a1
  for (int k = 0; k < 2; ++k) {
    const double d = k == 0 ? 1.0 : 0.0, w0 = k == 0 ? 0.0 : 1.0;
    const cplx a1 = (w0 - l2_ * d) / (l1_ - l2_);
    const cplx a2 = d - a1;
    x.e[k] = std::real(a1 * exp1 + a2 * exp2);
    x.w[k] = std::real(a1 * l1_ * exp1 + a2 * l2_ * exp2);
    x.integral[k] = t * std::real(a1 * p11 + a2 * p12);
    x.double_integral[k] = t * t * std::real(a1 * p21 + a2 * p22);
  }
  return x;
}

DampedOscillator::State DampedOscillator::at(double e0, double w0, double c, double t,
                                             bool reuse) const {
  const double ep = c / c0_;
  const double d = e0 - ep;
  Transition local;
  const Transition* use = &local;
  if (reuse) {
    // steps that differ only by rounding (t_k - t_{k-1}) share the coefficients
    int slot = -1;
    for (int k = 0; k < 2; ++k)
      if (std::fabs(t - cached_t_s_[k]) <= 1e-12 * t) slot = k;
    if (slot < 0) {
      slot = next_slot_;
      next_slot_ = 1 - next_slot_;
      cached_[slot] = transition(t);
      cached_t_s_[slot] = t;
    }
    use = &cached_[slot];
  } else {
    local = transition(t);
  }
  const Transition& x = *use;
  State s;
  s.e = ep + x.e[0] * d + x.e[1] * w0;
  s.w = x.w[0] * d + x.w[1] * w0;
  s.integral = ep * t + x.integral[0] * d + x.integral[1] * w0;
  s.double_integral = 0.5 * ep * t * t + x.double_integral[0] * d + x.double_integral[1] * w0;
  return s;
}

// ---------------------------------------------------------------------------------------------
// Mass-damper-spring actuator (eq 30)

CompliantPlant::CompliantPlant(const StageParams& stage, const FrictionLaw& friction)
    : Plant(stage, friction) {
  const double M = stage.slider_mass_kg, m = stage.counter_mass_kg;
  const double K = stage.stiffness_n_m, C = stage.damping_n_s_m;
  stuck_.set(K / m, C / m);
  sliding_.set(K / stage.reduced_mass_kg(), C / stage.reduced_mass_kg());
  gravity_along_m_s2_ = stage.gravity_m_s2 * std::sin(friction.tilt_rad);
  tilt_force_n_ = M * gravity_along_m_s2_;
  normal_force_n_ = (M + m) * stage.gravity_m_s2 * std::cos(friction.tilt_rad);
}

void CompliantPlant::reset(double x_m, double xi_m) {
  x_m_ = x_m;
  v_m_s_ = 0;
  xi_m_ = xi_m;
  rate_m_s_ = 0;
  // at rest: the spring carries the counter mass's weight along a tilted guide
  const double m = stage_.counter_mass_kg;
  e_m_ = -m * stage_.gravity_m_s2 * std::sin(friction_.tilt_rad) / stage_.stiffness_n_m;
  w_m_s_ = 0;
  direction_ = 0;
  span_hint_s_ = std::numeric_limits<double>::infinity();
}

double CompliantPlant::spring_force_n() const {
  return stage_.stiffness_n_m * e_m_ + stage_.damping_n_s_m * w_m_s_;
}

double CompliantPlant::hold_force_n(double e, double w) const {
  // slider at rest: 0 = (K e + C w) + F - M g sin(tilt)
  return tilt_force_n_ - (stage_.stiffness_n_m * e + stage_.damping_n_s_m * w);
}

double CompliantPlant::slip_friction_n(double direction) const {
  const double mu = friction_.velocity_dependent() ? friction_.sliding_at(std::fabs(v_m_s_), x_m_)
                                                   : friction_.kinetic_at(x_m_);
  return -direction * mu * normal_force_n_;
}

CompliantPlant::SlipState CompliantPlant::slip_from(const SlipState& a, double t,
                                                    bool reuse) const {
  const double M = stage_.slider_mass_kg;
  const double K = stage_.stiffness_n_m, C = stage_.damping_n_s_m;
  const DampedOscillator::State o = sliding_.at(a.e, a.w, -f_slip_n_ / M, t, reuse);
  const double net = f_slip_n_ - tilt_force_n_;
  SlipState s;
  s.e = o.e;
  s.w = o.w;
  s.v = a.v + (C * (o.e - a.e) + K * o.integral + net * t) / M;
  s.x =
      a.x + a.v * t + (C * (o.integral - a.e * t) + K * o.double_integral + 0.5 * net * t * t) / M;
  return s;
}

namespace {

// The top of a peak of excess(t) between a_s and d_s (golden section, at most 40 steps), as
// soon as it rises above 0: that t, or -1 when the peak stays at or below 0.
template <class Excess>
double golden_peak_crossing(const Excess& excess, double a, double d) {
  double x1 = d - 0.618 * (d - a), x2 = a + 0.618 * (d - a);
  double f1 = excess(x1), f2 = excess(x2);
  for (int i = 0; i < 40 && std::max(f1, f2) <= 0; ++i) {
    if (f1 > f2) {
      d = x2;
      x2 = x1;
      f2 = f1;
      x1 = d - 0.618 * (d - a);
      f1 = excess(x1);
    } else {
      a = x1;
      x1 = x2;
      f1 = f2;
      x2 = a + 0.618 * (d - a);
      f2 = excess(x2);
    }
  }
  if (std::max(f1, f2) <= 0) return -1;
  return f1 > 0 ? x1 : x2;
}

}  // namespace

void CompliantPlant::step(double dt_s, double xi_end_m) {
  if (!(dt_s > 0)) return;
  const double rate = (xi_end_m - xi_m_) / dt_s;
  w_m_s_ -= rate - rate_m_s_;  // the counter mass's velocity is continuous; e' = x' - xi'
  rate_m_s_ = rate;
  double remaining = dt_s;
  // Each segment ends at a stick/slip transition or at the step's end; a long step (the analysis
  // steps from event to event) can hold many transitions of a ringing counter mass.
  for (int segment = 0; segment < 1000000 && remaining > 0; ++segment) {
    if (direction_ == 0)
      advance_stuck(remaining);
    else
      advance_sliding(remaining);
  }
  xi_m_ = xi_end_m;
  // e is relative to the command: keep it consistent with the command at the step end
  if (apply_end_stops(x_m_, v_m_s_) && v_m_s_ == 0.0) direction_ = 0;  // stuck on the stop
}

// A step longer than an eighth of the counter mass's oscillation can hide a break-away that its
// end does not show: the hold force is looked at every eighth of a period, for as long as the
// ringing could still carry it over the limit (energy bound). Returns the end of the first probe
// interval in which |hold force| exceeds limit_n (lo_s its start), or -1 when none does.
double CompliantPlant::breakaway_probe(double remaining, double c_stuck, double limit,
                                       double& lo) const {
  double hi = -1;
  const double K = stage_.stiffness_n_m, C = stage_.damping_n_s_m;
  const double hold_rest = hold_force_n(c_stuck / stuck_.c0(), 0.0);
  const double probe = stuck_.probe_s();
  auto excess = [&](double t) {
    const DampedOscillator::State s = stuck_.at(e_m_, w_m_s_, c_stuck, t);
    return std::fabs(hold_force_n(s.e, s.w)) - limit;
  };
  double e = e_m_, w = w_m_s_, f_lo = -limit, t_before = -1, f_before = 0;
  for (double t = probe; t < remaining; t += probe) {
    const double bound = stuck_.energy_bound(e, w, c_stuck);
    if (std::fabs(hold_rest) + K * bound / std::sqrt(stuck_.c0()) + C * bound <= limit) break;
    const DampedOscillator::State s = stuck_.at(e, w, c_stuck, probe, true);  // from the last probe
    const double f = std::fabs(hold_force_n(s.e, s.w)) - limit;
    if (f > 0) {
      lo = t - probe;
      hi = t;
      break;
    }
    if (t_before >= 0 && f_lo > f_before && f < f_lo) {
      // a peak between t_before and t: its top, by golden section, may cross the limit
      const double crossing = golden_peak_crossing(excess, t_before, t);
      if (crossing >= 0) {
        lo = t_before;
        hi = crossing;
        break;
      }
    }
    t_before = lo;
    f_before = f_lo;
    e = s.e;
    w = s.w;
    lo = t;
    f_lo = f;
  }
  return hi;
}

void CompliantPlant::advance_stuck(double& remaining) {
  const double c_stuck = -gravity_along_m_s2_;
  const double limit = friction_.static_at(x_m_) * normal_force_n_;
  // Long steps are probed (breakaway_probe); shorter steps: the end only.
  double lo = 0, hi = -1;
  if (!held_ && remaining > stuck_.probe_s()) hi = breakaway_probe(remaining, c_stuck, limit, lo);
  if (hi < 0) {
    const DampedOscillator::State end = stuck_.at(e_m_, w_m_s_, c_stuck, remaining, true);
    if (held_ || std::fabs(hold_force_n(end.e, end.w)) <= limit) {
      e_m_ = end.e;
      w_m_s_ = end.w;
      v_m_s_ = 0;
      remaining = 0;
      return;
    }
    hi = remaining;
  }
  // Break-away inside the step: the first time |hold force| reaches the static limit.
  for (int i = 0; i < 60 && hi - lo > 1e-15 * remaining; ++i) {
    const double mid = 0.5 * (lo + hi);
    const DampedOscillator::State s = stuck_.at(e_m_, w_m_s_, c_stuck, mid);
    (std::fabs(hold_force_n(s.e, s.w)) > limit ? hi : lo) = mid;
  }
  const DampedOscillator::State s = stuck_.at(e_m_, w_m_s_, c_stuck, hi);
  e_m_ = s.e;
  w_m_s_ = s.w;
  remaining -= hi;
  // slides the way the force that friction could not hold pushes it
  direction_ = hold_force_n(e_m_, w_m_s_) > 0 ? -1.0 : 1.0;
  v_m_s_ = 0;
  f_slip_n_ = slip_friction_n(direction_);
}

double CompliantPlant::first_stop_probe(double remaining, double& lo, double& v_lo,
                                        double& v_hi) const {
  // A long step can hide a stop that its end does not show (the ringing dips the velocity to 0):
  // the velocity is looked at every eighth of a period while the ringing could still bring it to 0.
  // v(t) = trend + (C x + K integral of x) / M with x the ringing of the spring deflection, whose
  // change from any later time is bounded through the oscillator's energy.
  const double M = stage_.slider_mass_kg, K = stage_.stiffness_n_m, C = stage_.damping_n_s_m;
  const double c = -f_slip_n_ / M, c0 = sliding_.c0(), c1 = sliding_.c1();
  const double accel = (K * c / c0 + f_slip_n_ - tilt_force_n_) / M;  // the trend of v
  const double probe = sliding_.probe_s();
  SlipState last{e_m_, w_m_s_, v_m_s_, x_m_};  // at the last probe, lo
  double e = e_m_, w = w_m_s_, v = v_m_s_;
  double t_before = -1, v_before = 0;  // the probe before lo, for a dip between probes
  for (double t = probe; t < remaining; t += probe) {
    const double b = sliding_.energy_bound(e, w, c);
    const double swing =
        (2 * C * b / std::sqrt(c0) + (K / c0) * (2 * b + 2 * c1 * b / std::sqrt(c0))) / M;
    const double t_last = lo;  // the last probe: where (e, w, v) were taken
    const double v_trend_end = direction_ * (v + accel * (remaining - t_last));
    if (std::min(direction_ * v, v_trend_end) > swing) return -1;  // no stop can hide in the rest
    // nor before the trend comes within the swing of 0: the probes may skip ahead to there
    if (direction_ * accel < 0 && direction_ * v > swing) {
      const double reach = t_last + (direction_ * v - swing) / (-direction_ * accel);
      if (reach > t) t = std::min(reach, remaining - 0.5 * probe);
    }
    // from the last probe, the probe step's coefficients kept
    const double dt = t - t_last;
    const SlipState s = slip_from(last, dt, std::fabs(dt - probe) <= 1e-12 * probe);
    const double vt = s.v * direction_;
    if (vt <= 0) {
      v_hi = vt;
      return t;
    }
    if (t_before >= 0 && v_lo < v_before && vt > v_lo) {
      // a dip between t_before and t: its bottom, by golden section, may touch 0
      double a = t_before, d = t, x1 = d - 0.618 * (d - a), x2 = a + 0.618 * (d - a);
      double f1 = slip_at(x1).v * direction_, f2 = slip_at(x2).v * direction_;
      for (int i = 0; i < 40 && std::min(f1, f2) > 0; ++i) {
        if (f1 < f2) {
          d = x2;
          x2 = x1;
          f2 = f1;
          x1 = d - 0.618 * (d - a);
          f1 = slip_at(x1).v * direction_;
        } else {
          a = x1;
          x1 = x2;
          f1 = f2;
          x2 = a + 0.618 * (d - a);
          f2 = slip_at(x2).v * direction_;
        }
      }
      if (std::min(f1, f2) <= 0) {
        const bool first = f1 <= 0;
        v_hi = first ? f1 : f2;
        lo = t_before;
        v_lo = v_before;
        return first ? x1 : x2;
      }
    }
    t_before = lo;
    v_before = v_lo;
    lo = t;
    v_lo = vt;
    last = s;
    e = s.e;
    w = s.w;
    v = s.v;
  }
  return -1;
}

double CompliantPlant::velocity_span_s(double remaining, double& end_speed) const {
  const double v_s = friction_.stribeck_velocity_m_s;
  const double speed = direction_ * v_m_s_;
  // from twice the last span (an eighth of the ringing at most), halved until the speed (exact
  // under the segment's friction) stays close enough; far above the Stribeck velocity friction
  // is kinetic until the speed comes near it
  double span = std::min({remaining, sliding_.probe_s(), 2 * span_hint_s_});
  for (int i = 0; i < 60; ++i) {
    end_speed = direction_ * slip_at(span).v;
    if (speed > 4 * v_s ? end_speed >= 3.5 * v_s
                        : std::fabs(end_speed - speed) <= stribeck_speed_share_ * v_s)
      return span;
    span *= 0.5;
  }
  end_speed = direction_ * slip_at(span).v;
  return span;
}

void CompliantPlant::advance_sliding(double& remaining) {
  f_slip_n_ = slip_friction_n(direction_);
  // the friction of the segment's start holds for the whole segment: with a friction that
  // depends on the speed, the segment ends before the speed has moved along the curve, and its
  // friction is the one at its middle speed (predicted under the start's friction)
  double span = remaining;
  if (friction_.velocity_dependent()) {
    double end_speed = 0;
    span = velocity_span_s(remaining, end_speed);
    if (span < remaining) span_hint_s_ = span;
    const double mid = 0.5 * (direction_ * v_m_s_ + std::max(0.0, end_speed));
    f_slip_n_ = -direction_ * friction_.sliding_at(mid, x_m_) * normal_force_n_;
  }
  double part = span;
  advance_sliding_for(part);
  remaining -= span - part;
}

void CompliantPlant::advance_sliding_for(double& remaining) {
  double lo = 0, hi = -1;
  double v_lo = v_m_s_ * direction_, v_hi = 0;
  if (remaining > sliding_.probe_s()) hi = first_stop_probe(remaining, lo, v_lo, v_hi);
  if (hi < 0) {
    const SlipState end = slip_at(remaining, true);
    if (end.v * direction_ > 0) {
      e_m_ = end.e;
      w_m_s_ = end.w;
      v_m_s_ = end.v;
      x_m_ = end.x;
      remaining = 0;
      return;
    }
    hi = remaining;
    v_hi = end.v * direction_;
  }
  // The slider stops inside the step: find where v crosses 0 (false position, Illinois).
  if (v_lo <= 0) {
    // starting from rest (break-away): find a point where it moves
    double t = hi;
    for (int i = 0; i < 40; ++i) {
      t *= 0.5;
      const double v = slip_at(t).v * direction_;
      if (v > 0) {
        lo = t;
        v_lo = v;
        break;
      }
    }
    if (v_lo <= 0) {  // the break-away could not move it: it sticks again
      direction_ = 0;
      v_m_s_ = 0;
      return;
    }
  }
  int side = 0;
  double t = hi;
  for (int i = 0; i < 100; ++i) {
    t = (lo * v_hi - hi * v_lo) / (v_hi - v_lo);
    if (!(t > lo && t < hi)) t = 0.5 * (lo + hi);
    const double v = slip_at(t).v * direction_;
    if (v > 0) {
      lo = t;
      v_lo = v;
      if (side == 1) v_hi *= 0.5;
      side = 1;
    } else {
      hi = t;
      v_hi = v;
      if (side == -1) v_lo *= 0.5;
      side = -1;
    }
    if (hi - lo < 1e-14 * remaining || std::fabs(v) < 1e-16) break;
  }
  const SlipState s = slip_at(hi);
  e_m_ = s.e;
  w_m_s_ = s.w;
  x_m_ = s.x;
  v_m_s_ = 0;
  remaining -= hi;
  const double hold = hold_force_n(e_m_, w_m_s_);
  if (std::fabs(hold) <= friction_.static_at(x_m_) * normal_force_n_) {
    direction_ = 0;
  } else {
    direction_ = hold > 0 ? -1.0 : 1.0;
    f_slip_n_ = slip_friction_n(direction_);
  }
}

}  // namespace idm::model
