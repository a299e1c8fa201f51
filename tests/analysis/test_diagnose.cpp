// The diagnosis on sweeps generated in memory: fitting recovers a known effect, forward selection
// names the smallest set, effects whose signature the sweep lacks are reported as not identifiable,
// the JSON has the shape of specs/gap-report.md, and bad input is refused with a message.
#include <gtest/gtest.h>

#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>

#include "analysis/candidates.h"
#include "analysis/report_json.h"
#include "analysis/report_plots.h"
#include "analysis/selection.h"
#include "analysis/simulated_sweep.h"
#include "analysis/validate.h"

using namespace idm;
using namespace idm::analysis;

namespace {

// A small sweep in memory: 4 frequencies x 5 duties (one direction, one stroke), 4 trials.
SweepCells small_sweep(const std::vector<model::EffectSpec>& effects, std::vector<double> duties = {},
                       std::vector<double> strokes = {}) {
  model::SimConfig sim;
  sim.plant = model::PlantKind::Rigid;
  sim.noise_m = 2e-9;
  sim.seed = 5;
  for (const model::EffectSpec& e : effects) sim.effects.push_back(model::complete_effect(e, "test"));
  SweepPlan plan;
  plan.freqs_hz = {200, 400, 600, 800};
  plan.duties = duties.empty() ? std::vector<double>{0.05, 0.15, 0.25, 0.35, 0.45} : duties;
  plan.strokes_m = strokes;
  plan.trials = 4;
  plan.cycles = 10;
  plan.sample_rate_hz = 200e3;
  plan.seed = 5;
  std::vector<TrialInfo> infos;
  std::vector<TrialSeries> series;
  simulate_sweep(model::StageFile{}, sim, plan, [&](const TrialInfo& i, TrialSeries&& s) {
    infos.push_back(i);
    series.push_back(std::move(s));
  });
  model::StageFile stage;
  stage.interferometer.noise_m = sim.noise_m;
  return collect_cells(stage, infos, series, "memory");
}

const CandidateSpec& spec_of(const std::string& effect) {
  for (const CandidateSpec& s : candidate_library())
    if (s.effect == effect) return s;
  throw std::runtime_error("no candidate " + effect);
}

}  // namespace

TEST(Candidates, EveryEffectOfTheLibraryIsACandidateWithinItsAllowedRange) {
  ASSERT_EQ(candidate_library().size(), model::effect_library().size());
  for (std::size_t i = 0; i < candidate_library().size(); ++i) {
    const CandidateSpec& c = candidate_library()[i];
    EXPECT_EQ(c.effect, model::effect_library()[i].name);
    for (const FitParam& p : c.fit) {
      const auto& lib = model::effect_library()[i].params;
      const auto it = std::find_if(lib.begin(), lib.end(), [&](const model::EffectParamInfo& q) { return p.name == q.name; });
      ASSERT_NE(it, lib.end()) << c.effect << "." << p.name;
      EXPECT_GE(p.lo, it->lo) << c.effect << "." << p.name;
      EXPECT_LE(p.hi, it->hi) << c.effect << "." << p.name;
    }
  }
}

TEST(Candidates, FittingRecoversAKnownAmplifierCutoff) {
  const SweepCells sweep = small_sweep({{"amplifier", {{"cutoff_hz", 3000}, {"order", 2}}}});
  const GapEvaluation base = baseline_gap(sweep, 2);
  ASSERT_GT(base.gap, 5.0) << where_summary(base);
  FitOptions opt;
  opt.threads = 2;
  const CandidateResult r = fit_candidate(sweep, {}, spec_of("amplifier"), base.gap, opt);
  EXPECT_TRUE(r.plausible) << r.note;
  EXPECT_NEAR(r.params.at("cutoff_hz"), 3000, 300);
  EXPECT_EQ(r.params.at("order"), 2);
  EXPECT_GT(r.shrink, 0.6);
  // A wrong effect does not explain it as well.
  const CandidateResult tilt = fit_candidate(sweep, {}, spec_of("creep"), base.gap, opt);
  EXPECT_LT(tilt.shrink, r.shrink);
}

TEST(Candidates, ThePolishTakesASharpValleyToItsFloor) {
  // A soft actuator (validate drew this one at seed 4): with 2 nm noise the training gap is a V
  // of about 30 per 1 % of stiffness. The refinements stop partway down it (here K 1.9 % off,
  // held-out gap 27); the polish, a last Subplex from the winner with a tenth of the step, goes
  // on to the floor (0.02 % off, gap 2).
  const SweepCells sweep = small_sweep({{"actuator_compliance", {{"stiffness_n_m", 4.15e6}, {"damping_n_s_m", 137}}}});
  const GapEvaluation base = baseline_gap(sweep, 2);
  ASSERT_GT(base.gap, 100.0) << where_summary(base);
  FitOptions opt;
  opt.threads = 2;
  opt.polish = false;
  const CandidateResult rough = fit_candidate(sweep, {}, spec_of("actuator_compliance"), base.gap, opt);
  opt.polish = true;
  const CandidateResult polished = fit_candidate(sweep, {}, spec_of("actuator_compliance"), base.gap, opt);
  EXPECT_LE(polished.train_gap, rough.train_gap);
  EXPECT_NEAR(polished.params.at("stiffness_n_m"), 4.15e6, 0.005 * 4.15e6)
      << "without the polish: " << rough.params.at("stiffness_n_m");
  EXPECT_NEAR(polished.params.at("damping_n_s_m"), 137, 0.05 * 137);
  EXPECT_LT(polished.gap, 0.02 * base.gap) << "before " << base.gap << ", without the polish " << rough.gap;
}

TEST(Selection, NamesTheHiddenEffectAndNothingOnAnIdealStage) {
  DiagnoseOptions opt;
  opt.fit.threads = 2;
  opt.effects = {"amplifier", "creep", "stribeck"};
  const Diagnosis amp = diagnose(small_sweep({{"amplifier", {{"cutoff_hz", 2500}, {"order", 2}}}}), opt);
  ASSERT_EQ(amp.chosen.size(), 1u) << amp.where;
  EXPECT_EQ(amp.chosen[0].name, "amplifier");
  EXPECT_LT(amp.gap_after, amp.gap_before * 0.4);
  EXPECT_EQ(amp.candidates.front().effect, "amplifier");
  for (std::size_t i = 1; i < amp.candidates.size(); ++i)
    EXPECT_GE(amp.candidates[i - 1].shrink, amp.candidates[i].shrink);

  const Diagnosis ideal = diagnose(small_sweep({}), opt);
  EXPECT_LT(ideal.gap_before, kExplainedGap);
  EXPECT_TRUE(ideal.chosen.empty());
  EXPECT_EQ(ideal.gap_after, ideal.gap_before);
}

TEST(Selection, EffectsWhoseSignatureIsMissingAreNotIdentifiable) {
  const SweepCells one = small_sweep({}, {0.15, 0.35});
  EXPECT_NE(missing_signature(one, "hysteresis").find("second stroke"), std::string::npos);
  EXPECT_NE(missing_signature(one, "tilt").find("both directions"), std::string::npos);
  EXPECT_EQ(missing_signature(one, "amplifier"), "");
  EXPECT_EQ(missing_signature(one, "friction_spread"), "");
  DiagnoseOptions opt;
  opt.fit.threads = 2;
  opt.effects = {"hysteresis", "tilt", "creep"};
  const Diagnosis d = diagnose(one, opt);
  ASSERT_EQ(d.not_identifiable.size(), 2u);
  EXPECT_EQ(d.not_identifiable[0].effect, "hysteresis");
  EXPECT_EQ(d.not_identifiable[1].effect, "tilt");
  ASSERT_EQ(d.candidates.size(), 1u);
  EXPECT_EQ(d.candidates[0].effect, "creep");
  const std::string json = gap_report_json(one, d, "memory");
  EXPECT_NE(json.find("\"not_identifiable\": [{\"effect\": \"hysteresis\""), std::string::npos) << json;

  const SweepCells both = small_sweep({}, {0.15, 0.85}, {20.35e-6, 10e-6});
  EXPECT_EQ(missing_signature(both, "hysteresis"), "");
  EXPECT_EQ(missing_signature(both, "tilt"), "");
}

TEST(ReportJson, HasTheShapeOfTheGapReport) {
  const SweepCells sweep = small_sweep({}, {0.15, 0.35});
  DiagnoseOptions opt;
  opt.fit.threads = 2;
  opt.effects = {"tilt", "creep"};
  const Diagnosis d = diagnose(sweep, opt);
  const std::string j = gap_report_json(sweep, d, "some \"path\"");
  for (const char* key : {"\"dataset\": \"some \\\"path\\\"\"", "\"baseline\": {\"model\": \"impulse\"", "\"gap\": ",
                          "\"cells\": [", "\"freq_hz\": ", "\"measured_step_m\": ", "\"measured_step_sd_m\": ",
                          "\"model_step_m\": ", "\"measured_region\": ", "\"model_region\": ", "\"residual\": ",
                          "\"significant\": ", "\"where\": {\"significant_cells\": [", "\"summary\": ",
                          "\"candidates\": [", "\"effect\": \"creep\"", "\"plausible\": ", "\"shrink\": ",
                          "\"diagnosis\": {\"effects\": []", "\"gap_before\": ", "\"gap_after\": "})
    EXPECT_NE(j.find(key), std::string::npos) << key << "\n" << j;
  EXPECT_EQ(j.find("nan"), std::string::npos);
  std::size_t cells = 0;
  for (std::size_t p = j.find("{\"freq_hz\""); p != std::string::npos; p = j.find("{\"freq_hz\"", p + 1)) ++cells;
  EXPECT_EQ(cells, sweep.cells.size());
  int depth = 0;
  bool in_string = false;
  for (std::size_t i = 0; i < j.size(); ++i) {
    if (j[i] == '"' && (i == 0 || j[i - 1] != '\\')) in_string = !in_string;
    if (in_string) continue;
    if (j[i] == '{' || j[i] == '[') ++depth;
    if (j[i] == '}' || j[i] == ']') --depth;
    ASSERT_GE(depth, 0);
  }
  EXPECT_EQ(depth, 0);
}

TEST(Report, WritesPlotsAndAPageWithoutLeavingTemporaryFiles) {
  const SweepCells sweep = small_sweep({}, {0.15, 0.35});
  DiagnoseOptions opt;
  opt.fit.threads = 2;
  opt.effects = {"creep"};
  const Diagnosis d = diagnose(sweep, opt);
  const auto dir = std::filesystem::temp_directory_path() / ("gap_report_" + std::to_string(getpid()));
  std::filesystem::remove_all(dir);
  write_report(sweep, d, text_summary(sweep, d), dir.string());
  for (const char* f : {"regions.svg", "steps.svg", "gap_before.svg", "gap_after.svg", "ranking.svg", "report.html"}) {
    ASSERT_TRUE(std::filesystem::exists(dir / f)) << f;
    std::ifstream in(dir / f);
    const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (std::string(f).ends_with(".svg")) {
      EXPECT_EQ(text.rfind("<svg", 0), 0u) << f;
      EXPECT_NE(text.find("</svg>"), std::string::npos) << f;
    }
  }
  for (const auto& e : std::filesystem::directory_iterator(dir))
    EXPECT_EQ(e.path().filename().string().find(".tmp"), std::string::npos) << e.path();
  std::filesystem::remove_all(dir);
}

TEST(BadInput, ATooSmallSweepAndABadTrialFileAreRefusedWithAMessage) {
  model::SimConfig sim;
  SweepPlan plan;
  plan.freqs_hz = {100};
  plan.duties = {0.05};
  plan.trials = 2;
  plan.cycles = 4;
  std::vector<TrialInfo> infos;
  std::vector<TrialSeries> series;
  simulate_sweep(model::StageFile{}, sim, plan, [&](const TrialInfo& i, TrialSeries&& s) {
    infos.push_back(i);
    series.push_back(std::move(s));
  });
  try {
    collect_cells(model::StageFile{}, infos, series, "tiny");
    ADD_FAILURE() << "no error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("tiny: the sweep is too small to diagnose"), std::string::npos) << e.what();
  }
  EXPECT_THROW(collect_cells(model::StageFile{}, {}, {}, "empty"), InputError);

  // A NaN in a trial file names the file, the line and the column.
  const auto dir = std::filesystem::temp_directory_path() / ("gap_bad_" + std::to_string(getpid()));
  std::filesystem::remove_all(dir);
  plan.trials = 3;
  run_simulated_sweep(model::StageFile{}, sim, plan, dir.string());
  const recording::Dataset ds = recording::read_dataset(dir.string());
  const std::string file = ds.trial_path(1);
  std::ifstream in(file);
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  in.close();
  std::size_t line3 = text.find('\n', text.find('\n', text.find('\n') + 1) + 1);  // end of line 3
  const std::size_t comma = text.rfind(',', line3);
  text.replace(comma + 1, line3 - comma - 1, "nan");
  std::ofstream(file) << text;
  try {
    collect_cells(recording::read_dataset(dir.string()));
    ADD_FAILURE() << "no error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find(file + ":3:3"), std::string::npos) << e.what();
  }
  std::filesystem::remove_all(dir);
}

TEST(WriteFileAtomic, ReplacesWholeAndRefusesAMissingDirectory) {
  const auto dir = std::filesystem::temp_directory_path() / ("gap_atomic_" + std::to_string(getpid()));
  std::filesystem::create_directories(dir);
  const std::string path = (dir / "x.json").string();
  write_file_atomic(path, "first");
  write_file_atomic(path, "second");
  std::ifstream in(path);
  std::string text;
  std::getline(in, text);
  EXPECT_EQ(text, "second");
  EXPECT_THROW(write_file_atomic((dir / "no" / "x.json").string(), "x"), std::system_error);
  std::filesystem::remove_all(dir);
}

TEST(Validate, DrawsPlausibleParametersAndAPaperGrid) {
  for (const std::string& e : validate_effects()) {
    if (e == "none") continue;
    const model::EffectSpec a = draw_effect(e, 3), b = draw_effect(e, 3), c = draw_effect(e, 4);
    EXPECT_EQ(a.params, b.params) << e;
    EXPECT_NE(a.params, c.params) << e;
  }
  const SweepPlan p = validate_plan(false, 1);
  EXPECT_EQ(p.freqs_hz.size(), 8u);
  EXPECT_EQ(p.duties.size(), 18u);
  EXPECT_EQ(p.strokes_m.size(), 2u);
  EXPECT_GE(p.trials, 4);
}
