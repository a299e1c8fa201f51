// The move planner: a signed distance -> a sequence of bursts (duty, frequency, stroke, cycles),
// every one from a usable cell of the region map (robustly one-step, within the device limits).
// The rules are in control/README.md ("Planning rules").
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "model/param_table.h"

#include "control/region_map.h"

namespace idm::control {

struct PlannerConfig {
  // The step the last burst should not exceed: one interferometer count.
  double resolution_m = 9.8906e-9;
  // When no usable cell steps within the resolution, the last burst may use any cell whose step is
  // within this factor of the finest one.
  double final_class_slack = 1.25;
  // The last burst covers up to about this many of its (largest allowed) steps; the bursts before
  // it stop at least half of that short of the target for every mu of the stated interval.
  int final_approach_steps = 8;
  // Most bursts in one plan (a device that holds few cycles per burst needs many for a long move).
  int max_bursts = 10000;
};

// The keys of PlannerConfig (resolution_m comes from the interferometer, not a file).
const model::ParamTable<PlannerConfig>& planner_params();
void validate(const PlannerConfig& config, const std::string& where = "planner");

struct Burst {
  double freq_hz = 0;
  double duty = 0;
  double stroke_m = 0;
  std::uint32_t period_samples = 0;  // on the sample clock; 0 for a parameter device
  std::uint32_t extension_samples = 0;
  std::uint64_t cycles = 0;
  double step_m = 0;           // the cell's steady step (eq 22), signed
  double displacement_m = 0;   // predicted for the whole burst from rest, nominal mu, signed
  std::size_t cell_index = 0;  // into RegionMap::cells()

  double duration_s() const { return static_cast<double>(cycles) / freq_hz; }
};

struct Plan {
  double target_m = 0;
  std::vector<Burst> bursts;
  double predicted_m = 0;  // sum of the bursts' predicted displacements
  // The |step| of the last burst. For an empty plan the finest move toward the target: the final
  // class bound when the target is within half of it, else the smallest displacement of any burst
  // (which is then at least twice the target: no burst would come closer); 0 when no usable cell
  // moves that way.
  double final_step_m = 0;

  double residual_m() const { return target_m - predicted_m; }
  // The prediction ends within the final step of the target.
  bool within_final_step() const;
  std::uint64_t total_cycles() const;
  double duration_s() const;
};

class Planner {
 public:
  // Sorts the map's usable cells once per direction; the map must outlive the planner.
  explicit Planner(const RegionMap& map, PlannerConfig config = {});

  // Deterministic; allocates only when out.bursts has to grow.
  void plan(double distance_m, Plan& out) const;
  Plan plan(double distance_m) const;

  const RegionMap& map() const { return map_; }
  const PlannerConfig& config() const { return config_; }
  // Largest and smallest |step| of the usable cells moving in `direction` (+1 / -1); 0 if none.
  double largest_step_m(int direction) const;
  double finest_step_m(int direction) const;
  // The largest |step| a last burst toward `direction` may use.
  double final_step_bound_m(int direction) const;

 private:
  // A usable cell seen along its direction of motion (all lengths > 0 forward).
  struct Entry {
    double step_m;       // |eq 22| at nominal mu
    double step_hi_m;    // largest over the mu interval
    double single_m;     // one-cycle burst, nominal (may be < 0: a first cycle that goes back)
    double single_hi_m;  // largest over the mu interval
    double period_s;
    std::uint64_t max_cycles;
    std::size_t cell;
    double displacement_m(std::uint64_t n) const {
      return single_m + static_cast<double>(n - 1) * step_m;
    }
    // No burst of this cell moves more than this per cycle: max(step, single).
    double rate_bound_m() const { return single_m > step_m ? single_m : step_m; }
  };
  struct Direction {
    std::vector<Entry> all;       // by step, largest first (then shorter period, then cell index)
    std::vector<Entry> approach;  // by rate_bound_m, largest first (then as in `all`)
    std::vector<Entry> last;      // the final class: step <= final_step_bound
    double final_step_bound_m = 0;
    double smallest_move_m = 0;  // the smallest forward displacement of any burst
  };
  const Direction& direction(int sign) const { return sign > 0 ? positive_ : negative_; }
  Burst make_burst(const Entry& e, std::uint64_t cycles, int sign) const;

  const RegionMap& map_;
  PlannerConfig config_;
  Direction positive_;
  Direction negative_;
};

}  // namespace idm::control
