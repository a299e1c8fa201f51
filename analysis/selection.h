// The whole diagnosis of a sweep: where model and stage part, which set of effects explains it,
// how sure the fit is, and what is left unexplained.
//
// 1. Baseline: the impulse model with alpha and mu fitted (gap.h); its held-out gap is gap_before.
// 2. Candidates: every identifiable effect fitted alone (candidates.h), ranked by shrink.
// 3. Forward: the best plausible candidate starts the set, the runner-up a second within
//    kRunnerUpRatio, an alike partner of a start a third when the others leave too much to name
//    (a set that ends as one effect below kMinShrink is no result); every other candidate is
//    then fitted on top of the set (its own search with a set of one profiled, larger sets held,
//    then all jointly, screened at the search rate; a pair also the other way round, from the
//    newcomer's single when it shrinks the gap by kSwapShrink), and the best is added while the
//    set's gap is above kFurtherGap and the addition shrinks the part above the noise,
//    sqrt(gap^2 - 1), by kMinFurtherShrink (by kIntoNoiseShrink where it turns a significant
//    remainder into one within the noise). A baseline whose gap is within the noise starts a search
//    only when the best single takes kWeakExcessShrink of its part above the noise away (a weak
//    gap, above kWeakGap).
// 4. Backward: every member of a set of two or more is taken out and the rest refitted jointly,
//    from the set's parameters as well as from the forward fit of the smaller set (the better
//    counts); a member without which the gap grows by less than kBackwardTolerance goes (unless
//    without it a remainder within the noise becomes significant, or the forward rule would add
//    it again: the same test both ways).
// 5. Honesty: a set that leaves a significant remainder is named only when it explains most of the
//    gap (shrink >= kNameShrink); otherwise nothing is named and the gap is reported unexplained,
//    with the closest library effect. The remainder is significant when the held-out gap is above
//    kExplainedGap and its systematic part (what the training and the held-out residuals share,
//    systematic_gap) is above kSystematicGap: noise is not shared between trials.
// 6. Uncertainty: intervals for every fitted parameter (uncertainty.h); sets whose held-out gap is
//    within kAmbiguousRatio of the chosen one are ambiguous, with the sweep that would separate
//    them.
#pragma once

#include <string>
#include <vector>

#include "analysis/candidates.h"
#include "analysis/uncertainty.h"
#include "analysis/where.h"

namespace idm::analysis {

constexpr double kExplainedGap = 2.0;
constexpr double kSystematicGap = 1.5;
constexpr double kMinShrink = 0.3;
// A gap within the noise (not significant) but above kWeakGap is searched when the best single
// takes kWeakExcessShrink of its part above the noise, sqrt(gap^2 - 1), away on held-out trials.
constexpr double kWeakGap = 1.25;
constexpr double kWeakExcessShrink = 0.5;
constexpr double kMinFurtherShrink = 0.4;
constexpr double kIntoNoiseShrink = 0.2;   // the same where the remainder ends within the noise
constexpr std::size_t kFinishedLeads = 2;  // screened sets finished a step, best first
// A screened set is finished only when its screen takes this share of the excess of the set
// without its newcomer (screened alike) away.
constexpr double kScreenShrink = 0.1;
constexpr double kSwapShrink = 0.1;     // a single that shrinks this much starts a pair's other way
constexpr double kFurtherGap = 1.5;     // a set's gap above which another effect is looked for
constexpr double kRunnerUpRatio = 1.5;  // a second start when the runner-up's gap is this close
constexpr double kBackwardTolerance = 0.25;
constexpr double kNameShrink = 0.75;
// The best screened pair of a resonance and a one-coordinate effect, within kRunnerUpRatio of the
// best screen, that takes this much of the set's screened gap away and leaves more than kAcrossGap
// is searched across (SetFits).
constexpr double kAcrossShrink = 0.5;
constexpr double kAcrossGap = 2.0;
constexpr double kAmbiguousRatio = 1.25;
constexpr std::size_t kMaxEffects = 3;

struct NotIdentifiable {
  std::string effect;
  std::string needs;
};

struct SelectionStep {
  std::string action;                // "add", "remove", "keep"
  std::vector<std::string> effects;  // the set after this step
  double gap = 0;
};

struct Unexplained {
  bool significant = false;
  double gap = 0;              // held-out gap after the named effects
  double systematic_gap = 0;   // its part shared by training and held-out trials
  std::vector<CellKey> cells;  // cells whose residual after is significant
  std::string summary;
  std::string closest;  // when nothing is named: the library set that came closest, and its shrink
};

struct Ambiguity {
  std::vector<std::string>
      effects;  // the chosen set and the alternative, e.g. [amplifier, actuator_compliance]
  std::vector<std::string> chosen, alternative;
  double gap_chosen = 0, gap_alternative = 0;
  std::string why;
  std::string next_sweep;
};

struct Diagnosis {
  FittedModel baseline;                                    // impulse model, alpha and mu fitted
  std::vector<SetFit> candidates;                          // each effect alone, ranked by shrink
  std::vector<std::vector<ParameterIntervals>> intervals;  // per candidate (same order)
  std::vector<NotIdentifiable> not_identifiable;
  std::vector<SelectionStep> steps;
  SetFit best;                                       // the set selection ended with (named or not)
  bool named = false;                                // best is reported as the diagnosis
  std::vector<model::EffectSpec> chosen;             // the named effects (fitted), empty when none
  std::vector<ParameterIntervals> chosen_intervals;  // of the named set (joint fit)
  FittedModel after;  // the named set's model (the baseline when none)
  double gap_before = 0, gap_after = 0, shrink = 0;
  Unexplained unexplained;
  std::vector<Ambiguity> ambiguous;
  WhereReport where;
};

struct DiagnoseOptions {
  FitOptions fit;
  std::vector<std::string> effects;  // candidates to try; empty: the whole library
};

Diagnosis diagnose(const SweepCells& sweep, const DiagnoseOptions& options = {});

// Whether a model's held-out gap is beyond what the measurement's noise allows.
bool significant_gap(const FittedModel& model);

// Whether `with`, a set and one effect more, turns the significant remainder of `without` into
// one within the noise and shrinks its part above the noise, sqrt(gap^2 - 1), by kIntoNoiseShrink
// on the way (an effect on the trials' spread alone shows in few numbers and rarely shrinks the
// whole gap by kMinFurtherShrink, but without it a remainder is unexplained).
bool into_noise(const SetFit& with, const SetFit& without);

// Whether a screened set with a newcomer is worth finishing (polished and scored): its screen
// (training trials, the search rate, the cells of a coarse search) takes kScreenShrink of the part
// above the noise of the set without the newcomer, screened alike, away. A newcomer that cannot do
// that on the trials it was fitted to will not take kIntoNoiseShrink of it away on held-out ones.
bool worth_finishing(double screened_with, double screened_without);

// Whether the effect that `with` has and `without` lacks earns its place: `without` leaves more
// than kFurtherGap and the effect takes kMinFurtherShrink of its part above the noise away. The
// same rule adds an effect forward and keeps it backward (a remainder of 1.6-2 is within the noise
// by kExplainedGap, yet an effect that takes most of it away on held-out trials is seen there).
bool earns_place(const SetFit& with, const SetFit& without);

// Whether `fit` takes kWeakExcessShrink of the part above the noise of a baseline's gap that is
// not significant but above kWeakGap: an effect on the trials' spread alone (a friction spread on
// 4-5 trials a cell, 2 of them held out) shows in few numbers of an RMS over every cell, yet a
// library effect that takes most of that part away on held-out trials has found something.
bool explains_weak_gap(const SetFit& fit, const FittedModel& baseline);

// A short text summary (a few lines) for a person.
std::string text_summary(const SweepCells& sweep, const Diagnosis& d);
// The trials left out because their files could not be used (SweepCells::damaged), a line each
// (at most 8, then how many more); "" when none was (report_text.cpp).
std::string left_out_summary(const SweepCells& sweep);

}  // namespace idm::analysis
