// The candidate effects of the diagnosis and how a set of them is fitted.
//
// Every effect of model::effect_library() is a candidate. Its fitted parameters are searched in
// coordinates of the effect's own physics, with ranges taken from this sweep and this stage (never
// from the paper's Table 1): an amplifier's cutoff and an actuator's resonance against the
// sweep's fastest phase, the actuator's damping as a damping ratio, a Stribeck velocity against the
// slider's speeds, a tilt against the friction it competes with, a DAC's clock against the sweep's
// frequencies. Each coordinate is mapped to [0, 1] (log where it spans decades).
//
// A fit: a coarse grid finds the basin (the objective is piecewise flat where region labels
// change), NLopt's bounded derivative-free Subplex (LN_SBPLX) refines it from the best grid points
// that are not neighbours, at the cheaper plant rate under an actuator chain; the winner is
// polished by a short Subplex at the scoring rate and scored there on the held-out trials. The
// objective is the training gap, alpha and mu refitted at every evaluation (gap.h). A set of
// several effects is fitted jointly: all their coordinates together, from the single fits' optima.
// A fit is implausible when a coordinate ends on a bound of its range (the data asks for more than
// the physics allows, or for no effect at all), the model needs a step scale outside (0.05, 2], or
// it predicts a spread of the trials that the trials do not show (the spread part of its held-out
// gap above the baseline's and above kSpreadPartAllowance).
#pragma once

#include <functional>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "analysis/gap.h"

namespace idm::analysis {

struct FitAxis {
  std::string name;  // e.g. "resonance_hz"
  double lo = 0, hi = 1;
  bool log_scale = false;
  double value(double u) const;  // u in [0, 1] -> axis value
  double coordinate(double value) const;
};

using Params = std::map<std::string, double>;

struct CandidateSpec {
  std::string effect;
  std::vector<FitAxis> axes;     // fitted coordinates (empty with an explicit grid)
  std::vector<Params> variants;  // fixed parameters, each variant fitted on its own
  std::vector<Params> grid;      // explicit parameter sets (integer parameters), no refinement
  std::function<Params(const std::vector<double>& axis_values)>
      params;                 // -> the effect's parameters
  std::vector<double> start;  // a start in axis values (stage.yaml's K and C), or empty
  // A dense scan instead of the coarse grid for a needle-like objective (a lightly damped
  // resonance: the gap's basin is a few % wide in frequency): axis 0 in steps of scan_ratio, axis
  // 1 at each of scan_other.
  double scan_ratio = 0;
  std::vector<double> scan_other;
  // The scan only for the effect alone (its narrow valley found where an evaluation is cheap); on
  // top of a set the coarse grid with the set profiled at every point, and the scan with the set
  // held (fit_on_top keeps the better start).
  bool scan_alone_only = false;
  bool scans(bool alone) const { return scan_ratio > 1 && (alone || !scan_alone_only); }
  // On one coordinate beside an effect scanned alone only (or a resonance, when the selection
  // asks: FitOptions::resonance_across), that effect is scanned at every point of this one's grid
  // (fit_on_top); not where an evaluation costs several simulations.
  bool scanned_across = true;
  std::string physics;  // one line: what the coordinates mean (for the report)
};

// The candidates for every effect of model::effect_library(), in library order, with ranges
// scaled to this sweep and stage.
std::vector<CandidateSpec> candidate_library(const SweepCells& sweep);

// Where the sweep lies outside what the diagnosis searches: the first candidate coordinate whose
// range (from this sweep's frequencies, duties and strokes and this stage) is empty, as "EFFECT's
// AXIS: [LO, HI] is empty" with what bounds it; "" when every range holds values. A diagnosis of
// such a sweep is refused before anything is simulated (an actuator's resonance is searched from
// half the highest frequency up to 2e5 Hz: a sweep above 4e5 Hz has no range to search).
// `effects`: only these candidates (empty: all).
std::string search_range_problem(const SweepCells& sweep,
                                 const std::vector<std::string>& effects = {});
const CandidateSpec& spec_of(const std::vector<CandidateSpec>& library, const std::string& effect);

// What the effect's signature needs that the sweep lacks ("a second stroke", "both directions"),
// or "" when the effect is identifiable from this sweep.
std::string missing_signature(const SweepCells& sweep, const std::string& effect);

// One effect of a fitted set: its coordinates and fixed parameters.
struct MemberFit {
  std::string effect;
  Params fixed;           // the variant
  std::vector<double> u;  // coordinates in [0, 1] (empty for an explicit grid point)
  Params grid_point;      // the explicit parameters when the spec has a grid
};

struct SetFit {
  std::vector<MemberFit> members;
  std::vector<model::EffectSpec> effects;  // completed, as simulated
  FittedModel fitted;                      // at the scoring rate: train and held-out evaluations
  double train_gap = 0;                    // objective at the optimum
  double gap = 0;                          // held-out gap
  double shrink = 0;                       // 1 - gap / gap_before
  bool plausible = true;
  bool on_bound = false;  // a coordinate ended on a bound of its range (one reason not plausible)
  std::string note;       // why not plausible
  int evaluations = 0;
  std::vector<std::string> names() const;
};

struct FitOptions {
  // Told every fit and every decision of the selection, one line each, as they happen (idm-gap
  // diagnose --explain); empty: nothing is told. Fits run on several threads at once: it must
  // be safe to call from any of them.
  std::function<void(const std::string&)> explain;
  int threads = 0;        // 0: all cores
  int grid_1d = 9;        // coarse grid points for one coordinate
  int grid_2d = 7;        // per axis for two
  int refine_evals = 16;  // Subplex evaluations per coordinate after the grid
  int starts_2d = 3;      // refinements for two coordinates (best grid point, next non-neighbours)
  int polish_evals = 6;   // Subplex evaluations per coordinate at the scoring rate
  // The same for a set's joint fit: a pair's valley can be a few % wide in one coordinate
  // (amplifier + tilt: the gap triples 3 % off the cutoff), and the search rate's optimum is off
  // by about that much.
  int joint_polish_evals = 16;
  // A pair of an effect scanned alone only and an effect on one coordinate also searched by the
  // scan at every point of the other's grid (fit_on_top; off where the same pair was searched so
  // the other way round already).
  bool scan_across = true;
  // The same for an effect scanned on top of a set as well (a resonance), and only that search
  // (fit_on_top returns the best across, an infinite train_gap when there is none): asked for by
  // the selection after the pair's screen said the resonance is there and its basin was missed.
  bool resonance_across = false;
};

// The model of a set of effects at the given members (coordinates -> parameters).
std::vector<model::EffectSpec> effects_of(const std::vector<CandidateSpec>& library,
                                          const std::vector<MemberFit>& members);

// Cells a coarse search looks at on a large sweep.
constexpr std::size_t kCoarseCells = 24;

// The spread part of a held-out gap (gap.h, GapParts) a set that predicts a spread of the trials
// may leave whatever the baseline's: a right model on 2 held-out trials a cell leaves about 1.
constexpr double kSpreadPartAllowance = 1.5;

// At most `count` cells spread evenly over the sweep's order (stroke, frequency, duty), every
// other field as in `sweep`; the sweep itself when it is small.
SweepCells spread_subset(const SweepCells& sweep, std::size_t count);

// Starting points for a refinement from a grid of (value, coordinates u): the grid's local minima,
// best first (a point no worse than every grid neighbour: within `step` of it in each coordinate;
// a narrow valley between grid points shows as one, the slope towards a range's edge where an
// effect fades away does not), then, while fewer than max_starts, the best points not near a
// start (within `cell`).
std::vector<std::vector<double>> starts_from(
    std::vector<std::pair<double, std::vector<double>>> grid, const std::vector<double>& step,
    const std::vector<double>& cell, int max_starts);

// A set's training gap as a screen measures it (JointStage::Search's objective: the cells of
// spread_subset, the search rate, mu at stage.yaml's): what a screened set with one effect more
// is compared with.
double screening_gap(const SweepCells& sweep, const std::vector<CandidateSpec>& library,
                     const std::vector<MemberFit>& members, const FittedModel& baseline,
                     int threads);

// One effect alone, fitted on the training trials and scored on the held-out ones against
// `baseline` (its mu is where the search starts).
SetFit fit_single(const SweepCells& sweep, const std::vector<CandidateSpec>& library,
                  const CandidateSpec& spec, const FittedModel& baseline,
                  const FitOptions& options);

// `spec` added to the set `base`: its coarse search on top of the set, then the whole set's joint
// search, both on the subset of cells a coarse search uses (JointStage::Search: its train_gap
// ranks sets screened alike; fit_joint(..., Finish) takes it to every cell). A set of one is
// profiled at every grid point of `spec` (its coordinates refitted by a short Subplex: fitted
// alone it may have absorbed part of `spec`'s signature and sit beside the valley the two share);
// a larger set, or one under a scan (hundreds of points), is held where it is.
SetFit fit_on_top(const SweepCells& sweep, const std::vector<CandidateSpec>& library,
                  const std::vector<MemberFit>& base, const CandidateSpec& spec,
                  const FittedModel& baseline, const FitOptions& options);

// Whether fit_on_top searches the pair of `base`'s one member and `spec` across (fits_across):
// one of them scanned (alone only, or with `resonance` on top of a set as well: a resonance) and
// the other on one coordinate without a grid.
bool searched_across(const std::vector<CandidateSpec>& library, const std::vector<MemberFit>& base,
                     const CandidateSpec& spec, bool resonance);

// A set of effects fitted jointly from `start` (one member per effect, e.g. the single fits).
// Search: the Subplex at the search rate only (train_gap is its objective; no held-out score, gap
// is infinite), to screen sets; Finish: from `start` (a screened set) a short search on every cell,
// the polish and the score; Full: the search, the polish and the score.
enum class JointStage { Search, Finish, Full };
SetFit fit_joint(const SweepCells& sweep, const std::vector<CandidateSpec>& library,
                 const std::vector<MemberFit>& start, const FittedModel& baseline,
                 const FitOptions& options, JointStage stage = JointStage::Full);

}  // namespace idm::analysis
