#include "control/planner.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

namespace idm::control {

const model::ParamTable<PlannerConfig>& planner_params() {
  using model::integer;
  using model::real;
  static const model::ParamTable<PlannerConfig> table({
      real<PlannerConfig>(
          "resolution_m", "m", {0, 1e-6, true},
          "one interferometer count (from the interferometer)",
          [](auto& c) -> auto& { return c.resolution_m; }),
      integer<PlannerConfig>(
          "max_bursts", "count", 1, 1000000, "most chunks in one move",
          [](auto& c) -> auto& { return c.max_bursts; }),
  });
  return table;
}

void validate(const PlannerConfig& c, const std::string& where) {
  planner_params().validate(c, where);
}

bool Plan::within_final_step() const {
  return std::fabs(residual_m()) <= final_step_m * (1 + 1e-9);
}

std::uint64_t Plan::total_cycles() const {
  std::uint64_t n = 0;
  for (const Burst& b : bursts) n += b.cycles;
  return n;
}

double Plan::duration_s() const {
  double t = 0;
  for (const Burst& b : bursts) t += b.duration_s();
  return t;
}

std::uint64_t chunk_cycle_limit(const ChunkLimits& limits, double max_chunk_s, double freq_hz,
                                std::uint32_t period_samples, std::uint64_t max_cycles) {
  double n = std::floor(max_chunk_s * freq_hz * (1 + 1e-12));
  if (limits.buffered && period_samples > 0)
    n = std::min(n, std::floor(static_cast<double>(limits.max_chunk_samples - 1) / period_samples));
  if (max_cycles > 0) n = std::min(n, static_cast<double>(max_cycles));
  n = std::min(n, static_cast<double>(limits.max_burst_cycles));
  if (!limits.buffered) n = std::min(n, static_cast<double>(limits.device_max_cycles));
  return n < 1 ? 1 : static_cast<std::uint64_t>(n);
}

}  // namespace idm::control
