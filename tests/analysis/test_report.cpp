// The report's JSON (docs/gap-report.md with its extension), the plots, whole-file writes, bad
// input, and validate's scenarios.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <fstream>

#include "analysis/report_json.h"
#include "analysis/report_plots.h"
#include "analysis/selection.h"
#include "analysis/simulated_sweep.h"
#include "analysis/validate.h"

using namespace idm;
using namespace idm::analysis;

namespace {

SweepCells small_sweep(const std::vector<model::EffectSpec>& effects) {
  model::SimConfig sim;
  sim.noise_m = 2e-9;
  for (const model::EffectSpec& e : effects)
    sim.effects.push_back(model::complete_effect(e, "test"));
  SweepPlan plan;
  plan.freqs_hz = {200, 500, 800};
  plan.duties = {0.1, 0.3, 0.7, 0.9};
  plan.trials = 4;
  plan.cycles = 8;
  plan.sample_rate_hz = 20e3;
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

const Diagnosis& tilted() {
  static const Diagnosis d = [] {
    DiagnoseOptions opt;
    opt.fit.threads = 2;
    opt.effects = {"tilt", "creep"};
    return diagnose(small_sweep({{"tilt", {{"angle_deg", 2}}}}), opt);
  }();
  return d;
}

bool balanced(const std::string& j) {
  int depth = 0;
  bool in_string = false;
  for (std::size_t i = 0; i < j.size(); ++i) {
    if (j[i] == '"' && (i == 0 || j[i - 1] != '\\')) in_string = !in_string;
    if (in_string) continue;
    if (j[i] == '{' || j[i] == '[') ++depth;
    if (j[i] == '}' || j[i] == ']') --depth;
    if (depth < 0) return false;
  }
  return depth == 0 && !in_string;
}

}  // namespace

TEST(ReportJson, HasTheShapeOfTheGapReportAndItsExtension) {
  const SweepCells sweep = small_sweep({{"tilt", {{"angle_deg", 2}}}});
  const Diagnosis& d = tilted();
  const std::string j = gap_report_json(sweep, d, "some \"path\"");
  for (const char* key :
       {"\"dataset\": \"some \\\"path\\\"\"",
        "\"baseline\": {\"model\": \"impulse\", \"params\": {\"step_correction\": ",
        "\"friction_coefficient\": ",
        "\"cells\": [",
        "\"freq_hz\": ",
        "\"measured_step_m\": ",
        "\"measured_step_sd_m\": ",
        "\"model_step_m\": ",
        "\"measured_region\": ",
        "\"model_region\": ",
        "\"residual\": ",
        "\"significant\": ",
        "\"effect_gap\": ",
        "\"spread_excess\": ",
        "\"departure\": ",
        "\"summary_departure\": ",
        "\"where\": {\"significant_cells\": [",
        "\"summary\": ",
        "\"candidates\": [",
        "\"effect\": \"tilt\"",
        "\"intervals\": {\"angle_deg\": [",
        "\"plausible\": ",
        "\"shrink\": ",
        "\"diagnosis\": {\"effects\": [\"tilt\"]",
        "\"gap_before\": ",
        "\"gap_after\": ",
        "\"unexplained\": {\"significant\": false",
        "\"ambiguous\": [",
        "\"not_identifiable\": [",
        "\"dataset_status\": {\"status\": \"unmarked\""})
    EXPECT_NE(j.find(key), std::string::npos) << key << "\n" << j;
  EXPECT_EQ(j.find("nan"), std::string::npos);
  std::size_t cells = 0;
  for (std::size_t p = j.find("{\"freq_hz\""); p != std::string::npos;
       p = j.find("{\"freq_hz\"", p + 1))
    ++cells;
  EXPECT_EQ(cells, sweep.cells.size());
  EXPECT_TRUE(balanced(j));
}

TEST(Report, RoundTicksWithoutMinusZero) {
  const std::vector<double> t = nice_ticks(-6.89, 4.59, 6);
  ASSERT_GE(t.size(), 4u);
  const double step = t[1] - t[0];
  EXPECT_DOUBLE_EQ(step, 2.0);
  for (double v : t) EXPECT_DOUBLE_EQ(v / step, std::round(v / step));
  EXPECT_EQ(tick_label(-1e-17, 0.01), "0.00");
  EXPECT_EQ(tick_label(-2, 2), "-2");
  EXPECT_EQ(tick_label(0.25, 0.05), "0.25");
  const std::vector<double> small = nice_ticks(0.0, 0.0034, 5);
  EXPECT_NEAR(small[1] - small[0], 0.001, 1e-15);
}

TEST(Report, WritesPlotsAndAPageWithoutLeavingTemporaryFiles) {
  const SweepCells sweep = small_sweep({{"tilt", {{"angle_deg", 2}}}});
  const Diagnosis& d = tilted();
  const auto dir =
      std::filesystem::temp_directory_path() / ("gap_report_" + std::to_string(getpid()));
  std::filesystem::remove_all(dir);
  write_report(sweep, d, text_summary(sweep, d), dir.string());
  for (const char* f :
       {"steps.svg", "regions.svg", "gap_before.svg", "effect_gap.svg", "spread_excess.svg",
        "gap_after.svg", "departure.svg", "ranking.svg", "report.html"}) {
    ASSERT_TRUE(std::filesystem::exists(dir / f)) << f;
    std::ifstream in(dir / f);
    const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (std::string(f).ends_with(".svg")) {
      EXPECT_EQ(text.rfind("<svg", 0), 0u) << f;
      EXPECT_NE(text.find("</svg>"), std::string::npos) << f;
      EXPECT_EQ(text.find(">-0<"), std::string::npos) << f;
    }
  }
  std::ifstream in(dir / "steps.svg");
  const std::string steps((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_NE(steps.find("steady step (um per cycle)"), std::string::npos);
  EXPECT_NE(steps.find("model after the diagnosis"), std::string::npos);
  for (const auto& e : std::filesystem::directory_iterator(dir))
    EXPECT_EQ(e.path().filename().string().find(".tmp"), std::string::npos) << e.path();
  std::filesystem::remove_all(dir);
}

std::string slurp(const std::filesystem::path& p) {
  std::ifstream in(p);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

TEST(Report, ThePageHasSectionsTablesAndItsPlotsInlineWithNoExternalResource) {
  const SweepCells sweep = small_sweep({{"tilt", {{"angle_deg", 2}}}});
  const Diagnosis& d = tilted();
  const auto dir =
      std::filesystem::temp_directory_path() / ("gap_html_" + std::to_string(getpid()));
  std::filesystem::remove_all(dir);
  const std::string html = slurp(write_report(sweep, d, text_summary(sweep, d), dir.string()));
  for (const char* part :
       {"<meta name=\"viewport\"", "<style>", "svg{max-width:100%;height:auto", "<nav>",
        "<section id=\"summary\">", "<section id=\"which\">", "<section id=\"where\">",
        "<section id=\"steps\">", "<section id=\"regions\">", "<th>effect</th>", "<td>tilt</td>",
        "held-out gap (σ)", "pre{white-space:pre-wrap"})
    EXPECT_NE(html.find(part), std::string::npos) << part;
  // every plot inline, the page whole on its own: no image, script, stylesheet or link to fetch
  std::size_t svgs = 0;
  for (std::size_t at = html.find("<svg "); at != std::string::npos;
       at = html.find("<svg ", at + 1))
    ++svgs;
  EXPECT_EQ(svgs, 8u);
  for (const char* external : {"<img", "src=", "<link", "<script", "@import", "url(http"})
    EXPECT_EQ(html.find(external), std::string::npos) << external;
  std::filesystem::remove_all(dir);
}

TEST(Report, EveryGapTheSummaryPrintsCarriesItsUnit) {
  const SweepCells sweep = small_sweep({{"tilt", {{"angle_deg", 2}}}});
  const std::string text = text_summary(sweep, tilted());
  std::size_t gaps = 0;
  for (std::size_t at = text.find("gap "); at != std::string::npos;
       at = text.find("gap ", at + 1)) {
    std::size_t end = at + 4;
    if (end >= text.size() ||
        !(std::isdigit(static_cast<unsigned char>(text[end])) || text[end] == ' '))
      continue;
    while (end < text.size() && text[end] == ' ') ++end;
    const std::size_t number = end;
    while (end < text.size() && (std::isdigit(static_cast<unsigned char>(text[end])) ||
                                 text[end] == '.' || text[end] == 'e' || text[end] == '-'))
      ++end;
    if (end == number) continue;
    ++gaps;
    EXPECT_EQ(text.substr(end, 3), " σ") << text.substr(at, end - at + 8) << "\n" << text;
  }
  EXPECT_GE(gaps, 3u) << text;
  EXPECT_NE(text.find("gaps and residuals in σ"), std::string::npos) << text;
}

TEST(Report, AMapWithNothingToShowSaysSoAndCellsWithoutDataAreHatchedNotWhite) {
  SweepCells sweep = small_sweep({});
  std::vector<double> zeros(sweep.cells.size(), 0.0);
  const std::string empty = cell_map_svg(sweep, zeros, "Trial-to-trial spread beyond the model's",
                                         "spread_excess", "no cell shows a spread excess");
  EXPECT_NE(empty.find(">no cell shows a spread excess<"), std::string::npos) << empty;
  // write_report's spread_excess.svg, where no cell shows one
  Diagnosis d = tilted();
  for (CellWhere& w : d.where.cells) w.spread_excess = 0;
  const SweepCells tilt = small_sweep({{"tilt", {{"angle_deg", 2}}}});
  const auto dir =
      std::filesystem::temp_directory_path() / ("gap_empty_" + std::to_string(getpid()));
  std::filesystem::remove_all(dir);
  write_report(tilt, d, text_summary(tilt, d), dir.string());
  EXPECT_NE(slurp(dir / "spread_excess.svg").find(">no cell shows a spread excess<"),
            std::string::npos);
  std::filesystem::remove_all(dir);
  // a cell of the grid without data (left out) and a value that is not a number: hatched grey, in
  // the legend, never the white of a 0
  std::vector<double> values(sweep.cells.size(), 5.0);
  values[1] = std::nan("");
  sweep.cells.erase(sweep.cells.begin() + 2);
  values.erase(values.begin() + 2);
  const std::string map = cell_map_svg(sweep, values, "gap", "held-out residual");
  EXPECT_NE(map.find("<pattern id=\"idm-no-data\""), std::string::npos) << map;
  std::size_t hatched = 0;
  for (std::size_t at = map.find("fill=\"url(#idm-no-data)\""); at != std::string::npos;
       at = map.find("fill=\"url(#idm-no-data)\"", at + 1))
    ++hatched;
  // per panel the grid's background, the NaN cell, and the legend's swatch
  EXPECT_GE(hatched, 3u) << map;
  EXPECT_NE(map.find(">no data<"), std::string::npos) << map;
  EXPECT_EQ(map.find(">no cell shows"), std::string::npos);  // no sentence when not asked
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
    EXPECT_NE(std::string(e.what()).find("tiny: the sweep is too small to diagnose"),
              std::string::npos)
        << e.what();
  }
  EXPECT_THROW(collect_cells(model::StageFile{}, {}, {}, "empty"), InputError);
  const auto dir = std::filesystem::temp_directory_path() / ("gap_bad_" + std::to_string(getpid()));
  std::filesystem::remove_all(dir);
  plan.trials = 3;
  run_simulated_sweep(model::StageFile{}, sim, plan, dir.string());
  const recording::Dataset ds = recording::read_dataset(dir.string());
  const std::string file = ds.trial_path(1);
  std::ifstream in(file);
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  in.close();
  const std::size_t line3 = text.find('\n', text.find('\n', text.find('\n') + 1) + 1);
  const std::size_t comma = text.rfind(',', line3);
  text.replace(comma + 1, line3 - comma - 1, "nan");
  std::ofstream(file) << text;
  try {  // the damaged trial is left out; the cell's other 2 are too few, and the message says why
    collect_cells(recording::read_dataset(dir.string()));
    ADD_FAILURE() << "no error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("too small to diagnose"), std::string::npos) << e.what();
    EXPECT_NE(
        std::string(e.what()).find("1 trial(s) left out as damaged, the first: " + file + ":3:3"),
        std::string::npos)
        << e.what();
  }
  std::filesystem::remove_all(dir);
}

TEST(WriteFileAtomic, ReplacesWholeAndRefusesAMissingDirectory) {
  const auto dir =
      std::filesystem::temp_directory_path() / ("gap_atomic_" + std::to_string(getpid()));
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

TEST(Validate, ScenariosAreInTheIssuesRanges) {
  int both = 0, two = 0, three = 0, five = 0;
  for (std::uint64_t seed = 1; seed <= 40; ++seed)
    for (const std::string& c :
         {std::string("none"), std::string("tilt+hysteresis"), std::string("friction_spread"),
          std::string("unknown:stroke_saturation"), std::string("not_identifiable:tilt")}) {
      const Scenario s = make_scenario(c, seed, false);
      const model::StageParams& p = s.stage.stage;
      EXPECT_GE(p.slider_mass_kg, 0.0499);
      EXPECT_LE(p.slider_mass_kg, 0.501);
      EXPECT_GE(p.friction_coefficient, 0.1499);
      EXPECT_LE(p.friction_coefficient, 0.701);
      EXPECT_GE(p.stroke_m, 4.99e-6);
      EXPECT_LE(p.stroke_m, 50.1e-6);
      EXPECT_GE(s.plan.sample_rate_hz, 10e3);
      EXPECT_LE(s.plan.sample_rate_hz, 50e3);
      EXPECT_GE(s.plan.trials, 3);
      EXPECT_LE(s.plan.trials, 5);
      EXPECT_GE(s.plan.freqs_hz.size() * s.plan.duties.size(), 20u);
      EXPECT_LE(s.plan.freqs_hz.back() * 25, s.plan.sample_rate_hz + 1e-9);
      bool fwd = false, rev = false;
      for (double d : s.plan.duties) (d < 0.5 ? fwd : rev) = true;
      if (c == "tilt+hysteresis") {
        EXPECT_TRUE(fwd && rev);
        EXPECT_EQ(s.plan.strokes_m.size(), 2u);
        EXPECT_EQ(s.expected, (std::vector<std::string>{"hysteresis", "tilt"}));
      }
      if (c == "friction_spread") {
        EXPECT_GE(s.plan.trials, 4);
      }
      if (c == "not_identifiable:tilt") {
        EXPECT_FALSE(fwd && rev);
      }
      if (c == "unknown:stroke_saturation") {
        EXPECT_TRUE(s.expected.empty() && s.expect_unexplained);
      }
      both += fwd && rev;
      two += s.plan.strokes_m.size() == 2;
      three += s.plan.trials == 3;
      five += s.plan.trials == 5;
      const Scenario again = make_scenario(c, seed, false);
      EXPECT_EQ(again.params, s.params);
      EXPECT_EQ(again.plan.freqs_hz, s.plan.freqs_hz);
    }
  EXPECT_GT(both, 20);
  EXPECT_GT(two, 20);
  EXPECT_GT(three, 10);
  EXPECT_GT(five, 10);
  EXPECT_THROW(case_class("amplifier+amplifier"), InputError);
  EXPECT_THROW(case_class("warp"), InputError);
  EXPECT_THROW(case_class("unknown:warp"), InputError);
  EXPECT_EQ(case_class("stribeck+tilt"), "pair");
  // every separable pair, and the expected-ambiguous one left out
  const std::vector<std::string> full = validate_cases(false);
  EXPECT_EQ(std::count_if(full.begin(), full.end(),
                          [](const std::string& c) { return case_class(c) == "pair"; }),
            14);
  EXPECT_EQ(std::find(full.begin(), full.end(), "amplifier+actuator_compliance"), full.end());
}

// A run that throws is reported with its error and counts as wrong; validate goes on (seed 12's
// amplifier + hysteresis once stopped a 50-run validate after 25 minutes).
TEST(Validate, ARunThatThrowsIsReportedAndCountsAsWrong) {
  Scenario s = make_scenario("amplifier", 1, true);
  s.stage.stage.friction_coefficient = 2.5;  // the sweep cannot be generated
  ValidateRun run;
  ASSERT_NO_THROW(run = validate_one(s, 1));
  EXPECT_FALSE(run.correct);
  EXPECT_NE(run.error.find("friction_coefficient"), std::string::npos) << run.error;
  ValidateResult r;
  r.runs = {run};
  EXPECT_NE(validate_table(r).find("1 run(s) stopped with an error"), std::string::npos);
  EXPECT_NE(validate_json(r).find("\"error\": \"stage.friction_coefficient"), std::string::npos)
      << validate_json(r);
}
