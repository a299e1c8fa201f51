// The landing plan: how to end a move within the window when the ladder's rungs step farther than
// the window is wide. Pure (no state, no allocation): the positioner hands in what its rungs have
// learned and plays the first chunk of the plan returned, then plans again from the reading. A
// chunk of rung r with n cycles moves D(n) = offset + n step along the rung's direction, with a
// standard deviation of rel_sd |D(n)| (the rung's learned scatter), the estimate's own for n cycles
// (p_oo + 2 n p_os + n^2 p_ss) and the reading's (read_sd_m). Its pessimistic end is D(n) (1 +
// rel_margin) and two of the estimate's standard deviations. A plan is one chunk toward the target,
// or two: a first chunk of any rung either way, then the best single chunk from where that is
// expected to end (a vernier: +62 nm then -57 nm ends 5 nm on). The chunk that lands may aim
// outside the window (land by its scatter) unless it already missed in this move. A chunk's cycles
// are the nearest landing's (round((distance - offset) / step)) or up to two either side of it,
// the most the limits allow or one less, or 1-3. Its landing probability is that of a normal end
// position falling within +/- half_window_m of the target; the plan kept is the one with the least
// expected time to land, its time over its probability (a failed try costs the plan's time again).
#pragma once

#include <cstddef>
#include <cstdint>

namespace idm::control {

// A plan less likely than this to land is no plan (once in a thousand tries, where a move has
// max_retries of them: 10 by default).
inline constexpr double kMinLandingProbability = 1e-3;

// A window whose landing tries, all of a move's, are less likely than this to meet it cannot be
// met: hunting for it is more likely to end in retry_limit than in the window, so the move says
// so before its first try (landing_reach).
inline constexpr double kMinArrivalProbability = 0.5;

struct LandingRung {
  int direction = 1;                // +1 / -1: the way its chunks move the slider
  double offset_m = 0, step_m = 0;  // D(n) = offset + n step, along direction (step > 0)
  double rel_sd = 0.5;              // standard deviation of a chunk, as a share of D(n)
  // The estimate's own covariance of (offset, step), m^2: what D(n) is known to for a cycle
  // count it has seldom played (a coarse rung's first cycle).
  double p_oo = 0, p_os = 0, p_ss = 0;
  // How far a chunk may move beyond D(n), as a share of it (the positioner's pessimistic
  // burst): what the limits below are kept with.
  double rel_margin = 1.0;
  std::uint64_t max_cycles = 0;  // most cycles in one chunk (0: no limit)
  // A landing chunk of this many cycles was played in this move and missed (0: none): it is not
  // aimed outside the window again (on a stage that repeats itself it would miss the same way).
  std::uint64_t missed_cycles = 0;
  double freq_hz = 1;
};

struct LandingChunk {
  int rung = -1;  // index into the rungs handed in; -1: none
  std::uint64_t cycles = 0;
};

struct LandingPlan {
  LandingChunk first, second;  // second.rung < 0: one chunk
  double probability = 0;      // of ending within the window (0: no plan)
  double time_s = 0;           // the plan's cycles plus one overhead per chunk
  double expected_s() const { return probability > 0 ? time_s / probability : 1e300; }
  bool two_chunks() const { return second.rung >= 0; }
};

// What the plan must keep to.
struct LandingLimits {
  double half_window_m = 0;     // lands: the end within this of the target
  double read_sd_m = 0;         // the reading's own standard deviation
  double chunk_overhead_s = 0;  // a chunk's cost beyond its cycles (settle, read)
  // How far the slider may go each way from where it is (the soft limits): no chunk's
  // pessimistic end lies beyond. [0] negative, [1] positive.
  double room_m[2] = {1e300, 1e300};
  // A chunk toward the target may pass it, pessimistically, by at most this share of its step.
  double max_pass_steps = 0.8;
  std::uint64_t max_first_cycles = 4;  // the first chunk of a two-chunk plan
};

// P(|X - target| <= half_window) for an end position X normal about target + miss_m with sd_m.
double landing_probability(double miss_m, double sd_m, double half_window_m);

// The fewest cycles (at least one) of a rung moving offset + n step that are predicted to move
// at least half a step: a burst's first cycles can move nothing, and a chunk that moves nothing
// teaches nothing.
double moving_cycles(double offset_m, double step_m);

// P(|U + N| <= half_window) for U uniform on [-half_spacing, half_spacing] and N normal (0, sd):
// a chunk whose nearest end lies anywhere on a grid of that spacing about the target, with that
// scatter (a target's place on the rungs' grid is not known before the move).
double grid_landing_probability(double half_spacing_m, double sd_m, double half_window_m);

// Whether a window can be met at all: how likely one landing try is to end within it for a target
// anywhere, and `tries` of them. A try is the better of one chunk of any rung (ends a step apart,
// its scatter at its shortest chunk predicted to move half a step) and a vernier (a first chunk of
// 1..max_first_cycles cycles of any rung, then a chunk of any rung: the first chunks' ends spread
// evenly over the second's step, their scatters added). Optimistic wherever it guesses (the
// spread even, the estimates exact, rel_sd as handed in): a window it calls unreachable is met
// by luck only.
struct LandingReach {
  double try_probability = 0;
  double arrival_probability = 0;  // 1 - (1 - try)^tries
  bool reachable() const { return arrival_probability >= kMinArrivalProbability; }
};
LandingReach landing_reach(const LandingRung* rungs, std::size_t count, double half_window_m,
                           double read_sd_m, std::uint64_t max_first_cycles, int tries);
// The narrowest half window that `tries` tries meet (landing_reach) with kMinArrivalProbability,
// to 1 %; 0 without a usable rung.
double least_half_window_m(const LandingRung* rungs, std::size_t count, double read_sd_m,
                           std::uint64_t max_first_cycles, int tries);

// One chunk of rungs[index] with `cycles` cycles toward the target of `error_m`, scored as a
// plan is (no limit or aim applied): what the positioner's usual final chunk is weighed by.
LandingPlan score_chunk(double error_m, const LandingLimits& limits, const LandingRung* rungs,
                        std::size_t index, std::uint64_t cycles);

// The best single chunk for `error_m` (target - position; its sign is the way to go).
LandingPlan best_single_chunk(double error_m, const LandingLimits& limits, const LandingRung* rungs,
                              std::size_t count);

// The one- or two-chunk plan with the least expected time to land. probability 0: none.
LandingPlan plan_landing(double error_m, const LandingLimits& limits, const LandingRung* rungs,
                         std::size_t count);

}  // namespace idm::control
