// idm-gap: where, why and how far the model and a stage part (the sim-to-real gap diagnosis).
//
//   idm-gap diagnose DATASET [--json FILE] [--report DIR] [--threads N] [--effects LIST]
//   idm-gap validate [--seeds N] [--json FILE] [--effects LIST] [--threads N]
//
// diagnose prints a short summary; --json writes specs/gap-report.md; --report writes plots (SVG)
// and report.html. Every file is written whole (temporary name, then rename). Bad input: one line
// on stderr, exit status 2.
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <sstream>
#include <string>

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
    "usage: idm-gap diagnose DATASET [--json FILE] [--report DIR] [--threads N] [--effects LIST]\n"
    "       idm-gap validate [--seeds N] [--first-seed S] [--json FILE] [--effects LIST] [--quick 1] [--sample-rate HZ] [--threads N]\n"
    "DATASET is a sweep in the format of specs/sweep-dataset.md; LIST is comma-separated effect names\n"
    "(amplifier, actuator_compliance, hysteresis, creep, stribeck, friction_spread, tilt, quantization).\n";

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
      for (const model::EffectInfo& e : model::effect_library()) allowed += (allowed.empty() ? "" : ", ") + std::string(e.name);
      throw InputError("--effects: unknown effect '" + item + "', allowed " + allowed);
    }
    out.push_back(item);
  }
  return out;
}

void check_output_dir(const std::string& flag, const std::string& file) {
  const std::filesystem::path p(file);
  const std::filesystem::path dir = p.has_parent_path() ? p.parent_path() : std::filesystem::path(".");
  if (!std::filesystem::is_directory(dir))
    throw InputError("--" + flag + ": " + file + ": the directory " + dir.string() + " does not exist");
}

int diagnose(int argc, char** argv) {
  if (argc < 3 || std::string(argv[2]).rfind("--", 0) == 0) throw InputError("DATASET: missing (required)");
  const std::string path = argv[2];
  const tools::Flags f(argc, argv, 3, {"json", "report", "threads", "effects"});
  if (f.has("json")) check_output_dir("json", f.text("json"));
  analysis::DiagnoseOptions opt;
  opt.fit.threads = static_cast<int>(f.integer_or("threads", 0, 0, 256));
  opt.effects = effect_list(f);
  if (!std::filesystem::is_directory(path)) throw InputError(path + ": no such dataset directory");
  const analysis::SweepCells sweep = analysis::collect_cells(recording::read_dataset(path));
  const analysis::Diagnosis d = analysis::diagnose(sweep, opt);
  const std::string summary = analysis::text_summary(sweep, d);
  std::fputs(summary.c_str(), stdout);
  if (f.has("json")) analysis::write_file_atomic(f.text("json"), analysis::gap_report_json(sweep, d, path));
  if (f.has("report")) std::printf("report: %s\n", analysis::write_report(sweep, d, summary, f.text("report")).c_str());
  return 0;
}

void print_run(const analysis::ValidateRun& r) {
  std::string named, params;
  for (const std::string& n : r.named) named += (named.empty() ? "" : "+") + n;
  for (const auto& [k, v] : r.params) params += (params.empty() ? "" : ",") + k + "=" + model::format_number(v);
  std::fprintf(stdout, "%-4s hidden %-20s %-40s seed %-3llu named %-22s gap %7.3g -> %7.3g shrink %5.1f %%  %.0f s\n",
               r.correct ? "ok" : "MISS", r.hidden.c_str(), params.c_str(), static_cast<unsigned long long>(r.seed),
               named.empty() ? "(nothing)" : named.c_str(), r.gap_before, r.gap_after, 100 * r.shrink, r.seconds);
  std::fflush(stdout);
}

int validate(int argc, char** argv) {
  const tools::Flags f(argc, argv, 2, {"seeds", "json", "effects", "threads", "first-seed", "quick", "sample-rate"});
  if (f.has("json")) check_output_dir("json", f.text("json"));
  analysis::ValidateOptions opt;
  opt.seeds = static_cast<int>(f.integer_or("seeds", 1, 1, 1000));
  opt.first_seed = static_cast<std::uint64_t>(f.integer_or("first-seed", 1, 0, 1L << 40));
  opt.threads = static_cast<int>(f.integer_or("threads", 0, 0, 256));
  opt.quick = f.integer_or("quick", 0, 0, 1) == 1;
  opt.sample_rate_hz = f.number_or("sample-rate", 0, 20e3, 200e3);
  for (const std::string& e : effect_list(f)) opt.effects.push_back(e);
  if (f.has("effects"))
    for (const std::string& e : opt.effects) {
      bool ok = false;
      for (const std::string& v : analysis::validate_effects()) ok = ok || v == e;
      if (!ok) throw InputError("--effects: validate cannot hide '" + e + "' (no plausible range), allowed none, amplifier, actuator_compliance, hysteresis, stribeck, friction_spread, tilt");
    }
  const analysis::ValidateResult r = analysis::run_validate(opt, print_run);
  std::printf("accuracy %.3f (%zu runs)\n", r.accuracy, r.runs.size());
  for (const auto& [e, t] : r.by_effect) std::printf("  %-20s %d / %d\n", e.c_str(), t.second, t.first);
  if (f.has("json")) analysis::write_file_atomic(f.text("json"), analysis::validate_json(r));
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  return idm::tools::run_subcommands("idm-gap", kUsage, {{"diagnose", diagnose}, {"validate", validate}}, argc, argv);
}
