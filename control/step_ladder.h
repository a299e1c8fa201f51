// The step ladder: what to play next toward a target (control/README.md, "The step ladder"). Per
// direction, rungs built from the region map (one usable cell per stroke, frequency band and fast
// phase share), coarse to fine; each learns (offset, step) of its chunks online, is left out for a
// while when it does not move, and is judged proven once it moved as predicted. Given the error
// to the target it chooses the rung and cycles of the next chunk: the approach (the most progress
// per second that stops short), the final chunk (the finest rung that lands), the landing plan
// (landing_plan.h: one or two chunks of any rungs) and, when nothing lands from here, a back-off.
// It never plays anything itself: the positioner (positioner.h) turns a choice into a chunk,
// counts the tries and stalls, and ends the motion. Pure: no device, no allocation after build().
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

#include "control/calibration.h"
#include "control/landing_plan.h"
#include "control/planner.h"
#include "control/positioner_config.h"
#include "control/region_map.h"

namespace idm::control {

class StepLadder {
 public:
  struct Rung {
    std::size_t cell = 0;  // into the map's cells()
    int direction = 0;     // +1 / -1
    RungEstimate seed;     // the map's prediction, low confidence
    RungEstimate est;      // current
    bool dead = false;
    bool killed_in_streak = false;  // marked dead during the current run of non-moving chunks
    bool proven = false;            // has moved as predicted in this session
    std::uint64_t dead_until_move = 0;
    double pending_pred_m = 0, pending_moved_m = 0;  // small chunks awaiting a stall judgement
    std::uint64_t pending_cycles = 0;
    std::uint64_t chunks = 0;  // chunks played with it since construction
    // The scatter of its chunks about the estimate: a running mean of the squared relative
    // error of their displacements (friction along the guide moves a fine rung's step by tens
    // of per cent), and how many chunks it holds.
    double scatter_var = 0;
    std::uint64_t scatter_chunks = 0;
    // The cycles of its landing chunk that missed in this move (0: none; landing_plan.h).
    std::uint64_t missed_cycles = 0;
  };

  // What to play next (next_chunk).
  struct Choice {
    enum class Kind : std::uint8_t {
      Play,        // play `cycles` of rung `rung` toward `direction`
      NoRungs,     // no usable cell moves toward the target (the map has none that way)
      NoLiveRung,  // every rung toward the target has been judged not to move
      OutOfTries,  // nothing lands from here and a back-off would be one correction too many
    };
    Kind kind = Kind::Play;
    int direction = 0;
    int rung = -1;  // into the rungs of `direction`
    std::uint64_t cycles = 0;
    bool final_chunk = false;  // a chunk of the final zone (a try, unless capped or short)
    bool capped = false;       // cut short of the nearest landing: approach, not a try
    bool back_off = false;     // away from the target: a correction round of its own
    // The first chunk of a two-chunk landing plan (landing_plan.h: a vernier), either way: not a
    // try; the second is planned again from the reading.
    bool vernier = false;
    double final_step_m = 0;  // the final rung's learned step (what the plan reports)
  };

  // A chunk's judgement (judge): whether its rung was judged, found not to move, and whether that
  // counts toward a stall (the slider stuck, not the rung).
  struct Judgement {
    bool judged = false;
    bool failed = false;
    bool counts_as_stall = false;
  };

  // The map, the settings (read when planning: they may change between motions) and the
  // calibration (optional) must outlive the ladder.
  StepLadder(const RegionMap& map, const PositionerConfig& config, Calibration* calibration);
  // Builds the rungs (once, at the positioner's construction) and sizes every buffer.
  void build(double count_m, const ChunkLimits& chunk_limits);

  // At a move's start (or a hold's correction): the estimates from the calibration (or the
  // seeds without one), the pending judgements and this move's misses forgotten.
  void start_move();

  // The next chunk toward the target `error_m` (target - position, not within the window) from
  // position_m, landing within +/- landing_m. may_correct: a back-off (a correction round) is
  // still allowed. `moves` (the positioner's move count) times the dead rungs' rest.
  Choice next_chunk(double error_m, double position_m, double landing_m, bool may_correct,
                    std::uint64_t moves);

  // After a closed-loop chunk of rung `rung` toward `direction` with `cycles` cycles, predicted
  // to move predicted_along_m along it, moved moved_m (signed): judges the rung and learns from
  // the chunk. in_stall_run: the chunks just before did not move either.
  Judgement judge(int direction, int rung, std::uint64_t cycles, double predicted_along_m,
                  double moved_m, bool in_stall_run, std::uint64_t moves);
  // A stall was declared: the rungs left out during its run are not to blame.
  void revive_streak();

  std::size_t size(int direction) const { return ladder_[index(direction)].size(); }
  const Rung& at(int direction, std::size_t i) const { return ladder_[index(direction)].at(i); }
  // Leaves rung i out for dead_rung_moves moves.
  void kill(int direction, std::size_t i, std::uint64_t moves);
  // Whether a window of +/- landing_m can be met by the live rungs of both ways in `tries` landing
  // tries (landing_plan.h, landing_reach): 0 when it can, else the narrowest half window that
  // can. A rung's scatter is its own once three chunks showed it, else the least any rung has
  // shown (none yet: 0, the benefit of the doubt).
  double unreachable_landing_m(double landing_m, int tries, std::uint64_t moves);
  // The standard deviation of the mean of the latched readings at rest, as the positioner measures
  // it (0 until it has): where the reading's noise is larger than a count (a fine interferometer)
  // it, not the count, is what a landing is read to.
  void set_reading_sd_m(double sd_m) { reading_sd_m_ = sd_m; }
  // The learned step of the finest live rung toward `direction` (0: none).
  double finest_live_step_m(int direction) const;
  // What the rungs learned over what the map seeded them with (1 until one has learned).
  double gain() const { return gain_; }

 private:
  static int index(int sign) { return sign > 0 ? 1 : 0; }
  // A final chunk of rung r for the remaining distance: the cycles that land nearest, cut so that
  // the pessimistic landing passes by at most 0.8 step (`cut`), never below the cycles predicted
  // to move half a step; `safe`: the result keeps to that.
  struct FinalChunk {
    std::uint64_t cycles = 1;
    bool cut = false, safe = false;
  };
  FinalChunk final_chunk_for(const Rung& r, double distance) const;
  // What the landing plan (and the window's reach) see of rung r, with the scatter rel_sd.
  LandingRung landing_rung(const Rung& r, double rel_sd) const;
  // The fewest cycles rung r is predicted to move at least half a step with.
  std::uint64_t moving_cycles(const Rung& r) const;
  // How far this rung's next chunk may move beyond its estimate, as a share of it.
  double rung_uncertainty(const Rung& r) const;
  bool live(Rung& r, std::uint64_t moves);  // revives a rung whose dead time is over
  // A rung never learned: its seed times gain_ (offset, step; covariance by its square).
  RungEstimate scaled_seed(const Rung& r) const;
  void update_gain();
  void kill(Rung& r, std::uint64_t moves);
  bool moves_enough(const Rung& r) const;  // its learned step is at least min_step_counts
  int final_rung(std::vector<Rung>& ladder, std::uint64_t moves);
  int approach_rung(const std::vector<Rung>& ladder, double distance, double keep,
                    std::uint64_t& cycles) const;
  int final_try(const std::vector<Rung>& ladder, int fin, double distance, std::uint64_t& cycles,
                bool& capped) const;
  int nearest_landing(const std::vector<Rung>& ladder, double distance,
                      std::uint64_t& cycles) const;
  // A chunk away from the target (toward -sign) to a distance a rung toward it lands from within
  // the window; false when no rung that way can (or none plays the way back).
  bool back_off(int sign, std::vector<Rung>& toward, double distance, double landing_m,
                std::uint64_t moves, Choice& out);
  // The landing plan over the proven live rungs of both ways, against the final chunk (chosen,
  // cycles) planned the usual way: true with `out` set when a plan is expected to land sooner.
  bool landing_plan(int sign, double error, double position_m, double landing_m, int chosen,
                    std::uint64_t cycles, std::uint64_t moves, Choice& out);
  // What a reading at rest is known to: the larger of a count's quantization and the noise of the
  // mean of the latched words (set_reading_sd_m; noise that large dithers the quantization away,
  // so the two do not add). On the common interferometers with 1-3 nm noise the count's.
  double read_sd_m() const { return std::max(count_m_ / std::sqrt(12.0), reading_sd_m_); }
  // The most cycles one chunk of rung r may play (the device and max_chunk_s).
  std::uint64_t chunk_limit(const Rung& r) const;
  void learn(Rung& r, int sign, std::uint64_t cycles, double along, double predicted,
             double moved_m, std::uint64_t moves);

  const RegionMap& map_;
  const PositionerConfig& config_;
  Calibration* calibration_;
  double count_m_ = 0;
  // The least displacement two readings at rest tell apart: a count, or where the noise of the
  // latched mean is larger (a fine interferometer), the difference of two such means (sqrt 2 of
  // its standard deviation). What a chunk's judgement and learning measure their thresholds in.
  double resolution_m() const { return std::max(count_m_, std::sqrt(2.0) * reading_sd_m_); }
  double reading_sd_m_ = 0;
  ChunkLimits chunk_limits_;
  CalibrationConfig rls_;        // the calibration's (or the default) RLS settings
  std::vector<Rung> ladder_[2];  // [0] negative, [1] positive
  // Learned step over seeded step of the learned rungs (1 until one has learned): scales the
  // seeds of the rungs not yet played (a stage that moves three times the map's step moves its
  // fine rungs three times too, and they are then the ones that land).
  double gain_ = 1.0;
  // The landing plan's view of the live rungs (capacity reserved in build()) and, for each, its
  // (direction, index).
  std::vector<LandingRung> landing_rungs_;
  std::vector<std::pair<int, int>> landing_index_;
  // The landing chunk the plan chose last in this move (rung -1: none): when the final zone
  // plans again, it missed.
  struct LandingTry {
    int direction = 0, rung = -1;
    std::uint64_t cycles = 0;
  } landing_try_;
};

}  // namespace idm::control
