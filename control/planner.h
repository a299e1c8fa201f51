// What the positioner plans with (PlannerConfig), what it reports of its plans (Burst, Plan), and
// how long one chunk may be (ChunkLimits): a chunk is one burst of a usable cell of the region map
// (robustly one-step, within the device limits), cut to whole cycles. The step ladder that
// chooses it is control/step_ladder.h.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "control/region_map.h"
#include "model/param_table.h"

namespace idm::control {

struct PlannerConfig {
  // One interferometer count.
  double resolution_m = 9.8906e-9;
  // Most bursts (chunks) in one move (a device that holds few cycles per burst needs many for a
  // long move).
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

// What the device lets one chunk be: the output's buffer (an output that takes samples) or its
// burst parameters (one that takes a frequency, duty and cycle count), and the map's longest burst.
struct ChunkLimits {
  bool buffered = true;                       // the output takes samples
  std::size_t max_chunk_samples = 0;          // buffered: the longest chunk it takes, samples
  std::uint64_t max_burst_cycles = 1000000;   // the map's (DeviceLimits::max_burst_cycles)
  std::uint64_t device_max_cycles = 1000000;  // not buffered: most cycles in one burst
};

// The most whole cycles (at least 1) one chunk of a cell of freq_hz (period_samples on the sample
// clock; its max_cycles, 0: no limit) may play: within max_chunk_s and the device's limits.
std::uint64_t chunk_cycle_limit(const ChunkLimits& limits, double max_chunk_s, double freq_hz,
                                std::uint32_t period_samples, std::uint64_t max_cycles);

}  // namespace idm::control
