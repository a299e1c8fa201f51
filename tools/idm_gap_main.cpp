// idm-gap: where, why and how far the model and a stage part (the sim-to-real gap diagnosis).
//
//   idm-gap diagnose DATASET [--json FILE] [--report DIR] [--threads N] [--effects LIST]
//                    [--explain]
//   idm-gap validate [--seeds N] [--first-seed S] [--json FILE] [--cases LIST] [--quick 1]
//   [--threads N]
//
// diagnose prints a short summary; --json writes docs/gap-report.md; --report writes plots (SVG)
// and report.html. Every file is written whole (temporary name, then rename). Bad input: one line
// on stderr, exit status 2, nothing written. A trial file that cannot be read is left out with a
// warning on stderr naming it and why (listed in the summary and the JSON too). `idm-gap
// --version` prints the project's version; `--help` after any subcommand its usage (exit 0).
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <mutex>
#include <sstream>
#include <string>

#include "analysis/candidates.h"
#include "analysis/gap_cells.h"
#include "analysis/report_json.h"
#include "analysis/report_plots.h"
#include "analysis/selection.h"
#include "analysis/validate.h"
#include "model/yaml_util.h"
#include "tools/cli.h"

using namespace idm;
using idm::model::InputError;

namespace {

const char* kUsage =
    "usage: idm-gap --version\n"
    "       idm-gap diagnose DATASET [--json FILE] [--report DIR] [--threads N] [--effects LIST]\n"
    "                        [--explain]\n"
    "       idm-gap validate [--seeds N] [--first-seed S] [--json FILE] [--cases LIST] [--quick 1] "
    "[--threads N]\n"
    "DATASET is a sweep in the format of docs/sweep-dataset.md; LIST is comma-separated effect "
    "names\n"
    "(amplifier, actuator_compliance, hysteresis, creep, stribeck, friction_spread, tilt, "
    "quantization);\n"
    "validate cases: none, an effect, two joined by '+', unknown:stroke_saturation, "
    "unknown:thermal_stroke,\n"
    "not_identifiable:tilt, not_identifiable:hysteresis (default: all of them, or a quick few with "
    "--quick 1).\n";

std::vector<std::string> effect_list(const tools::Flags& f) {
  std::vector<std::string> out;
  if (!f.has("effects")) return out;
  const bool allow_none = std::string(f.text("effects")).find("none") != std::string::npos;
  std::stringstream ss(f.text("effects"));
  std::string item;
  while (std::getline(ss, item, ',')) {
    if (item.empty()) continue;
    bool known = allow_none && item == "none";
    for (const model::EffectInfo& e : model::effect_library()) known = known || item == e.name;
    if (!known) {
      std::string allowed;
      for (const model::EffectInfo& e : model::effect_library())
        allowed += (allowed.empty() ? "" : ", ") + std::string(e.name);
      throw InputError("--effects: unknown effect '" + item + "', allowed " + allowed);
    }
    out.push_back(item);
  }
  return out;
}

void check_output_dir(const std::string& flag, const std::string& file) {
  const std::filesystem::path p(file);
  const std::filesystem::path dir =
      p.has_parent_path() ? p.parent_path() : std::filesystem::path(".");
  if (!std::filesystem::is_directory(dir))
    throw InputError("--" + flag + ": " + file + ": the directory " + dir.string() +
                     " does not exist");
}

int diagnose(int argc, char** argv) {
  if (argc < 3 || std::string(argv[2]).rfind("--", 0) == 0)
    throw InputError("DATASET: missing (required)");
  const std::string path = argv[2];
  const tools::Flags f(argc, argv, 3, {"json", "report", "threads", "effects", "explain"}, {},
                       {"explain"});
  if (f.has("json")) check_output_dir("json", f.text("json"));
  analysis::DiagnoseOptions opt;
  // --explain: every fit and every decision of the selection on stdout as it happens, before the
  // summary (the fitting threads take turns).
  std::mutex explain_mutex;
  if (f.has("explain"))
    opt.fit.explain = [&explain_mutex](const std::string& line) {
      const std::lock_guard<std::mutex> lock(explain_mutex);
      std::printf("explain: %s\n", line.c_str());
      std::fflush(stdout);
    };
  opt.fit.threads = static_cast<int>(f.integer_or("threads", 0, 0, 256));
  opt.effects = effect_list(f);
  if (!std::filesystem::is_directory(path)) throw InputError(path + ": no such dataset directory");
  const analysis::SweepCells sweep = analysis::collect_cells(recording::read_dataset(path));
  if (const std::string p = analysis::search_range_problem(sweep, opt.effects); !p.empty())
    throw InputError((std::filesystem::path(path) / "sweep.csv").string() +
                     ": freq_hz, duty, stroke_m: the sweep lies outside what the diagnosis "
                     "searches: " +
                     p);
  for (const analysis::LeftOutTrial& t : sweep.damaged)
    std::fprintf(stderr, "idm-gap diagnose: warning: trial left out: %s\n", t.why.c_str());
  const analysis::Diagnosis d = analysis::diagnose(sweep, opt);
  const std::string summary = analysis::text_summary(sweep, d);
  std::fputs(summary.c_str(), stdout);
  if (f.has("json"))
    analysis::write_file_atomic(f.text("json"), analysis::gap_report_json(sweep, d, path));
  if (f.has("report"))
    std::printf("report: %s\n",
                analysis::write_report(sweep, d, summary, f.text("report")).c_str());
  return 0;
}

void print_run(const analysis::ValidateRun& r) {
  std::string named, params;
  for (const std::string& n : r.named) named += (named.empty() ? "" : "+") + n;
  for (const auto& [k, v] : r.params)
    params += (params.empty() ? "" : ",") + k + "=" + model::format_number(v);
  std::fprintf(
      stdout,
      "%-4s %-40s seed %-3llu named %-30s%s gap %7.3g %s -> %7.3g %s shrink %5.1f %% where %s  "
      "%.0f s\n",
      r.correct ? "ok" : (r.error.empty() ? "MISS" : "ERR"), r.hidden.c_str(),
      static_cast<unsigned long long>(r.seed), named.empty() ? "(nothing)" : named.c_str(),
      r.unexplained ? " +unexplained" : "", r.gap_before, analysis::kGapUnit, r.gap_after,
      analysis::kGapUnit, 100 * r.shrink,
      r.where_scored ? model::format_number(std::round(100 * r.where_rank) / 100).c_str() : "-",
      r.seconds);
  std::fprintf(stdout, "     %s; %s\n", r.setup.c_str(), params.c_str());
  if (r.truth_scored) {
    std::string cannot;
    for (const std::string& n : r.truth_cannot_show) cannot += (cannot.empty() ? "" : ", ") + n;
    std::fprintf(stdout, "     the true set: held-out gap %.3g %s%s%s%s\n", r.truth_gap,
                 analysis::kGapUnit, cannot.empty() ? "" : "; it does not earn a place for ",
                 cannot.c_str(),
                 r.fit_short ? "; the fit of the named set stopped short of it" : "");
  }
  if (!r.error.empty()) std::fprintf(stdout, "     error: %s\n", r.error.c_str());
  std::fflush(stdout);
}

int validate(int argc, char** argv) {
  const tools::Flags f(argc, argv, 2, {"seeds", "json", "cases", "threads", "first-seed", "quick"});
  if (f.has("json")) check_output_dir("json", f.text("json"));
  analysis::ValidateOptions opt;
  opt.seeds = static_cast<int>(f.integer_or("seeds", 1, 1, 1000));
  opt.first_seed = static_cast<std::uint64_t>(f.integer_or("first-seed", 1, 0, 1L << 40));
  opt.threads = static_cast<int>(f.integer_or("threads", 0, 0, 256));
  opt.quick = f.integer_or("quick", 0, 0, 1) == 1;
  if (f.has("cases")) {
    std::stringstream ss(f.text("cases"));
    std::string item;
    while (std::getline(ss, item, ','))
      if (!item.empty()) {
        try {
          analysis::case_class(item);
        } catch (const InputError& e) {
          throw InputError(std::string("--cases: ") + e.what());
        }
        opt.cases.push_back(item);
      }
  }
  const analysis::ValidateResult r = analysis::run_validate(opt, print_run);
  std::fputs(analysis::validate_table(r).c_str(), stdout);
  if (f.has("json")) analysis::write_file_atomic(f.text("json"), analysis::validate_json(r));
  return 0;
}

}  // namespace

#ifndef IDM_VERSION
#define IDM_VERSION "0"
#endif

int main(int argc, char** argv) {
  if (argc == 2 && (std::string(argv[1]) == "--version" || std::string(argv[1]) == "-V")) {
    std::printf("idm-gap %s\n", IDM_VERSION);
    return 0;
  }
  return idm::tools::run_subcommands("idm-gap", kUsage,
                                     {{"diagnose", diagnose}, {"validate", validate}}, argc, argv);
}
