// Online calibration of the step model: each measured steady step updates, for its region and
// direction, a recursive least-squares estimate (with forgetting) of the correction factor alpha
// and the friction coefficient mu, so that later moves of a session need fewer corrections.
// Saved to a file (serialize(); the daemon writes it crash-safe with recording::write_file_durably)
// and loaded at start; a corrupt or mismatched file is reported (the daemon refuses to start on it
// rather than overwrite a file it cannot read).
//
// CONTRACT (shared with daemon/): the daemon constructs one Calibration, hands a pointer to the
// Positioner, copies state() out of the real-time loop to save it, and loads it at start.
// Extend it; do not change what is here without changing the daemon with it.
//
// The step model (eq 22 written along the direction of motion, d = min(duty, 1 - duty)):
//
//     step = alpha m S / ((M+m)(1-d)) - alpha mu g d^2 T^2
//
// is linear in theta = (alpha, alpha mu). A burst of N cycles from rest is predicted as
//
//     D(N) = N step + (alpha / alpha_nominal) (single_nominal - step_nominal)
//
// (the map's first-cycle transient scaled by alpha), also linear in theta. Each measured burst
// (rest to rest, at least min_update_counts counts) is one observation of D(N), divided by the
// nominal prediction so that every burst weighs by its relative error, and weighted by its
// expected relative noise (observation_relative_sd and one count over the displacement).
// P is kept in units of the parameters (variances of alpha and alpha mu). Details and the file
// format: control/README.md ("Online calibration").
#pragma once

#include <cstdint>
#include <string>

#include "model/impulse_model.h"
#include "model/param_table.h"
#include "model/stage.h"

namespace idm::control {

struct RegionCell;

struct CalibrationConfig {
  double forgetting = 0.98;  // RLS forgetting factor lambda, (0, 1]
  bool enabled = true;
  // Relative standard deviation of the nominal alpha and alpha mu before any update (P0).
  double initial_relative_sd = 0.3;
  // Relative standard deviation of one burst's displacement about the model (the model's own
  // error); the interferometer's count over the displacement is added to it per burst.
  double observation_relative_sd = 0.05;
  // A calibrated prediction is used only while its ratio to the nominal one lies in
  // [1 / max_ratio, max_ratio]; outside, the cell falls back to the nominal prediction.
  double max_ratio = 3.0;
  // A burst updates the estimate only when it moved at least this many interferometer counts.
  double min_update_counts = 3.0;
  // Per-rung estimates (see RungEstimate): relative standard deviation of the model's seed (the
  // impulse model is off by 0.3x .. 0.8x on a compliant plant: low confidence), and the
  // forgetting factor of their RLS (friction varies along the guide: recent bursts weigh more).
  double rung_initial_relative_sd = 0.5;
  double rung_forgetting = 0.9;
};
const model::ParamTable<CalibrationConfig>& calibration_params();
void validate(const CalibrationConfig& config, const std::string& where = "control.calibration");

// One (region, direction) estimate: theta = (alpha, alpha mu), its covariance P (symmetric).
struct CalibrationEstimate {
  double alpha = 0;
  double alpha_mu = 0;
  double p_aa = 0, p_am = 0, p_mm = 0;
  std::uint64_t updates = 0;

  double mu() const { return alpha != 0 ? alpha_mu / alpha : 0.0; }
};

// One rung of the positioner's step ladder (a played cell, one direction): the displacement of a
// burst of N cycles from rest, along the motion, as D(N) = offset_m + N step_m (the first-cycle
// transient and the steady step). For a fixed cell eq 22 makes step = alpha p - (alpha mu) q with
// p, q fixed, so a per-cell (alpha, alpha mu) carries exactly one combination of the two: the rung
// keeps the identifiable pair (offset, step) instead, by weighted RLS with forgetting, seeded from
// the map's prediction. P: covariance of (offset, step) in m^2.
struct RungEstimate {
  double freq_hz = 0, duty = 0, stroke_m = 0;  // the key: the played cell
  double offset_m = 0, step_m = 0;
  double p_oo = 0, p_os = 0, p_ss = 0;
  std::uint64_t updates = 0;

  double predict_m(std::uint64_t cycles) const {
    return offset_m + static_cast<double>(cycles) * step_m;
  }
  bool same_cell(double f, double d, double s) const;
};

// A plain snapshot (trivially copyable): what is saved and loaded.
struct CalibrationState {
  static constexpr int kRegions = 3;     // model::Region: Cutoff, OneStep, MultiStep
  static constexpr int kDirections = 2;  // [0]: negative (duty < 0.5), [1]: positive
  // The stage the estimates belong to (a file for another stage is refused).
  double slider_mass_kg = 0, counter_mass_kg = 0, friction_coefficient = 0, gravity_m_s2 = 0,
         stroke_m = 0, step_correction = 0;
  CalibrationEstimate estimates[kRegions][kDirections];
  std::uint64_t total_updates = 0;
  // Per-rung estimates, per direction ([0] negative, [1] positive), the first rung_count used.
  static constexpr int kMaxRungs = 128;
  int rung_count[kDirections] = {0, 0};
  RungEstimate rungs[kDirections][kMaxRungs];
};

class Calibration {
 public:
  Calibration(const model::StageParams& nominal, CalibrationConfig config = {});

  // Loads a saved calibration. Returns false and sets `error` (naming the file, and the line or
  // key) when the file is missing, corrupt, or for another stage; the calibration is then left
  // as it was (nominal). Never throws on bad content.
  bool load(const std::string& path, std::string& error);
  // Back to the nominal stage.
  void reset();

  const CalibrationConfig& config() const { return config_; }

  // ---- snapshot (for the daemon: copy out of the real-time loop, save elsewhere) ----
  CalibrationState state() const { return state_; }
  // Takes a snapshot over. Throws model::InputError when it belongs to another stage or holds
  // non-finite or non-positive estimates (nothing is changed then).
  void set_state(const CalibrationState& state);
  // The file's text for a snapshot and back (what save/load write and read). parse returns false
  // with `error` naming `source` and the line on bad content; `out` is then unchanged.
  static std::string serialize(const CalibrationState& state);
  static bool parse(const std::string& text, const std::string& source, CalibrationState& out,
                    std::string& error);

  // ---- used by the Positioner (real-time safe: no allocation, no lock) ----
  const CalibrationEstimate& estimate(model::Region region, int direction) const;
  double alpha(model::Region region, int direction) const {
    return estimate(region, direction).alpha;
  }
  double mu(model::Region region, int direction) const { return estimate(region, direction).mu(); }
  // One measured burst of `cycles` cycles of the cell: displacement signed (as the cell's
  // step_m), count_m the interferometer count. Returns whether it updated the estimate.
  bool update(const RegionCell& cell, std::uint64_t cycles, double measured_m, double count_m);
  std::uint64_t total_updates() const { return state_.total_updates; }
  const model::StageParams& nominal() const { return nominal_; }

  // ---- per-rung estimates (real-time safe: fixed arrays, no allocation) ----
  // The stored estimate of the cell (freq, duty, stroke) moving `direction`: false when disabled
  // or none is stored.
  bool find_rung(int direction, double freq_hz, double duty, double stroke_m,
                 RungEstimate& out) const;
  // Stores (adds or replaces by key) a rung estimate; false when disabled, the table is full or
  // the estimate is not finite. Counts one update.
  bool store_rung(int direction, const RungEstimate& estimate);
  // One weighted RLS step of a rung estimate with a measured burst of `cycles` cycles
  // (`measured_along_m` > 0 along the motion); noise: count_m and relative_sd of the displacement.
  // P is bounded by p_max_* (no wind-up). Returns false (estimate untouched) on bad input.
  static bool rls_update(RungEstimate& e, std::uint64_t cycles, double measured_along_m,
                         double count_m, double relative_sd, double forgetting, double p_max_oo,
                         double p_max_ss);

 private:
  CalibrationEstimate& slot(model::Region region, int direction);
  CalibrationState nominal_state() const;

  model::StageParams nominal_;
  CalibrationConfig config_;
  CalibrationState state_;
};

}  // namespace idm::control
