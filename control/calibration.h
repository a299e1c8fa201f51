// Online calibration of the step model: each measured steady step updates, for its region and
// direction, a recursive least-squares estimate (with forgetting) of the correction factor alpha
// and the friction coefficient mu, so that later moves of a session need fewer corrections.
// Saved to a file and loaded at start; a corrupt or mismatched file is reported and ignored.
//
// CONTRACT (shared with daemon/): the daemon constructs one Calibration, hands a pointer to the
// Positioner, copies state() out of the real-time loop to save it, and loads it at start.
// Extend it; do not change what is here without changing the daemon with it.
#pragma once

#include <string>

#include "model/stage.h"

namespace idm::control {

struct CalibrationConfig {
  double forgetting = 0.98;  // RLS forgetting factor lambda, (0, 1]
  bool enabled = true;
};
void validate(const CalibrationConfig& config, const std::string& where = "control.calibration");

class Calibration {
 public:
  Calibration(const model::StageParams& nominal, CalibrationConfig config = {});

  // Loads a saved calibration. Returns false and sets `error` (naming the file, and the line or
  // key) when the file is missing, corrupt, or for another stage; the calibration is then left
  // as it was (nominal). Never throws on bad content.
  bool load(const std::string& path, std::string& error);
  // Writes crash-safe (temporary name, fsync, rename). Throws std::system_error naming the file.
  void save(const std::string& path) const;
  // Back to the nominal stage.
  void reset();

  const CalibrationConfig& config() const { return config_; }
  // (estimates per region and direction; update API used by the Positioner)
 private:
  model::StageParams nominal_;
  CalibrationConfig config_;
};

}  // namespace idm::control
