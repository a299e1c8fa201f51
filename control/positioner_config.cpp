// The positioner's settings: the table of control: keys and the check of a PositionerConfig.
#include "control/positioner_config.h"

#include <cmath>
#include <vector>

#include "control/rest_mean.h"
#include "model/yaml_util.h"

namespace idm::control {

namespace {

using model::integer;
using model::real;
using model::with_default;
using model::with_relation;
using P = PositionerConfig;

// The window, the corrections, the stall, the chunks, the readings and the soft limits.
std::vector<model::Param<P>> move_params() {
  return {
      real<P>(
          "tolerance_m", "m", {0, 1e-3},
          "the in-position window (RDBD, MOVE:WINDow); 0: one count (the loop aims for half a "
          "count within it)",
          [](auto& c) -> auto& { return c.tolerance_m; }),
      integer<P>(
          "max_retries", "count", 0, 1000, "correction rounds after the first plan (RTRY)",
          [](auto& c) -> auto& { return c.max_retries; }),
      integer<P>(
          "stall_bursts", "count", 1, 1000, "bursts in a row without progress: a stall fault",
          [](auto& c) -> auto& { return c.stall_bursts; }),
      real<P>(
          "stall_fraction", "1", {0, 1, false, true},
          "a burst that moved less than this share of its prediction made no progress",
          [](auto& c) -> auto& { return c.stall_fraction; }),
      real<P>(
          "settle_s", "s", {0, 10}, "after a burst, wait this long before the position is read",
          [](auto& c) -> auto& { return c.settle_s; }),
      real<P>(
          "max_chunk_s", "s", {0, 10, true},
          "the longest piece played at once: what a STOP waits for (must fit the capture)",
          [](auto& c) -> auto& { return c.max_chunk_s; }),
      integer<P>(
          "latch_words", "count", 1, RestMean::kMaxWords,
          "readings averaged for a position at rest (the one shown, and the landing's: up to 16 "
          "times as many while its mean is not surely inside the window)",
          [](auto& c) -> auto& { return c.latch_words; }),
      with_relation(with_default(real<P>(
                                     "soft_lower_m", "m", {-10, 10},
                                     "soft limit (LLM): a move or STEP ending below is refused",
                                     [](auto& c) -> auto& { return c.soft_lower_m; }),
                                 "stage.travel_m"),
                    "< soft_upper_m",
                    [](const P& c) {
                      return model::Range{-1e300, c.soft_upper_m, false, true};
                    }),
      with_relation(with_default(real<P>(
                                     "soft_upper_m", "m", {-10, 10},
                                     "soft limit (HLM): a move or STEP ending above is refused",
                                     [](auto& c) -> auto& { return c.soft_upper_m; }),
                                 "stage.travel_m"),
                    "> soft_lower_m",
                    [](const P& c) {
                      return model::Range{c.soft_lower_m, 1e300, true, false};
                    }),
  };
}

// hold_s: -1 (until the next motion) or [0, 86400] s, which one interval cannot say: the real
// key's range, read, check and assign, each refusing what lies between -1 and 0.
model::Param<P> hold_param() {
  const auto get = [](auto& c) -> auto& {
    return c.hold_s;
  };
  model::Param<P> p = real<P>(
      "hold_s", "s", {-1, 86400},
      "after a move: keep the target this long (0: no hold, -1: until the next motion; HOLD)", get);
  p.range = "-1 or [0, 86400]";
  const auto ok = [](double x) { return x == -1 || (x >= 0 && x <= 86400); };
  const auto refuse = [range = p.range](double x) {
    return model::format_number(x) + " is out of range, allowed " + range;
  };
  p.read = [ok, refuse, get](P& c, const YAML::Node& v, const std::string& file,
                             const std::string& key) {
    const double x = model::read_double(v, file, key, -1e308, 1e308);
    if (!ok(x)) throw model::InputError(model::located(file, v, key, refuse(x)));
    get(c) = x;
  };
  p.check = [ok, refuse](const P& c, const std::string& key) {
    if (!ok(c.hold_s)) throw model::InputError(key + ": " + refuse(c.hold_s));
  };
  p.assign = [ok, refuse](P& c, double x, const std::string& key) {
    if (!ok(x)) throw model::InputError(key + ": " + refuse(x) + " s");
    c.hold_s = x;
  };
  return p;
}

// The approach and the step ladder, and how a motion ends: dwell, timeout, end of travel, hold.
std::vector<model::Param<P>> ladder_and_end_params() {
  return {
      real<P>(
          "approach_uncertainty", "1", {0, 10},
          "share by which an approach burst may exceed its prediction",
          [](auto& c) -> auto& { return c.approach_uncertainty; }),
      real<P>(
          "stall_min_counts", "count", {0, 1e6},
          "chunks predicted to move fewer counts are not judged for a stall",
          [](auto& c) -> auto& { return c.stall_min_counts; }),
      integer<P>(
          "max_chunks_per_move", "count", 0, 100000000,
          "most chunks in one move (0: the planner's max_bursts)",
          [](auto& c) -> auto& { return c.max_chunks_per_move; }),
      real<P>(
          "final_step_counts", "count", {0.5, 1000},
          "the last chunks use a rung of at most this step",
          [](auto& c) -> auto& { return c.final_step_counts; }),
      with_relation(real<P>(
                        "min_step_counts", "count", {0, 1000, false, true},
                        "a rung stepping less per cycle is taken as not moving",
                        [](auto& c) -> auto& { return c.min_step_counts; }),
                    "< final_step_counts",
                    [](const P& c) {
                      return model::Range{-1e300, c.final_step_counts, false, true};
                    }),
      integer<P>(
          "dead_rung_moves", "count", 1, 1000000,
          "a rung judged not to move is left out for this many moves",
          [](auto& c) -> auto& { return c.dead_rung_moves; }),
      real<P>(
          "chunk_overhead_s", "s", {0, 10},
          "time a chunk costs beyond its cycles (planning weight)",
          [](auto& c) -> auto& { return c.chunk_overhead_s; }),
      real<P>(
          "max_speed_m_s", "m/s", {0, 1},
          "speed limit of a move's approach (0: none; MOVE:VELocity; the final rung plays at its "
          "own speed)",
          [](auto& c) -> auto& { return c.max_speed_m_s; }),
      real<P>(
          "dwell_s", "s", {0, 60},
          "a move is done once fresh readings stayed in the window this long (MOVE:DWELl)",
          [](auto& c) -> auto& { return c.dwell_s; }),
      real<P>(
          "move_timeout_s", "s", {0, 86400},
          "a move not done after this long ends with TIMEOUT (0: no limit)",
          [](auto& c) -> auto& { return c.move_timeout_s; }),
      real<P>(
          "eot_step_m", "m", {0, 1e-3},
          "end of travel: mean step below this while driving stops the axis (0: off; EOT:STEP)",
          [](auto& c) -> auto& { return c.eot_step_m; }),
      integer<P>(
          "eot_cycles", "count", 1, 100000,
          "end of travel: the cycles the mean step is taken over (EOT:CYCLes)",
          [](auto& c) -> auto& { return c.eot_cycles; }),
      hold_param(),
      real<P>(
          "hold_window_m", "m", {0, 1e-3},
          "a hold corrects when a reading leaves this window (0: the move window; HOLD:WINDow)",
          [](auto& c) -> auto& { return c.hold_window_m; }),
  };
}

}  // namespace

const model::ParamTable<PositionerConfig>& positioner_params() {
  static const model::ParamTable<P> table(model::join<P>({move_params(), ladder_and_end_params()}));
  return table;
}

void validate(const PositionerConfig& c, const std::string& where) {
  // Infinite soft limits are allowed in code (no limit), as the ends of the range on their side;
  // files always give finite ones. The table checks the ranges and the relations (lower < upper,
  // min_step_counts < final_step_counts).
  PositionerConfig finite = c;
  if (std::isinf(finite.soft_lower_m)) finite.soft_lower_m = std::copysign(10.0, c.soft_lower_m);
  if (std::isinf(finite.soft_upper_m)) finite.soft_upper_m = std::copysign(10.0, c.soft_upper_m);
  positioner_params().validate(finite, where);
  if (!(c.travel_lower_m < c.travel_upper_m))
    throw model::InputError(where + ": the travel [" + model::format_number(c.travel_lower_m) +
                            ", " + model::format_number(c.travel_upper_m) +
                            "] m is not an interval (stage.travel_m: lower < upper)");
}

}  // namespace idm::control
