// The step ladder's landing plan (control/README.md, "The step ladder", step 4): the proven live
// rungs of both directions handed to plan_landing (landing_plan.h), weighed against the usual
// final chunk. Part of class StepLadder (step_ladder.h).
#include <cmath>

#include "control/step_ladder.h"

namespace idm::control {

LandingRung StepLadder::landing_rung(const Rung& r, double rel_sd) const {
  LandingRung l;
  l.direction = r.direction;
  l.offset_m = r.est.offset_m;
  l.step_m = r.est.step_m;
  l.rel_sd = rel_sd;
  l.rel_margin = rung_uncertainty(r);
  l.p_oo = r.est.p_oo;
  l.p_os = r.est.p_os;
  l.p_ss = r.est.p_ss;
  l.max_cycles = map_.cells()[r.cell].max_cycles;
  l.missed_cycles = r.missed_cycles;
  l.freq_hz = map_.cells()[r.cell].freq_hz;
  return l;
}

bool StepLadder::landing_plan(int sign, double error, double position_m, double landing_m,
                              int chosen, std::uint64_t cycles, std::uint64_t moves, Choice& out) {
  if (landing_try_.rung >= 0) {
    // Planning again in the final zone: the landing chunk chosen last did not land.
    ladder_[index(landing_try_.direction)]
        .at(static_cast<std::size_t>(landing_try_.rung))
        .missed_cycles = landing_try_.cycles;
    landing_try_ = LandingTry{};
  }
  landing_rungs_.clear();
  landing_index_.clear();
  int current = -1;
  for (int dir : {-1, 1}) {
    std::vector<Rung>& ladder = ladder_[index(dir)];
    for (std::size_t i = 0; i < ladder.size(); ++i) {
      Rung& r = ladder[i];
      const bool is_current = dir == sign && static_cast<int>(i) == chosen;
      // The rungs known to move (and the usual chunk's): a rung not yet learned is known to no
      // better than half its step, and leaving it out keeps the search short (the loop's tick).
      if (!(is_current || r.proven) || !live(r, moves) ||
          landing_rungs_.size() == landing_rungs_.capacity())
        continue;
      if (is_current) current = static_cast<int>(landing_rungs_.size());
      landing_rungs_.push_back(
          landing_rung(r, r.scatter_chunks >= 3 ? std::sqrt(r.scatter_var) : 0.5));
      landing_index_.emplace_back(dir, static_cast<int>(i));
    }
  }
  LandingLimits lim;
  lim.half_window_m = landing_m;
  lim.read_sd_m = read_sd_m();
  lim.chunk_overhead_s = config_.chunk_overhead_s;
  lim.room_m[0] = position_m - config_.soft_lower_m;
  lim.room_m[1] = config_.soft_upper_m - position_m;
  const LandingPlan plan = plan_landing(error, lim, landing_rungs_.data(), landing_rungs_.size());
  if (!(plan.probability > 0)) return false;
  if (current >= 0) {
    // The usual final chunk, scored the same way.
    const LandingPlan usual =
        score_chunk(error, lim, landing_rungs_.data(), static_cast<std::size_t>(current), cycles);
    if (usual.probability > 0 && !(plan.expected_s() < usual.expected_s())) return false;
  }
  const auto [dir, i] = landing_index_[static_cast<std::size_t>(plan.first.rung)];
  if (!plan.two_chunks()) landing_try_ = {dir, i, plan.first.cycles};
  out.direction = dir;
  out.rung = i;
  out.cycles = plan.first.cycles;
  out.final_chunk = !plan.two_chunks();
  out.vernier = plan.two_chunks();
  out.capped = false;
  return true;
}

double StepLadder::unreachable_landing_m(double landing_m, int tries, std::uint64_t moves) {
  double least_var = -1;
  for (const std::vector<Rung>& l : ladder_)
    for (const Rung& r : l)
      if (r.scatter_chunks >= 3 && (least_var < 0 || r.scatter_var < least_var))
        least_var = r.scatter_var;
  const double least_rel_sd = least_var > 0 ? std::sqrt(least_var) : 0.0;
  landing_rungs_.clear();
  for (std::vector<Rung>& l : ladder_)
    for (Rung& r : l) {
      if (!live(r, moves) || !moves_enough(r)) continue;
      landing_rungs_.push_back(
          landing_rung(r, r.scatter_chunks >= 3 ? std::sqrt(r.scatter_var) : least_rel_sd));
    }
  const double read_sd = read_sd_m();
  const LandingLimits lim;
  if (landing_reach(landing_rungs_.data(), landing_rungs_.size(), landing_m, read_sd,
                    lim.max_first_cycles, tries)
          .reachable())
    return 0;
  return least_half_window_m(landing_rungs_.data(), landing_rungs_.size(), read_sd,
                             lim.max_first_cycles, tries);
}

}  // namespace idm::control
