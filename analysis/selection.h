// The whole diagnosis of a sweep: where model and stage part, which effect explains it (forward
// selection over the candidates), and how far the gap shrinks.
//
// Forward selection: nothing is named when the baseline's held-out gap is within the noise
// (<= kExplainedGap). Otherwise every identifiable candidate is fitted alone and the one that leaves
// the smallest held-out gap is chosen if it is plausible and shrinks the gap by at least
// kMinShrink; then each remaining effect that shrank the gap by kMinShrink alone is fitted on
// top of the chosen set, and the best one is
// added while it shrinks the remaining gap by at least kMinFurtherShrink and the gap is not yet
// within the noise (a second effect has to earn its place against the freedom it adds).
#pragma once

#include <string>
#include <vector>

#include "analysis/candidates.h"

namespace idm::analysis {

constexpr double kExplainedGap = 2.0;
constexpr double kMinShrink = 0.3;
constexpr double kMinFurtherShrink = 0.5;

struct NotIdentifiable {
  std::string effect;
  std::string needs;
};

struct SelectionStep {
  std::vector<std::string> effects;  // the set after this step
  double gap = 0;
};

struct Diagnosis {
  GapEvaluation baseline;                   // held-out, impulse model with fitted alpha
  std::vector<CandidateResult> candidates;  // each effect alone, ranked by shrink
  std::vector<NotIdentifiable> not_identifiable;
  std::vector<model::EffectSpec> chosen;    // the smallest set that explains the gap (fitted)
  std::vector<SelectionStep> steps;
  GapEvaluation after;                      // held-out, baseline plus the chosen set
  double gap_before = 0, gap_after = 0, shrink = 0;
  std::string where;
};

struct DiagnoseOptions {
  FitOptions fit;
  std::vector<std::string> effects;  // candidates to try; empty: the whole library
};

Diagnosis diagnose(const SweepCells& sweep, const DiagnoseOptions& options = {});

// A short text summary (a few lines) for a person.
std::string text_summary(const SweepCells& sweep, const Diagnosis& d);

}  // namespace idm::analysis
