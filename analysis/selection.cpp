#include "analysis/selection.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <sstream>

#include "analysis/parallel.h"
#include "model/yaml_util.h"

namespace idm::analysis {

namespace {

bool wanted(const DiagnoseOptions& o, const std::string& effect) {
  return o.effects.empty() ||
         std::find(o.effects.begin(), o.effects.end(), effect) != o.effects.end();
}

bool contains(const SetFit& s, const std::string& effect) {
  const std::vector<std::string> n = s.names();
  return std::find(n.begin(), n.end(), effect) != n.end();
}

std::string joined(const std::vector<std::string>& names, const char* sep = " + ") {
  std::string out;
  for (const std::string& n : names) out += (out.empty() ? "" : sep) + n;
  return out.empty() ? "nothing" : out;
}

std::string key_of(const std::vector<MemberFit>& members) {
  std::vector<std::string> n;
  n.reserve(members.size());
  for (const MemberFit& m : members) n.push_back(m.effect);
  std::sort(n.begin(), n.end());
  std::string k;
  for (const std::string& s : n) k += s + "+";
  return k;
}

// Every set fitted in one diagnosis, by the names of its effects: screened (the search at the
// cheaper rate, to rank sets) and finished (polished and scored on held-out trials). The single
// fits are finished sets already.
class SetFits {
 public:
  SetFits(const SweepCells& sweep, const std::vector<CandidateSpec>& library,
          const FittedModel& baseline, const FitOptions& options,
          const std::vector<SetFit>& singles)
      : sweep_(sweep), library_(library), baseline_(baseline), options_(options) {
    for (const SetFit& s : singles) finished_[key_of(s.members)] = s;
  }

  // A line for --explain (FitOptions::explain): `line()` is built only when one is asked for.
  template <class Line>
  void tell(Line&& line) const {
    if (options_.explain) options_.explain(std::string(line()));
  }

  // Screens every set not screened yet (spread over the threads), and returns them all.
  std::vector<SetFit> screen(const std::vector<std::vector<MemberFit>>& sets) {
    const SweepCells coarse = spread_subset(sweep_, kCoarseCells);
    return screen_each(sets, [&](std::size_t i, const FitOptions& one) {
      return fit_joint(coarse, library_, sets[i], baseline_, one, JointStage::Search);
    });
  }

  // Each effect of `specs` added to `base` (fit_on_top), screened; cached like screen(). A pair
  // is searched both ways: the newcomer on top of the set's single, and the set's effect on top
  // of the newcomer's single (each single fit can have absorbed the other's signature and sit in
  // a basin the joint search does not leave); the lower training gap counts. A newcomer whose
  // single fit shrinks the gap by less than kSwapShrink is all but absent from it: the set's
  // effect on top of it would repeat the set's own single fit (unless the set's single is weak
  // too, weak_single, and the newcomer's single did not end on a bound of its range: fitted to
  // nothing, a rigid actuator, where a compliant plant costs the most to simulate).
  std::vector<SetFit> screen_on_top(const std::vector<MemberFit>& base,
                                    const std::vector<const CandidateSpec*>& specs) {
    std::vector<std::vector<MemberFit>> sets, swapped;
    for (const CandidateSpec* spec : specs) {
      std::vector<MemberFit> m = base;
      m.push_back({spec->effect, {}, {}, {}});
      sets.push_back(m);
      const auto single = finished_.find(key_of({m.back()}));
      const bool informative =
          single != finished_.end() &&
          (single->second.shrink >= kSwapShrink || (weak_single(base) && !single->second.on_bound));
      swapped.push_back(base.size() == 1 && informative ? single->second.members
                                                        : std::vector<MemberFit>{});
    }
    std::vector<SetFit> screened = screen_each(sets, [&](std::size_t i, const FitOptions& one) {
      SetFit f = fit_on_top(sweep_, library_, base, *specs[i], baseline_, one);
      if (swapped[i].empty()) return f;
      FitOptions again = one;
      again.scan_across = false;  // the pair's scan across was searched by f
      SetFit g = fit_on_top(sweep_, library_, swapped[i], spec_of(library_, base[0].effect),
                            baseline_, again);
      if (!(g.train_gap < f.train_gap)) return f;
      std::rotate(g.members.begin(), g.members.begin() + 1, g.members.end());  // the set first
      g.effects = effects_of(library_, g.members);
      g.evaluations += f.evaluations;
      return g;
    });
    search_best_across(base, screened);
    return screened;
  }

  // A screened pair searched again across the grid of its one-coordinate member (fits_across)
  // when it is a resonance beside such an effect, the screen says the resonance is there (the
  // pair takes kAcrossShrink of the set's gap away) but not where (it leaves more than
  // kAcrossGap), and it is the best such pair and within kRunnerUpRatio of the best lead: the
  // scan with the set held looks only beside the set's own fit, which may have absorbed part of
  // the resonance (a tilt of 10.8 degrees fitted alone at 12.2 with alpha 0.86 beside a 2.4 kHz
  // resonance; scanned there, the resonance ended at 70 times the true stiffness and the pair
  // left 28 of 343). Near the lead only: beside an amplifier that the resonance stands in for,
  // the amplifier's pair leads by far and nothing is searched again.
  void search_best_across(const std::vector<MemberFit>& base, std::vector<SetFit>& screened) {
    if (base.size() != 1 || screened.empty()) return;
    double lead_gap = std::numeric_limits<double>::infinity();
    for (const SetFit& f : screened) lead_gap = std::min(lead_gap, f.train_gap);
    const double set_gap = screened_gap(base);
    SetFit* pick = nullptr;
    const CandidateSpec* pick_spec = nullptr;
    std::string pick_key;
    for (SetFit& f : screened) {
      const std::string k = key_of(f.members);
      if (f.members.size() != 2 || finished_.count(k) || across_.count(k)) continue;
      // the newcomer: a pair screened from another start first keeps that start's order
      const MemberFit& newcomer =
          f.members[0].effect == base[0].effect ? f.members[1] : f.members[0];
      const CandidateSpec& spec = spec_of(library_, newcomer.effect);
      if (!searched_across(library_, base, spec, true) ||
          searched_across(library_, base, spec, false))
        continue;
      if (!(f.train_gap > kAcrossGap && f.train_gap < (1 - kAcrossShrink) * set_gap &&
            f.train_gap <= kRunnerUpRatio * lead_gap))
        continue;
      if (!pick || f.train_gap < pick->train_gap) {
        pick = &f;
        pick_spec = &spec;
        pick_key = k;
      }
    }
    if (!pick) return;
    across_.insert(pick_key);  // once a pair, whichever start asks
    FitOptions across = options_;
    across.resonance_across = true;
    SetFit f = fit_on_top(sweep_, library_, base, *pick_spec, baseline_, across);
    if (!(f.train_gap < pick->train_gap)) return;
    f.evaluations += pick->evaluations;
    screened_[pick_key] = f;
    *pick = std::move(f);
  }

  // A set of one whose single fit shrinks the gap by less than kMinShrink: the effects of a pair
  // can each hide the other's signature, and every newcomer is searched both ways then.
  bool weak_single(const std::vector<MemberFit>& base) const {
    const auto single = finished_.find(key_of(base));
    return base.size() == 1 && single != finished_.end() && single->second.shrink < kMinShrink;
  }

  // A set's training gap as the screens measure it (screening_gap), cached.
  double screened_gap(const std::vector<MemberFit>& members) {
    const std::string k = start_of(members);
    if (!screening_gaps_.count(k))
      screening_gaps_[k] = screening_gap(sweep_, library_, members, baseline_, options_.threads);
    return screening_gaps_.at(k);
  }

  // The finished fit of a set (from its screened optimum when there is one).
  const SetFit& finish(const std::vector<MemberFit>& members) {
    const std::string k = key_of(members);
    if (!finished_.count(k)) {
      const bool screened = screened_.count(k) > 0;
      finished_[k] =
          fit_joint(sweep_, library_, screened ? screened_.at(k).members : members, baseline_,
                    options_, screened ? JointStage::Finish : JointStage::Full);
    }
    return finished_.at(k);
  }

  // The finished fit of `members`, the set `current` with a newcomer last. The set with the
  // newcomer holds the set without it (at the newcomer's zero), so a finished fit that trains
  // worse than `current` has not converged: it is refitted from current's parameters and the
  // newcomer's screened ones (refit), the better kept.
  const SetFit& finish_nested(const std::vector<MemberFit>& members, const SetFit& current) {
    const SetFit& f = finish(members);
    if (f.plausible && f.fitted.train.gap <= current.fitted.train.gap) return f;
    std::vector<MemberFit> start = current.members;
    start.push_back(members.back());
    return refit(start);
  }

  // The set of `members` refitted from the parameters they carry (those of a larger set that held
  // them): a set fitted earlier from its own singles can sit in a local optimum that the larger
  // set's fit left behind. The better of that and the finished fit on the training trials, as
  // scored (train_gap is the search's objective, at the mu each search held), becomes the set's
  // fit. A set is refitted from the same parameters once (two starts of a search can ask again).
  const SetFit& refit(const std::vector<MemberFit>& members) {
    const std::string k = key_of(members);
    const SetFit& known = finish(members);
    if (!refitted_.insert(start_of(members)).second) return known;
    SetFit again = fit_joint(sweep_, library_, members, baseline_, options_, JointStage::Finish);
    if (again.plausible && (!known.plausible || again.fitted.train.gap < known.fitted.train.gap))
      finished_[k] = std::move(again);
    return finished_.at(k);
  }

 private:
  // The sets not screened or finished yet fitted by fit(i, options) (one thread each, spread
  // over the threads), cached; every set's fit returned, the finished one where there is one.
  template <class Fit>
  std::vector<SetFit> screen_each(const std::vector<std::vector<MemberFit>>& sets, Fit&& fit) {
    std::vector<std::size_t> todo;
    for (std::size_t i = 0; i < sets.size(); ++i)
      if (!screened_.count(key_of(sets[i])) && !finished_.count(key_of(sets[i]))) todo.push_back(i);
    std::vector<SetFit> done(todo.size());
    FitOptions one = options_;
    one.threads = 1;
    parallel_for(todo.size(), options_.threads,
                 [&](std::size_t i) { done[i] = fit(todo[i], one); });
    for (SetFit& f : done) screened_[key_of(f.members)] = std::move(f);
    std::vector<SetFit> out;
    for (const auto& m : sets) {
      const std::string k = key_of(m);
      out.push_back(finished_.count(k) ? finished_.at(k) : screened_.at(k));
    }
    return out;
  }

  // A set's members with the parameters they carry, as text (what refit starts from).
  static std::string start_of(const std::vector<MemberFit>& members) {
    std::ostringstream s;
    s.precision(17);
    s << key_of(members);
    for (const MemberFit& m : members) {
      s << '|' << m.effect;
      for (const auto* params : {&m.fixed, &m.grid_point})
        for (const auto& [name, v] : *params) s << ' ' << name << '=' << v;
      for (double u : m.u) s << ' ' << u;
    }
    return s.str();
  }

  const SweepCells& sweep_;
  const std::vector<CandidateSpec>& library_;
  const FittedModel& baseline_;
  FitOptions options_;
  std::map<std::string, SetFit> screened_, finished_;
  std::set<std::string> refitted_, across_;
  std::map<std::string, double> screening_gaps_;
};

std::vector<MemberFit> without(const SetFit& s, std::size_t index) {
  std::vector<MemberFit> m = s.members;
  m.erase(m.begin() + static_cast<std::ptrdiff_t>(index));
  return m;
}

// Two effects that act alike: a low-pass amplifier and a damped actuator resonance both round
// the velocity corners of the triangle, and below the resonance they look alike.
bool alike(const std::string& a, const std::string& b) {
  return (a == "amplifier" && b == "actuator_compliance") ||
         (b == "amplifier" && a == "actuator_compliance");
}

bool any_alike(const std::vector<std::string>& a, const std::vector<std::string>& b) {
  for (const std::string& x : a)
    for (const std::string& y : b)
      if (alike(x, y)) return true;
  return false;
}

// What the physics says about a pair that explains a sweep equally well.
std::string why_alike(const std::vector<std::string>& a, const std::vector<std::string>& b,
                      double ga, double gb) {
  std::string s;
  if (any_alike(a, b))
    s = "a low-pass amplifier and a damped actuator resonance both round the velocity corners of "
        "the triangle; "
        "below the resonance they look alike. ";
  char buf[200];
  std::snprintf(buf, sizeof buf, "%s leaves a held-out gap of %.3g %s, %s %.3g %s.",
                joined(a).c_str(), ga, kGapUnit, joined(b).c_str(), gb, kGapUnit);
  return s + buf;
}

// The remainder after a model, in words: where, and whether the stage steps further or less far.
std::string remainder_summary(const SweepCells& sweep, const FittedModel& after,
                              const std::string& named) {
  int further = 0, shorter = 0, wider = 0, labels = 0;
  std::vector<double> rest;
  for (const CellResidual& r : after.test.cells) {
    rest.push_back(r.residual);
    if (!r.significant) continue;
    if (std::fabs(r.mean_z) >= 2)
      (std::fabs(r.measured_step_m) > std::fabs(r.model_step_m) ? further : shorter)++;
    if (r.spread_z >= 2) ++wider;
    if (r.label > 0) ++labels;
  }
  std::ostringstream s;
  s << "After " << named << ", a held-out gap of " << model::format_number(after.test.gap, 3) << " "
    << kGapUnit << " (systematic part " << model::format_number(systematic_gap(after), 3) << " "
    << kGapUnit << ") remains that no effect of the library explains. "
    << pattern_summary(sweep, rest, "It")
    << " In the significant cells the stage steps further than the model in " << further
    << ", less far in " << shorter << "; its trial-to-trial spread is wider than predicted in "
    << wider << "; the region label differs in " << labels << ".";
  return s.str();
}

// The part of a gap above the noise: a model that explains everything leaves about 1 (gap.h), the
// noise and a systematic part adding in squares.
double excess(double gap) {
  return std::sqrt(std::max(0.0, gap * gap - 1.0));
}

// --explain's lines of select_from's steps (SetFits::tell), each naming the rule that decided.
void explain_forward_stop(const SetFits& fits, const SetFit* best, const SetFit& current) {
  fits.tell([&] {
    return best ? "forward: stop: " + joined(best->names()) + " (held-out " +
                      model::format_number(best->gap, 3) + " against " +
                      model::format_number(current.gap, 3) +
                      ") neither earns its place (earns_place: kMinFurtherShrink of the "
                      "excess) nor brings the remainder into the noise (into_noise)"
                : "forward: stop: no plausible finished lead";
  });
}

void explain_forward_add(const SetFits& fits, const SetFit& added, const SetFit& current) {
  fits.tell([&] {
    return "forward: add: " + joined(added.names()) + ", held-out " +
           model::format_number(added.gap, 3) + " from " + model::format_number(current.gap, 3) +
           (earns_place(added, current) ? " (earns_place)" : " (into_noise)");
  });
}

void explain_forward_end(const SetFits& fits, const SetFit& current) {
  if (current.members.size() >= kMaxEffects)
    fits.tell(
        [&] { return "forward: stop: " + joined(current.names()) + " has kMaxEffects members"; });
  else if (current.gap <= kFurtherGap)
    fits.tell([&] {
      return "forward: stop: the held-out gap " + model::format_number(current.gap, 3) +
             " is at most kFurtherGap: nothing more for another effect to explain";
    });
}

// `kept`: the set stays as it is (else `best`, a member less, takes its place).
void explain_backward(const SetFits& fits, const SetFit& current, const SetFit* best, bool kept) {
  if (kept)
    fits.tell([&] {
      return "backward: keep " + joined(current.names()) + " (held-out " +
             model::format_number(current.gap, 3) + "): " +
             (best ? "without a member the best is " + joined(best->names()) + " at " +
                         model::format_number(best->gap, 3) +
                         " (grows past kBackwardTolerance while significant, or the member "
                         "earns its place, or takes the remainder out of the noise)"
                   : std::string("no plausible set without a member"));
    });
  else
    fits.tell([&] {
      return "backward: remove: " + joined(current.names()) + " -> " + joined(best->names()) +
             ", held-out " + model::format_number(current.gap, 3) + " -> " +
             model::format_number(best->gap, 3) + " (within kBackwardTolerance or the noise)";
    });
}

// Forward from `first`: every identifiable candidate (`joiners`) joins the set in a joint fit
// (screened at the search rate, the best polished and scored) while the gap is above kFurtherGap
// and the addition shrinks its excess over the noise by kMinFurtherShrink (or brings it into the
// noise, into_noise); then backward: every member taken out and the rest refitted from the set's
// own parameters (SetFits::refit); a member without which the gap grows by less than
// kBackwardTolerance (or stays within the noise) goes, unless without it the remainder leaves
// the noise (into_noise) or it earns its place by the forward rule (earns_place).
SetFit select_from(const SetFit& first, const std::vector<const SetFit*>& joiners,
                   const std::vector<CandidateSpec>& library, SetFits& fits,
                   std::vector<SelectionStep>& steps) {
  SetFit current = first;
  steps.push_back({"add", current.names(), current.gap});
  while (current.members.size() < kMaxEffects && current.gap > kFurtherGap) {
    // an effect alike a member does not join: on top of it, it fits what the member's model
    // misses (the other one is reported ambiguous instead)
    std::vector<const CandidateSpec*> tries;
    for (const SetFit* c : joiners) {
      const std::string& e = c->members.front().effect;
      if (!contains(current, e) && !any_alike(current.names(), {e}))
        tries.push_back(&spec_of(library, e));
    }
    if (tries.empty()) break;
    const std::vector<SetFit> screened = fits.screen_on_top(current.members, tries);
    std::vector<const SetFit*> leads;
    leads.reserve(screened.size());
    for (const SetFit& t : screened) leads.push_back(&t);
    std::stable_sort(leads.begin(), leads.end(),
                     [](const SetFit* a, const SetFit* b) { return a->train_gap < b->train_gap; });
    // the best screened sets finished; the best of them that is plausible (a joiner may end on
    // a bound). Into the noise is the weaker test: it holds only when no finished lead, plausible
    // or not, fits the training trials better (else the effect that does is on a bound of its
    // range, and another one merely stands in for it). A lead not worth_finishing is skipped: a
    // joint fit of three effects with a friction spread under a compliant actuator costs minutes.
    const double here = fits.screened_gap(current.members);
    const SetFit* best = nullptr;
    double best_train = std::numeric_limits<double>::infinity();
    for (std::size_t k = 0; k < leads.size() && k < kFinishedLeads; ++k) {
      const bool worth = worth_finishing(leads[k]->train_gap, here);
      fits.tell([&] {
        return "forward: " + joined(leads[k]->names()) + " screened " +
               model::format_number(leads[k]->train_gap, 3) + ", the set without it " +
               model::format_number(here, 3) +
               (worth ? ": finished"
                      : ": not finished (worth_finishing: its excess over the "
                        "noise shrinks by less than kScreenShrink)");
      });
      if (!worth) continue;
      const SetFit& f = fits.finish_nested(leads[k]->members, current);
      best_train = std::min(best_train, f.fitted.train.gap);
      if (f.plausible && (!best || f.gap < best->gap)) best = &f;
    }
    if (!best || (!earns_place(*best, current) &&
                  !(into_noise(*best, current) && best->fitted.train.gap <= best_train))) {
      explain_forward_stop(fits, best, current);
      break;
    }
    explain_forward_add(fits, *best, current);
    current = *best;
    steps.push_back({"add", current.names(), current.gap});
  }
  explain_forward_end(fits, current);
  while (current.members.size() >= 2) {
    const SetFit* best = nullptr;
    std::vector<SetFit> reduced;
    for (std::size_t i = 0; i < current.members.size(); ++i)
      reduced.push_back(fits.refit(without(current, i)));
    for (const SetFit& r : reduced)
      if (r.plausible && (!best || r.gap < best->gap)) best = &r;
    if (!best ||
        (best->gap > (1 + kBackwardTolerance) * current.gap && significant_gap(best->fitted)) ||
        into_noise(current, *best) || earns_place(current, *best)) {
      explain_backward(fits, current, best, true);
      steps.push_back({"keep", current.names(), current.gap});
      break;
    }
    explain_backward(fits, current, best, false);
    current = *best;
    steps.push_back({"remove", current.names(), current.gap});
  }
  return current;
}

}  // namespace

bool significant_gap(const FittedModel& m) {
  return m.test.gap > kExplainedGap && systematic_gap(m) > kSystematicGap;
}

bool into_noise(const SetFit& with, const SetFit& without) {
  return excess(with.gap) <= (1 - kIntoNoiseShrink) * excess(without.gap) &&
         significant_gap(without.fitted) && !significant_gap(with.fitted);
}

bool worth_finishing(double screened_with, double screened_without) {
  return !(excess(screened_without) > 0 &&
           excess(screened_with) > (1 - kScreenShrink) * excess(screened_without));
}

bool earns_place(const SetFit& with, const SetFit& without) {
  return without.gap > kFurtherGap &&
         excess(with.gap) <= (1 - kMinFurtherShrink) * excess(without.gap);
}

bool explains_weak_gap(const SetFit& fit, const FittedModel& baseline) {
  return !significant_gap(baseline) && baseline.test.gap > kWeakGap &&
         excess(fit.gap) <= (1 - kWeakExcessShrink) * excess(baseline.test.gap);
}

namespace {

// The library's wanted candidates that the sweep can identify; the others go to
// d.not_identifiable with what the sweep lacks.
std::vector<const CandidateSpec*> identifiable_specs(const SweepCells& sweep,
                                                     const std::vector<CandidateSpec>& library,
                                                     const DiagnoseOptions& options, Diagnosis& d) {
  std::vector<const CandidateSpec*> specs;
  for (const CandidateSpec& spec : library) {
    if (!wanted(options, spec.effect)) continue;
    const std::string needs = missing_signature(sweep, spec.effect);
    if (!needs.empty())
      d.not_identifiable.push_back({spec.effect, needs});
    else
      specs.push_back(&spec);
  }
  return specs;
}

// Every candidate alone, one per thread, best shrink first (d.candidates); then its intervals.
void fit_candidates(const SweepCells& sweep, const std::vector<CandidateSpec>& library,
                    const std::vector<const CandidateSpec*>& specs, const FitOptions& fit,
                    int threads, Diagnosis& d) {
  FitOptions one = fit;
  one.threads = 1;
  d.candidates.resize(specs.size());
  parallel_for(specs.size(), threads, [&](std::size_t i) {
    d.candidates[i] = fit_single(sweep, library, *specs[i], d.baseline, one);
  });
  std::stable_sort(d.candidates.begin(), d.candidates.end(),
                   [](const SetFit& a, const SetFit& b) { return a.shrink > b.shrink; });
  d.intervals.resize(d.candidates.size());
  parallel_for(d.candidates.size(), threads, [&](std::size_t i) {
    // a fit on a bound of its range, or one that does not shrink the gap, has no interval to give
    if (d.candidates[i].plausible && d.candidates[i].shrink > 0)
      d.intervals[i] = parameter_intervals(sweep, library, d.candidates[i], d.baseline, 1, true);
  });
}

// Honesty: a set that leaves a significant remainder is named only when it explains most of the
// gap (kNameShrink).
bool nameable(const SetFit& set) {
  return !(significant_gap(set.fitted) && set.shrink < kNameShrink);
}

// The set search (select_from) from the best plausible candidate that shrinks the gap, and from
// the runner-up when it comes close (an amplifier and a compliant actuator trade places), and from
// a start's alike partner when those sets leave too much to name: the set that ends with the
// smaller held-out gap, its steps in d.steps; none when the baseline's gap is
// not significant (unless the best candidate explains a weak gap, explains_weak_gap). Every
// candidate in `joiners` may join. A best single below kMinShrink still starts a search (two
// effects can each explain little alone), but a set of one that ends there below kMinShrink is
// none (unless it explains a weak gap).
std::optional<SetFit> search_set(const std::vector<const SetFit*>& pool,
                                 const std::vector<const SetFit*>& joiners,
                                 const std::vector<CandidateSpec>& library, SetFits& fits,
                                 Diagnosis& d) {
  if (pool.empty() ||
      !(significant_gap(d.baseline) || explains_weak_gap(*pool.front(), d.baseline))) {
    fits.tell([&] {
      return pool.empty() ? "no set search: no plausible candidate"
                          : "no set search: the baseline's gap is not significant "
                            "(significant_gap: kExplainedGap, kSystematicGap) and the best "
                            "candidate does not explain a weak gap (explains_weak_gap)";
    });
    return std::nullopt;
  }
  std::vector<const SetFit*> firsts{pool.front()};
  if (pool.size() > 1 && pool[1]->shrink >= kMinShrink &&
      pool[1]->gap <= kRunnerUpRatio * pool.front()->gap)
    firsts.push_back(pool[1]);
  std::optional<SetFit> current;
  const auto start = [&](const SetFit* first) {
    fits.tell([&] {
      return "search from " + joined(first->names()) + " (held-out " +
             model::format_number(first->gap, 3) + ")";
    });
    std::vector<SelectionStep> steps;
    const SetFit end = select_from(*first, joiners, library, fits, steps);
    fits.tell([&] {
      return "search from " + joined(first->names()) + " ends at " + joined(end.names()) +
             " (held-out " + model::format_number(end.gap, 3) + ")";
    });
    if (!current || end.gap < current->gap) {
      current = end;
      d.steps = steps;
    }
  };
  for (const SetFit* first : firsts) start(first);
  // a start's alike partner (alike: one never joins a set that holds the other) starts a search
  // of its own when the sets found leave a remainder too large to name: under a second effect
  // the one that fits best alone need not be the one in the stage
  if (!nameable(*current))
    for (const SetFit* c : pool) {
      const bool tried = std::find(firsts.begin(), firsts.end(), c) != firsts.end();
      const bool partner = std::any_of(firsts.begin(), firsts.end(), [&](const SetFit* f) {
        return any_alike(f->names(), c->names());
      });
      if (!tried && partner && c->gap <= kRunnerUpRatio * pool.front()->gap) start(c);
    }
  if (current->members.size() == 1 && current->shrink < kMinShrink &&
      !explains_weak_gap(*current, d.baseline)) {
    fits.tell([&] {
      return "none: the set of one, " + joined(current->names()) + ", shrinks the gap by " +
             model::format_number(current->shrink, 3) + " < kMinShrink";
    });
    d.steps.clear();
    return std::nullopt;
  }
  return current;
}

// What is left after d.after: its gap, the significant cells and a summary; `searched`: a set
// search ran (d.best is its result, named or not).
void describe_unexplained(const SweepCells& sweep, bool searched, Diagnosis& d) {
  Unexplained& u = d.unexplained;
  u.gap = d.gap_after;
  u.systematic_gap = systematic_gap(d.after);
  u.significant = significant_gap(d.after);
  for (const CellResidual& r : d.after.test.cells)
    if (r.significant) u.cells.push_back(r.key);
  const std::string named = d.named ? joined(d.best.names()) : "the impulse model alone";
  if (u.significant) {
    u.summary = remainder_summary(sweep, d.after, named);
    if (!d.named) u.summary += " " + d.where.summary_departure;
    if (searched && !d.named)
      u.closest =
          "the closest library set, " + joined(d.best.names()) + ", shrinks the gap by only " +
          model::format_number(std::round(1000 * d.best.shrink) / 10) + " % and is not named";
    else if (!searched && !d.candidates.empty())
      u.closest = "the closest library effect, " + d.candidates.front().effects.front().name +
                  ", shrinks the gap by " +
                  model::format_number(std::round(1000 * d.candidates.front().shrink) / 10) + " %";
  } else {
    u.summary = "After " + named + " the held-out gap is " + model::format_number(u.gap, 3) + " " +
                kGapUnit + ", within what the measurement's noise allows (systematic part " +
                model::format_number(u.systematic_gap, 3) + " " + kGapUnit + ").";
  }
}

// The sets that might rival the named one: with one member, every other plausible candidate;
// else each member replaced by one of the two best candidates outside the set, screened, and the
// ones whose training gap comes near the chosen set's finished.
std::vector<SetFit> rival_sets(const Diagnosis& d, const std::vector<const SetFit*>& pool,
                               SetFits& fits) {
  std::vector<SetFit> alt;
  if (d.best.members.size() == 1) {
    for (const SetFit& c : d.candidates)
      if (c.plausible && !contains(d.best, c.members.front().effect)) alt.push_back(c);
    return alt;
  }
  std::vector<const SetFit*> rivals;
  for (const SetFit* c : pool)
    if (rivals.size() < 2 && !contains(d.best, c->members.front().effect)) rivals.push_back(c);
  std::vector<std::vector<MemberFit>> alternatives;
  for (std::size_t i = 0; i < d.best.members.size(); ++i)
    for (const SetFit* c : rivals) {
      std::vector<MemberFit> m = without(d.best, i);
      m.push_back(c->members.front());
      alternatives.push_back(m);
    }
  for (const SetFit& a : fits.screen(alternatives))
    if (a.train_gap <= kAmbiguousRatio * d.best.train_gap + 1.0)
      alt.push_back(fits.finish(a.members));
  return alt;
}

// The named set's rivals that explain the data about equally well (d.ambiguous), each with the
// sweep that would tell them apart.
void find_ambiguities(const SweepCells& sweep, const std::vector<const SetFit*>& pool,
                      SetFits& fits, int threads, Diagnosis& d) {
  for (const SetFit& a : rival_sets(d, pool, fits)) {
    if (!a.plausible) continue;
    const double ratio = d.best.gap > 0 ? a.gap / d.best.gap : 1.0;
    const bool both_within = a.gap <= kExplainedGap && d.best.gap <= kExplainedGap;
    if (!(ratio <= kAmbiguousRatio || both_within)) continue;
    Ambiguity am;
    am.chosen = d.best.names();
    am.alternative = a.names();
    am.effects = am.chosen;
    for (const std::string& n : am.alternative)
      if (std::find(am.effects.begin(), am.effects.end(), n) == am.effects.end())
        am.effects.push_back(n);
    am.gap_chosen = d.best.gap;
    am.gap_alternative = a.gap;
    am.why = why_alike(am.chosen, am.alternative, am.gap_chosen, am.gap_alternative);
    am.next_sweep = separating_sweep(sweep, d.best, a, threads);
    d.ambiguous.push_back(am);
  }
}

}  // namespace

Diagnosis diagnose(const SweepCells& sweep, const DiagnoseOptions& options) {
  Diagnosis d;
  const std::vector<CandidateSpec> library = candidate_library(sweep);
  const int threads = options.fit.threads > 0 ? options.fit.threads : default_threads();
  d.baseline = fit_baseline(sweep, threads);
  d.gap_before = d.baseline.test.gap;
  fit_candidates(sweep, library, identifiable_specs(sweep, library, options, d), options.fit,
                 threads, d);

  // The set starts with the best plausible candidate that shrinks the gap; every candidate may
  // join it (an effect hidden under a larger one shrinks little alone, and alone its fit may end
  // on a bound of its range: the set's fit is judged once it is in).
  std::vector<const SetFit*> pool, joiners;
  for (const SetFit& c : d.candidates) {
    joiners.push_back(&c);
    if (c.plausible) pool.push_back(&c);
  }
  SetFits fits(sweep, library, d.baseline, options.fit, d.candidates);
  fits.tell([&] {
    return "baseline: held-out gap " + model::format_number(d.baseline.test.gap, 3) +
           ", systematic " + model::format_number(systematic_gap(d.baseline), 3) +
           (significant_gap(d.baseline) ? " (significant)" : " (not significant)");
  });
  for (const SetFit& c : d.candidates)
    fits.tell([&] {
      return "single " + joined(c.names()) + ": held-out " + model::format_number(c.gap, 3) +
             ", shrink " + model::format_number(c.shrink, 3) +
             (c.plausible ? "" : ", implausible: " + c.note);
    });
  const std::optional<SetFit> found = search_set(pool, joiners, library, fits, d);
  // honesty: a set that leaves a significant remainder must explain most of the gap
  if (found) {
    d.best = *found;
    d.named = nameable(*found);
    fits.tell([&] {
      return d.named ? "named " + joined(found->names()) + ": the remainder (held-out " +
                           model::format_number(found->gap, 3) + ") " +
                           (significant_gap(found->fitted)
                                ? "is significant but the set explains most of the gap (shrink " +
                                      model::format_number(found->shrink, 3) + " >= kNameShrink)"
                                : std::string("is within the noise"))
                     : "not named: " + joined(found->names()) +
                           " leaves a significant remainder (held-out " +
                           model::format_number(found->gap, 3) + ") and shrinks the gap by " +
                           model::format_number(found->shrink, 3) +
                           " < kNameShrink: the gap is reported unexplained";
    });
  } else {
    fits.tell([&] { return "nothing named: the gap is reported as it is"; });
  }
  if (d.named) {
    d.chosen = d.best.effects;
    d.after = d.best.fitted;
    d.chosen_intervals = parameter_intervals(sweep, library, d.best, d.baseline, threads, true);
  } else {
    d.after = d.baseline;
  }
  d.gap_after = d.after.test.gap;
  d.shrink = d.gap_before > 0 ? 1.0 - d.gap_after / d.gap_before : 0.0;
  // where: the named effects' footprint, the spread beyond the model's, what is left, the
  // departure from the stage as described
  const std::vector<CellPrediction> described = predict_sweep(sweep, nominal_model(sweep), threads);
  if (d.named) {
    ModelConfig bare = d.after.model;
    bare.effects.clear();
    const std::vector<CellPrediction> no_effects = predict_sweep(sweep, bare, threads);
    d.where = where_of(sweep, d.baseline, d.after, &no_effects, described);
  } else {
    d.where = where_of(sweep, d.baseline, d.after, nullptr, described);
  }
  describe_unexplained(sweep, found.has_value(), d);
  if (d.named) find_ambiguities(sweep, pool, fits, threads, d);
  return d;
}

}  // namespace idm::analysis
