#include "control/calibration.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <optional>
#include <sstream>
#include <system_error>
#include <vector>

#include "control/region_map.h"
#include "model/yaml_util.h"

namespace idm::control {

namespace {

constexpr const char* kMagic = "idm-calibration 2";
constexpr const char* kMagicV1 = "idm-calibration 1";  // no rung lines; still read

int direction_index(int direction) {
  return direction > 0 ? 1 : 0;
}

const char* direction_name(int index) {
  return index == 1 ? "positive" : "negative";
}

const char* region_key(int region) {
  return model::region_name(static_cast<model::Region>(region));
}

// The regressors of a burst of `cycles` cycles of the cell along its direction, for
// theta = (alpha, alpha mu): D(N) = alpha phi_a - alpha mu phi_m.
struct Regressors {
  double phi_a;
  double phi_m;
  double step_a;  // per-cycle parts (the steady step = alpha step_a - alpha mu step_m)
  double step_m;
};

Regressors regressors(const model::StageParams& s, const RegionCell& cell, std::uint64_t cycles) {
  const double d = cell.duty < 0.5 ? cell.duty : 1.0 - cell.duty;
  const double period_s = 1.0 / cell.freq_hz;
  const int sign = cell.direction();
  Regressors r{};
  r.step_a = s.mass_ratio() * cell.stroke_m / (1.0 - d);
  r.step_m = s.gravity_m_s2 * d * d * period_s * period_s;
  // The nominal first-cycle transient over the nominal alpha: scales with alpha.
  const double transient = (sign * cell.single_burst_m - sign * cell.step_m) / s.step_correction;
  const double n = static_cast<double>(cycles);
  r.phi_a = n * r.step_a + transient;
  r.phi_m = n * r.step_m;
  return r;
}

std::uint64_t fnv1a(const std::string& text) {
  std::uint64_t h = 1469598103934665603ull;
  for (unsigned char c : text) {
    h ^= c;
    h *= 1099511628211ull;
  }
  return h;
}

bool same(double a, double b) {
  return std::fabs(a - b) <= 1e-12 * std::max(std::fabs(a), std::fabs(b));
}

bool rung_ok(const RungEstimate& e) {
  return std::isfinite(e.freq_hz) && std::isfinite(e.duty) && std::isfinite(e.stroke_m) &&
         std::isfinite(e.offset_m) && std::isfinite(e.step_m) && std::isfinite(e.p_oo) &&
         std::isfinite(e.p_os) && std::isfinite(e.p_ss) && e.freq_hz > 0 && e.duty > 0 &&
         e.duty < 1 && e.stroke_m > 0 && e.p_oo >= 0 && e.p_ss >= 0 &&
         e.p_os * e.p_os <= e.p_oo * e.p_ss * (1 + 1e-9) + 1e-300;
}

bool estimate_ok(const CalibrationEstimate& e) {
  return std::isfinite(e.alpha) && std::isfinite(e.alpha_mu) && std::isfinite(e.p_aa) &&
         std::isfinite(e.p_am) && std::isfinite(e.p_mm) && e.alpha > 0 && e.alpha_mu > 0 &&
         e.p_aa >= 0 && e.p_mm >= 0 && e.p_am * e.p_am <= e.p_aa * e.p_mm * (1 + 1e-9);
}

}  // namespace

const model::ParamTable<CalibrationConfig>& calibration_params() {
  using model::boolean;
  using model::real;
  static const model::ParamTable<CalibrationConfig> table({
      boolean<CalibrationConfig>(
          "enabled", "learn the step model online from measured steps",
          [](auto& c) -> auto& { return c.enabled; }),
      real<CalibrationConfig>(
          "forgetting", "1", {0, 1, true}, "RLS forgetting factor of the cell estimates",
          [](auto& c) -> auto& { return c.forgetting; }),
      real<CalibrationConfig>(
          "initial_relative_sd", "1", {0, 10, true},
          "relative sd of the nominal alpha and alpha mu before any update",
          [](auto& c) -> auto& { return c.initial_relative_sd; }),
      real<CalibrationConfig>(
          "observation_relative_sd", "1", {0, 10, true},
          "relative sd of one burst's displacement about the model",
          [](auto& c) -> auto& { return c.observation_relative_sd; }),
      real<CalibrationConfig>(
          "max_ratio", "1", {1, 100, true},
          "a calibrated prediction is used within this ratio of the nominal",
          [](auto& c) -> auto& { return c.max_ratio; }),
      real<CalibrationConfig>(
          "min_update_counts", "count", {0, 1e6},
          "a burst updates the estimate only when it moved this many counts",
          [](auto& c) -> auto& { return c.min_update_counts; }),
      real<CalibrationConfig>(
          "rung_initial_relative_sd", "1", {0, 10, true},
          "relative sd of a rung's seed from the model",
          [](auto& c) -> auto& { return c.rung_initial_relative_sd; }),
      real<CalibrationConfig>(
          "rung_forgetting", "1", {0, 1, true}, "RLS forgetting factor of the rungs",
          [](auto& c) -> auto& { return c.rung_forgetting; }),
  });
  return table;
}

void validate(const CalibrationConfig& c, const std::string& where) {
  calibration_params().validate(c, where);
}

bool RungEstimate::same_cell(double f, double d, double s) const {
  return same(freq_hz, f) && same(duty, d) && same(stroke_m, s);
}

Calibration::Calibration(const model::StageParams& nominal, CalibrationConfig config)
    : nominal_(nominal), config_(config) {
  model::validate(nominal_, "stage");
  validate(config_);
  state_ = nominal_state();
}

CalibrationState Calibration::nominal_state() const {
  CalibrationState s;
  s.slider_mass_kg = nominal_.slider_mass_kg;
  s.counter_mass_kg = nominal_.counter_mass_kg;
  s.friction_coefficient = nominal_.friction_coefficient;
  s.gravity_m_s2 = nominal_.gravity_m_s2;
  s.stroke_m = nominal_.stroke_m;
  s.step_correction = nominal_.step_correction;
  const double alpha = nominal_.step_correction;
  const double alpha_mu = alpha * nominal_.friction_coefficient;
  const double sd = config_.initial_relative_sd;
  for (auto& region : s.estimates) {
    for (CalibrationEstimate& e : region) {
      e.alpha = alpha;
      e.alpha_mu = alpha_mu;
      e.p_aa = (sd * alpha) * (sd * alpha);
      e.p_am = 0;
      e.p_mm = (sd * alpha_mu) * (sd * alpha_mu);
      e.updates = 0;
    }
  }
  s.total_updates = 0;
  return s;
}

void Calibration::reset() {
  state_ = nominal_state();
}

const CalibrationEstimate& Calibration::estimate(model::Region region, int direction) const {
  return state_.estimates[static_cast<int>(region)][direction_index(direction)];
}

CalibrationEstimate& Calibration::slot(model::Region region, int direction) {
  return state_.estimates[static_cast<int>(region)][direction_index(direction)];
}

void Calibration::set_state(const CalibrationState& s) {
  const CalibrationState nominal = nominal_state();
  auto check_stage = [&](const char* key, double got, double want) {
    if (!same(got, want))
      throw model::InputError("calibration: stage." + std::string(key) + " " +
                              model::format_number(got) + " differs from the configured " +
                              model::format_number(want) + " (a calibration of another stage)");
  };
  check_stage("slider_mass_kg", s.slider_mass_kg, nominal.slider_mass_kg);
  check_stage("counter_mass_kg", s.counter_mass_kg, nominal.counter_mass_kg);
  check_stage("friction_coefficient", s.friction_coefficient, nominal.friction_coefficient);
  check_stage("gravity_m_s2", s.gravity_m_s2, nominal.gravity_m_s2);
  check_stage("stroke_m", s.stroke_m, nominal.stroke_m);
  check_stage("step_correction", s.step_correction, nominal.step_correction);
  for (int r = 0; r < CalibrationState::kRegions; ++r) {
    for (int d = 0; d < CalibrationState::kDirections; ++d) {
      if (!estimate_ok(s.estimates[r][d]))
        throw model::InputError(std::string("calibration: estimate ") + region_key(r) + " " +
                                direction_name(d) +
                                ": alpha and alpha_mu must be finite and > 0, the covariance "
                                "positive semi-definite");
    }
  }
  for (int d = 0; d < CalibrationState::kDirections; ++d) {
    if (s.rung_count[d] < 0 || s.rung_count[d] > CalibrationState::kMaxRungs)
      throw model::InputError(std::string("calibration: rung count ") + direction_name(d) +
                              " out of range [0, " + std::to_string(CalibrationState::kMaxRungs) +
                              "]");
    for (int i = 0; i < s.rung_count[d]; ++i)
      if (!rung_ok(s.rungs[d][i]))
        throw model::InputError(std::string("calibration: rung ") + direction_name(d) + " " +
                                std::to_string(i) + ": not finite, or a bad cell or covariance");
  }
  state_ = s;
}

bool Calibration::find_rung(int direction, double freq_hz, double duty, double stroke_m,
                            RungEstimate& out) const {
  if (!config_.enabled) return false;
  const int d = direction_index(direction);
  for (int i = 0; i < state_.rung_count[d]; ++i) {
    if (state_.rungs[d][i].same_cell(freq_hz, duty, stroke_m)) {
      out = state_.rungs[d][i];
      return true;
    }
  }
  return false;
}

bool Calibration::store_rung(int direction, const RungEstimate& e) {
  if (!config_.enabled || !rung_ok(e)) return false;
  const int d = direction_index(direction);
  int i = 0;
  while (i < state_.rung_count[d] && !state_.rungs[d][i].same_cell(e.freq_hz, e.duty, e.stroke_m))
    ++i;
  if (i == state_.rung_count[d]) {
    if (i >= CalibrationState::kMaxRungs) return false;
    ++state_.rung_count[d];
  }
  state_.rungs[d][i] = e;
  ++state_.total_updates;
  return true;
}

bool Calibration::rls_update(RungEstimate& e, std::uint64_t cycles, double measured_along_m,
                             double count_m, double relative_sd, double forgetting, double p_max_oo,
                             double p_max_ss) {
  if (cycles == 0 || !std::isfinite(measured_along_m) || !(count_m > 0) || !(forgetting > 0))
    return false;
  const double n = static_cast<double>(cycles);
  // Noise of one burst: the two readings (about half a count each after averaging and
  // quantization) and the burst's own scatter (friction along the guide), relative_sd of it.
  const double size = std::max(std::fabs(measured_along_m), std::fabs(e.predict_m(cycles)));
  const double sd = std::sqrt(0.5 * count_m * count_m + relative_sd * relative_sd * size * size);
  const double f_o = 1.0 / sd, f_s = n / sd, y = measured_along_m / sd;
  const double pf_o = e.p_oo * f_o + e.p_os * f_s;
  const double pf_s = e.p_os * f_o + e.p_ss * f_s;
  const double denom = forgetting + f_o * pf_o + f_s * pf_s;
  const double k_o = pf_o / denom, k_s = pf_s / denom;
  const double innovation = y - (e.offset_m * f_o + e.step_m * f_s);
  RungEstimate next = e;
  next.offset_m += k_o * innovation;
  next.step_m += k_s * innovation;
  next.p_oo = (e.p_oo - k_o * pf_o) / forgetting;
  next.p_os = (e.p_os - k_o * pf_s) / forgetting;
  next.p_ss = (e.p_ss - k_s * pf_s) / forgetting;
  if (next.p_oo > p_max_oo || next.p_ss > p_max_ss) {
    const double shrink = std::min(p_max_oo / std::max(next.p_oo, p_max_oo),
                                   p_max_ss / std::max(next.p_ss, p_max_ss));
    next.p_oo *= shrink;
    next.p_os *= shrink;
    next.p_ss *= shrink;
  }
  ++next.updates;
  if (!rung_ok(next)) return false;
  e = next;
  return true;
}

bool Calibration::update(const RegionCell& cell, std::uint64_t cycles, double measured_m,
                         double count_m) {
  if (!config_.enabled || cycles == 0 || !std::isfinite(measured_m)) return false;
  const int sign = cell.direction();
  const double measured_along = sign * measured_m;
  if (!(measured_along >= config_.min_update_counts * count_m)) return false;
  const double nominal_along = sign * cell.burst_displacement_m(cycles);
  if (!(nominal_along > 0)) return false;
  const Regressors r = regressors(nominal_, cell, cycles);
  // Relative observation: y = D / D_nominal = theta . phi / D_nominal, divided by its expected
  // noise (the model's relative error and one count of each of the two readings).
  const double quantization = count_m / nominal_along;
  const double noise = std::sqrt(config_.observation_relative_sd * config_.observation_relative_sd +
                                 quantization * quantization);
  const double scale = 1.0 / (nominal_along * noise);
  const double y = measured_along * scale;
  const double f_a = r.phi_a * scale, f_m = -r.phi_m * scale;
  CalibrationEstimate& e = slot(cell.region, sign);
  const double predicted = e.alpha * f_a + e.alpha_mu * f_m;
  // A burst that moved less than half or more than twice its prediction is not a step of this
  // model (a stall, a collision, a jump of friction): it is left to the positioner's checks.
  if (!(y > 0.5 * predicted && y < 2.0 * predicted)) return false;
  const double lambda = config_.forgetting;
  const double pf_a = e.p_aa * f_a + e.p_am * f_m;
  const double pf_m = e.p_am * f_a + e.p_mm * f_m;
  const double denom = lambda + f_a * pf_a + f_m * pf_m;
  const double k_a = pf_a / denom, k_m = pf_m / denom;
  const double innovation = y - predicted;
  CalibrationEstimate next = e;
  next.alpha += k_a * innovation;
  next.alpha_mu += k_m * innovation;
  next.p_aa = (e.p_aa - k_a * pf_a) / lambda;
  next.p_am = (e.p_am - k_a * pf_m) / lambda;
  next.p_mm = (e.p_mm - k_m * pf_m) / lambda;
  // No wind-up: forgetting without excitation must not grow P beyond its initial size.
  const double sd = config_.initial_relative_sd;
  const double p_aa_max = (sd * nominal_.step_correction) * (sd * nominal_.step_correction);
  const double p_mm_max = p_aa_max * nominal_.friction_coefficient * nominal_.friction_coefficient;
  if (next.p_aa > p_aa_max || next.p_mm > p_mm_max) {
    const double shrink = std::min(p_aa_max / std::max(next.p_aa, p_aa_max),
                                   p_mm_max / std::max(next.p_mm, p_mm_max));
    next.p_aa *= shrink;
    next.p_am *= shrink;
    next.p_mm *= shrink;
  }
  ++next.updates;
  if (!estimate_ok(next)) return false;
  e = next;
  ++state_.total_updates;
  return true;
}

std::string Calibration::serialize(const CalibrationState& s) {
  std::string body;
  char line[512];
  body += std::string(kMagic) + "\n";
  std::snprintf(line, sizeof line, "stage %.17g %.17g %.17g %.17g %.17g %.17g\n", s.slider_mass_kg,
                s.counter_mass_kg, s.friction_coefficient, s.gravity_m_s2, s.stroke_m,
                s.step_correction);
  body += line;
  for (int r = 0; r < CalibrationState::kRegions; ++r) {
    for (int d = 0; d < CalibrationState::kDirections; ++d) {
      const CalibrationEstimate& e = s.estimates[r][d];
      std::snprintf(line, sizeof line, "estimate %s %s %llu %.17g %.17g %.17g %.17g %.17g\n",
                    region_key(r), direction_name(d), static_cast<unsigned long long>(e.updates),
                    e.alpha, e.alpha_mu, e.p_aa, e.p_am, e.p_mm);
      body += line;
    }
  }
  std::snprintf(line, sizeof line, "rungs %d %d\n", s.rung_count[0], s.rung_count[1]);
  body += line;
  for (int d = 0; d < CalibrationState::kDirections; ++d) {
    for (int i = 0; i < s.rung_count[d] && i < CalibrationState::kMaxRungs; ++i) {
      const RungEstimate& e = s.rungs[d][i];
      std::snprintf(
          line, sizeof line, "rung %s %.17g %.17g %.17g %llu %.17g %.17g %.17g %.17g %.17g\n",
          direction_name(d), e.freq_hz, e.duty, e.stroke_m,
          static_cast<unsigned long long>(e.updates), e.offset_m, e.step_m, e.p_oo, e.p_os, e.p_ss);
      body += line;
    }
  }
  std::snprintf(line, sizeof line, "total_updates %llu\n",
                static_cast<unsigned long long>(s.total_updates));
  body += line;
  std::snprintf(line, sizeof line, "checksum %016llx\n",
                static_cast<unsigned long long>(fnv1a(body)));
  return body + line;
}

namespace {

// A calibration file's error: its 1-based line and what is wrong there.
struct FileError {
  std::size_t line = 0;
  std::string what;
};

constexpr std::size_t kEstimateLines =
    static_cast<std::size_t>(CalibrationState::kRegions) * CalibrationState::kDirections;

// The file's shape: the magic line, the stage line, the estimates, (version 2) 'rungs NEG POS' and
// that many rung lines, 'total_updates N', the checksum. Reads the rung counts; checks the line
// count and the checksum over every line before the last.
std::optional<FileError> check_layout(const std::vector<std::string>& lines,
                                      int (&rung_counts)[2]) {
  if (lines.empty() || (lines[0] != kMagic && lines[0] != kMagicV1))
    return FileError{1,
                     std::string("not a calibration file (expected first line '") + kMagic + "')"};
  const bool v1 = lines[0] == kMagicV1;
  std::size_t expected_lines = 2 + kEstimateLines + 2;
  if (!v1) {
    const std::size_t rungs_line = 2 + kEstimateLines + 1;  // 1-based
    if (lines.size() < rungs_line + 2)
      return FileError{lines.size(), "truncated: " + std::to_string(lines.size()) +
                                         " lines, expected at least " +
                                         std::to_string(rungs_line + 2)};
    char tail = 0;
    if (std::sscanf(lines[rungs_line - 1].c_str(), "rungs %d %d%c", &rung_counts[0],
                    &rung_counts[1], &tail) != 2 ||
        rung_counts[0] < 0 || rung_counts[1] < 0 || rung_counts[0] > CalibrationState::kMaxRungs ||
        rung_counts[1] > CalibrationState::kMaxRungs)
      return FileError{rungs_line, "expected 'rungs NEGATIVE POSITIVE' (each 0 .. " +
                                       std::to_string(CalibrationState::kMaxRungs) + ")"};
    expected_lines += 1 + static_cast<std::size_t>(rung_counts[0] + rung_counts[1]);
  }
  if (lines.size() != expected_lines)
    return FileError{lines.size(), "truncated or extended: " + std::to_string(lines.size()) +
                                       " lines, expected " + std::to_string(expected_lines)};
  std::string body;
  for (std::size_t i = 0; i + 1 < lines.size(); ++i) body += lines[i] + "\n";
  unsigned long long sum = 0;
  char tail = 0;
  if (std::sscanf(lines.back().c_str(), "checksum %llx%c", &sum, &tail) != 1)
    return FileError{lines.size(), "expected 'checksum HEX'"};
  if (sum != fnv1a(body)) return FileError{lines.size(), "checksum mismatch (the file is corrupt)"};
  return std::nullopt;
}

// The estimate lines (3 ..), one per region and direction in that order.
std::optional<FileError> read_estimates(const std::vector<std::string>& lines,
                                        CalibrationState& s) {
  for (int r = 0; r < CalibrationState::kRegions; ++r) {
    for (int d = 0; d < CalibrationState::kDirections; ++d) {
      const std::size_t ln = 3 + static_cast<std::size_t>(r * CalibrationState::kDirections + d);
      char region[32] = {}, direction[32] = {}, tail = 0;
      unsigned long long updates = 0;
      CalibrationEstimate& e = s.estimates[r][d];
      if (std::sscanf(lines[ln - 1].c_str(), "estimate %31s %31s %llu %lf %lf %lf %lf %lf%c",
                      region, direction, &updates, &e.alpha, &e.alpha_mu, &e.p_aa, &e.p_am, &e.p_mm,
                      &tail) != 8)
        return FileError{
            ln, "expected 'estimate REGION DIRECTION UPDATES ALPHA ALPHA_MU P_AA P_AM P_MM'"};
      if (std::string(region) != region_key(r) || std::string(direction) != direction_name(d))
        return FileError{ln, std::string("expected the estimate for ") + region_key(r) + " " +
                                 direction_name(d) + ", found " + region + " " + direction};
      e.updates = updates;
      if (!estimate_ok(e))
        return FileError{ln,
                         "alpha and alpha_mu must be finite and > 0, the covariance positive "
                         "semi-definite"};
    }
  }
  return std::nullopt;
}

// The rung lines after 'rungs NEG POS': the negative rungs, then the positive ones.
std::optional<FileError> read_rungs(const std::vector<std::string>& lines,
                                    const int (&rung_counts)[2], CalibrationState& s) {
  std::size_t ln = 2 + kEstimateLines + 2;  // the first rung line (1-based)
  for (int d = 0; d < CalibrationState::kDirections; ++d) {
    s.rung_count[d] = rung_counts[d];
    for (int i = 0; i < rung_counts[d]; ++i, ++ln) {
      char direction[32] = {}, tail = 0;
      unsigned long long updates = 0;
      RungEstimate& e = s.rungs[d][i];
      if (std::sscanf(lines[ln - 1].c_str(), "rung %31s %lf %lf %lf %llu %lf %lf %lf %lf %lf%c",
                      direction, &e.freq_hz, &e.duty, &e.stroke_m, &updates, &e.offset_m, &e.step_m,
                      &e.p_oo, &e.p_os, &e.p_ss, &tail) != 10)
        return FileError{
            ln, "expected 'rung DIRECTION FREQ DUTY STROKE UPDATES OFFSET STEP P_OO P_OS P_SS'"};
      if (std::string(direction) != direction_name(d))
        return FileError{ln, std::string("expected a rung moving ") + direction_name(d) +
                                 ", found " + direction};
      e.updates = updates;
      if (!rung_ok(e))
        return FileError{ln, "a rung must be a valid cell with finite values and a covariance"};
    }
  }
  return std::nullopt;
}

// The stage line (2) and 'total_updates N' (the line before the checksum).
std::optional<FileError> read_stage_and_total(const std::vector<std::string>& lines,
                                              CalibrationState& s) {
  char tail = 0;
  if (std::sscanf(lines[1].c_str(), "stage %lf %lf %lf %lf %lf %lf%c", &s.slider_mass_kg,
                  &s.counter_mass_kg, &s.friction_coefficient, &s.gravity_m_s2, &s.stroke_m,
                  &s.step_correction, &tail) != 6)
    return FileError{2, "expected 'stage' and six numbers"};
  unsigned long long total = 0;
  const std::size_t total_line = lines.size() - 1;  // 1-based
  if (std::sscanf(lines[total_line - 1].c_str(), "total_updates %llu%c", &total, &tail) != 1)
    return FileError{total_line, "expected 'total_updates N'"};
  s.total_updates = total;
  return std::nullopt;
}

}  // namespace

bool Calibration::parse(const std::string& text, const std::string& source, CalibrationState& out,
                        std::string& error) {
  std::vector<std::string> lines;
  std::istringstream in(text);
  for (std::string l; std::getline(in, l);) lines.push_back(l);
  int rung_counts[2] = {0, 0};
  CalibrationState s;
  std::optional<FileError> e = check_layout(lines, rung_counts);
  if (!e) e = read_stage_and_total(lines, s);
  if (!e) e = read_estimates(lines, s);
  if (!e) e = read_rungs(lines, rung_counts, s);
  if (e) {
    error = source + ":" + std::to_string(e->line) + ": " + e->what;
    return false;
  }
  out = s;
  return true;
}

bool Calibration::load(const std::string& path, std::string& error) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    error = path + ": cannot open: " + std::strerror(errno);
    return false;
  }
  std::ostringstream buf;
  buf << in.rdbuf();
  CalibrationState s;
  if (!parse(buf.str(), path, s, error)) return false;
  try {
    set_state(s);
  } catch (const model::InputError& e) {
    error = path + ": " + e.what();
    return false;
  }
  error.clear();
  return true;
}

}  // namespace idm::control
