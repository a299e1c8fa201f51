#include "control/region_map.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <tuple>

namespace idm::control {

namespace {

[[noreturn]] void fail(const std::string& where, const std::string& key, double value,
                       const std::string& range) {
  std::ostringstream msg;
  msg.precision(9);
  msg << where << "." << key << ": " << value << " is out of range, allowed " << range;
  throw model::InputError(msg.str());
}

bool finite_in(double v, double lo, double hi) {
  return std::isfinite(v) && v >= lo && v <= hi;
}

// Relative tolerance for comparing a cell's frequency with the device's limits.
constexpr double kLimitTolerance = 1e-12;
// A period or extension within this many samples of a whole number is on the clock.
constexpr double kClockTolerance_samples = 1e-9;

unsigned check_limits(const DeviceLimits& lim, double f, double duty, double stroke,
                      std::uint32_t& period_samples, std::uint32_t& extension_samples,
                      std::uint64_t& max_cycles) {
  unsigned v = 0;
  if (f < lim.min_freq_hz * (1 - kLimitTolerance)) v |= limit_violation::kFreqBelowMin;
  if (f > lim.max_freq_hz * (1 + kLimitTolerance)) v |= limit_violation::kFreqAboveMax;
  if (stroke < lim.min_stroke_m * (1 - kLimitTolerance) ||
      stroke > lim.max_stroke_m * (1 + kLimitTolerance))
    v |= limit_violation::kStrokeOutOfRange;
  period_samples = 0;
  extension_samples = 0;
  max_cycles = lim.max_burst_cycles;
  if (lim.output_sample_rate_hz > 0) {
    const double p = lim.output_sample_rate_hz / f;
    const double p_whole = std::round(p);
    const double k = duty * p_whole;
    const double k_whole = std::round(k);
    if (std::fabs(p - p_whole) > kClockTolerance_samples || p_whole < 2 || p_whole > 4e9 ||
        std::fabs(k - k_whole) > kClockTolerance_samples || k_whole < 1 || k_whole > p_whole - 1) {
      v |= limit_violation::kOffSampleClock;
    } else {
      period_samples = static_cast<std::uint32_t>(p_whole);
      extension_samples = static_cast<std::uint32_t>(k_whole);
      if (lim.max_burst_samples > 0) {
        max_cycles =
            std::min<std::uint64_t>(max_cycles, (lim.max_burst_samples - 1) / period_samples);
      }
    }
  }
  if (max_cycles == 0) v |= limit_violation::kBurstTooLong;
  return v;
}

model::StageParams with_friction(const model::StageParams& s, double relative_change) {
  model::StageParams out = s;
  out.friction_coefficient = s.friction_coefficient * (1 + relative_change);
  return out;
}

// The relative change e >= 0 of mu (sign +1: increase, beta / (1 + e); -1: decrease,
// beta / (1 - e)) at which the cell stops being one-step, searched up to `limit`. Samples e at
// multiples of `scan_step` and at exactly `u`, then bisects between the last one-step sample and
// the first other one.
double one_step_margin(double beta, double duty, int sign, double u, double scan_step,
                       double limit) {
  auto one_step_at = [&](double e) {
    const double b = sign > 0 ? beta / (1 + e) : beta / (1 - e);
    return model::region(b, duty) == model::Region::OneStep;
  };
  double previous = 0;
  bool u_done = !(u > 0 && u < limit);
  for (long i = 1;; ++i) {
    double e = std::min(static_cast<double>(i) * scan_step, limit);
    if (!u_done && e >= u) {
      e = u;
      u_done = true;
      --i;  // the regular sample i follows
    }
    if (!one_step_at(e)) {
      double lo = previous;
      double hi = e;
      while (hi - lo > 1e-12) {
        const double mid = 0.5 * (lo + hi);
        (one_step_at(mid) ? lo : hi) = mid;
      }
      return lo;
    }
    previous = e;
    if (e >= limit) return limit;
  }
}

}  // namespace

void validate(const DeviceLimits& lim, const std::string& where) {
  if (!finite_in(lim.min_freq_hz, 0, 1e6) || !(lim.min_freq_hz > 0))
    fail(where, "min_freq_hz", lim.min_freq_hz, "(0, 1e6]");
  if (!finite_in(lim.max_freq_hz, lim.min_freq_hz, 1e6))
    fail(where, "max_freq_hz", lim.max_freq_hz, "[min_freq_hz, 1e6]");
  if (!finite_in(lim.output_sample_rate_hz, 0, 1e9))
    fail(where, "output_sample_rate_hz", lim.output_sample_rate_hz, "0 (none) or (0, 1e9]");
  if (lim.output_sample_rate_hz > 0 && lim.output_sample_rate_hz < 2 * lim.max_freq_hz)
    fail(where, "output_sample_rate_hz", lim.output_sample_rate_hz,
         "0 (none) or at least 2 max_freq_hz");
  if (!finite_in(lim.min_stroke_m, 0, 1e-3) || !(lim.min_stroke_m > 0))
    fail(where, "min_stroke_m", lim.min_stroke_m, "(0, 1e-3]");
  if (!finite_in(lim.max_stroke_m, lim.min_stroke_m, 1e-3))
    fail(where, "max_stroke_m", lim.max_stroke_m, "[min_stroke_m, 1e-3]");
  if (lim.max_burst_cycles < 1)
    fail(where, "max_burst_cycles", static_cast<double>(lim.max_burst_cycles), ">= 1");
  if (lim.max_burst_samples == 1) fail(where, "max_burst_samples", 1.0, "0 (no limit) or >= 2");
}

std::string describe_limit_violations(unsigned flags) {
  static const std::pair<unsigned, const char*> names[] = {
      {limit_violation::kFreqBelowMin, "frequency below min"},
      {limit_violation::kFreqAboveMax, "frequency above max"},
      {limit_violation::kOffSampleClock, "off sample clock"},
      {limit_violation::kStrokeOutOfRange, "stroke out of range"},
      {limit_violation::kBurstTooLong, "burst too long"},
  };
  std::string out;
  for (const auto& [flag, name] : names) {
    if (!(flags & flag)) continue;
    if (!out.empty()) out += ", ";
    out += name;
  }
  return out;
}

std::vector<double> RegionGrid::duties() const {
  std::vector<double> out;
  for (long j = 1;; ++j) {
    const double d = static_cast<double>(j) * duty_step;
    if (d >= 1 - 1e-12) break;
    if (std::fabs(d - 0.5) < 1e-12) continue;
    out.push_back(d);
  }
  return out;
}

std::vector<double> RegionGrid::frequency_steps(double min_hz, double max_hz, double step_hz) {
  std::vector<double> out;
  if (!(step_hz > 0) || !(min_hz > 0)) return out;
  for (long i = 0;; ++i) {
    const double f = min_hz + static_cast<double>(i) * step_hz;
    if (f > max_hz * (1 + 1e-12)) break;
    out.push_back(f);
  }
  return out;
}

std::vector<double> RegionGrid::stroke_steps(double min_m, double max_m, int count) {
  std::vector<double> out;
  if (count < 1 || !(min_m > 0) || !(max_m >= min_m)) return out;
  if (count == 1 || max_m == min_m) return {max_m};
  const double ratio = std::pow(min_m / max_m, 1.0 / (count - 1));
  for (int i = 0; i < count; ++i)
    out.push_back(i == count - 1 ? min_m : max_m * std::pow(ratio, i));
  return out;
}

RegionGrid RegionGrid::covering(const DeviceLimits& lim, double freq_step_hz, double duty_step,
                                int stroke_count) {
  RegionGrid g;
  g.freqs_hz =
      frequency_steps(std::max(lim.min_freq_hz, freq_step_hz), lim.max_freq_hz, freq_step_hz);
  g.duty_step = duty_step;
  g.strokes_m = stroke_steps(lim.min_stroke_m, lim.max_stroke_m, stroke_count);
  return g;
}

void validate(const RegionGrid& g, const std::string& where) {
  if (g.freqs_hz.empty()) throw model::InputError(where + ".freqs_hz: empty, need at least one");
  for (double f : g.freqs_hz)
    if (!finite_in(f, 0, 1e6) || !(f > 0)) fail(where, "freqs_hz", f, "(0, 1e6]");
  if (!finite_in(g.duty_step, 1e-4, 0.25)) fail(where, "duty_step", g.duty_step, "[1e-4, 0.25]");
  if (g.strokes_m.empty()) throw model::InputError(where + ".strokes_m: empty, need at least one");
  for (double s : g.strokes_m)
    if (!finite_in(s, 0, 1e-3) || !(s > 0)) fail(where, "strokes_m", s, "(0, 1e-3]");
}

void validate(const RegionMapConfig& c, const std::string& where) {
  model::validate(c.stage, where + ".stage");
  validate(c.limits, where + ".limits");
  validate(c.grid, where + ".grid");
  if (!finite_in(c.margin_search_limit, 1e-3, 0.99))
    fail(where, "margin_search_limit", c.margin_search_limit, "[0.001, 0.99]");
  if (!finite_in(c.friction_uncertainty, 0, c.margin_search_limit) ||
      !(c.friction_uncertainty < c.margin_search_limit))
    fail(where, "friction_uncertainty", c.friction_uncertainty, "[0, margin_search_limit)");
  if (!finite_in(c.margin_scan_step, 1e-5, 0.05))
    fail(where, "margin_scan_step", c.margin_scan_step, "[1e-5, 0.05]");
}

double burst_displacement_ideal_m(const model::StageParams& stage, double freq_hz, double duty,
                                  double stroke_m, int cycles) {
  model::ImpulseEventSimulator sim(stage);
  sim.run(model::TriangleWave{freq_hz, duty, stroke_m, cycles});  // ends with the corner to rate 0
  sim.advance(std::numeric_limits<double>::max());                // the slide to rest after it
  return sim.position_m();
}

RegionCell evaluate_cell(const RegionMapConfig& config, double f, double duty, double stroke) {
  const model::StageParams& s = config.stage;
  const double u = config.friction_uncertainty;
  const double alpha = s.step_correction;
  RegionCell c;
  c.freq_hz = f;
  c.duty = duty;
  c.stroke_m = stroke;
  c.limit_violations = check_limits(config.limits, f, duty, stroke, c.period_samples,
                                    c.extension_samples, c.max_cycles);

  c.beta = model::impulse_ratio(s, f, stroke);
  c.region = model::region(c.beta, duty);
  c.step_m = model::steady_step_corrected_m(s, f, duty, stroke);
  c.single_burst_m = alpha * burst_displacement_ideal_m(s, f, duty, stroke, 1);

  const double step_a = model::steady_step_corrected_m(with_friction(s, -u), f, duty, stroke);
  const double step_b = model::steady_step_corrected_m(with_friction(s, u), f, duty, stroke);
  c.step_min_m = std::min(step_a, step_b);
  c.step_max_m = std::max(step_a, step_b);
  c.single_burst_min_m = c.single_burst_m;
  c.single_burst_max_m = c.single_burst_m;
  constexpr int kMuSamples = 9;
  for (int i = 0; i < kMuSamples; ++i) {
    const double e = -u + 2 * u * i / (kMuSamples - 1);
    const double x = alpha * burst_displacement_ideal_m(with_friction(s, e), f, duty, stroke, 1);
    c.single_burst_min_m = std::min(c.single_burst_min_m, x);
    c.single_burst_max_m = std::max(c.single_burst_max_m, x);
  }

  if (c.region == model::Region::OneStep) {
    c.margin_mu_increase =
        one_step_margin(c.beta, duty, +1, u, config.margin_scan_step, config.margin_search_limit);
    c.margin_mu_decrease =
        one_step_margin(c.beta, duty, -1, u, config.margin_scan_step, config.margin_search_limit);
  }
  c.robust_one_step = c.region == model::Region::OneStep && c.step_m != 0.0 &&
                      c.margin_mu_increase > u && c.margin_mu_decrease > u;
  return c;
}

RegionMap::RegionMap(RegionMapConfig config) : config_(std::move(config)) {
  validate(config_);
  duties_ = config_.grid.duties();
  const auto& freqs = config_.grid.freqs_hz;
  const auto& strokes = config_.grid.strokes_m;
  const double rate = config_.limits.output_sample_rate_hz;
  cells_.reserve(freqs.size() * duties_.size() * strokes.size());
  for (double stroke : strokes) {
    for (double f : freqs) {
      for (double d : duties_) {
        if (rate > 0) {
          const ClockedWave w = snap_to_sample_clock(rate, f, d);
          cells_.push_back(evaluate_cell(config_, w.freq_hz, w.duty, stroke));
        } else {
          cells_.push_back(evaluate_cell(config_, f, d, stroke));
        }
      }
    }
  }
  // Usable cells, each played waveform once: the first grid point that snaps to it.
  std::vector<std::size_t> order;
  for (std::size_t i = 0; i < cells_.size(); ++i)
    if (cells_[i].usable()) order.push_back(i);
  auto key = [this](std::size_t i) {
    const RegionCell& c = cells_[i];
    return std::make_tuple(c.stroke_m, c.freq_hz, c.duty, i);
  };
  std::sort(order.begin(), order.end(),
            [&](std::size_t a, std::size_t b) { return key(a) < key(b); });
  for (std::size_t j = 0; j < order.size(); ++j) {
    const RegionCell& c = cells_[order[j]];
    if (j > 0) {
      const RegionCell& p = cells_[order[j - 1]];
      if (p.stroke_m == c.stroke_m && p.freq_hz == c.freq_hz && p.duty == c.duty) continue;
    }
    usable_.push_back(order[j]);
  }
  std::sort(usable_.begin(), usable_.end());
}

const RegionCell& RegionMap::cell(std::size_t i_freq, std::size_t i_duty,
                                  std::size_t i_stroke) const {
  const std::size_t nf = config_.grid.freqs_hz.size();
  const std::size_t nd = duties_.size();
  return cells_.at((i_stroke * nf + i_freq) * nd + i_duty);
}

RegionCell RegionMap::at(double freq_hz, double duty, double stroke_m) const {
  return evaluate_cell(config_, freq_hz, duty, stroke_m);
}

RegionCell RegionMap::playable(double freq_hz, double duty, double stroke_m) const {
  const double rate = config_.limits.output_sample_rate_hz;
  if (!(rate > 0)) return at(freq_hz, duty, stroke_m);
  const ClockedWave w = snap_to_sample_clock(rate, freq_hz, duty);
  return at(w.freq_hz, w.duty, stroke_m);
}

std::size_t RegionMap::count(model::Region region) const {
  return static_cast<std::size_t>(std::count_if(
      cells_.begin(), cells_.end(), [region](const RegionCell& c) { return c.region == region; }));
}

}  // namespace idm::control
