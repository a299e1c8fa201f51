// idm-model: the impulse model and the simulated stage from the command line.
//
//   idm-model regions  [--stage FILE] --freq LIST --duty LIST [--stroke LIST]
//   idm-model simulate [--stage FILE] [--plant impulse|rigid|mck] [--effect NAME:k=v,...]...
//                      --freq F --duty D --cycles N --sample-rate R [--seed S] [--noise M]
//   idm-model sweep    [--stage FILE] [--plant ...] [--effect ...]... --freq LIST --duty LIST
//                      [--stroke LIST] --trials N --cycles N --sample-rate R --seed S --out DIR
//                      [--noise M]
// LIST: comma-separated, or start:stop:step. Bad input: one line on stderr, exit status 2.
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <string>

#include "analysis/simulated_sweep.h"
#include "model/impulse_model.h"
#include "model/simulation.h"
#include "tools/cli.h"

using namespace idm;
using idm::model::InputError;

namespace {

const char* kUsage =
    "usage: idm-model regions  [--stage FILE] --freq LIST --duty LIST [--stroke LIST]\n"
    "       idm-model simulate [--stage FILE] [--plant impulse|rigid|mck] [--effect "
    "NAME:key=value,...]...\n"
    "                          --freq F --duty D --cycles N --sample-rate R [--seed S] [--noise "
    "M]\n"
    "       idm-model sweep    [--stage FILE] [--plant impulse|rigid|mck] [--effect ...]... --freq "
    "LIST\n"
    "                          --duty LIST [--stroke LIST] --trials N --cycles N --sample-rate R "
    "--seed S\n"
    "                          --out DIR [--noise M]\n"
    "LIST is comma-separated or start:stop:step; effects: amplifier, actuator_compliance, "
    "hysteresis,\n"
    "creep, stribeck, friction_spread, tilt, quantization (see model/README.md).\n";

model::StageFile stage_of(const tools::Flags& f) {
  if (!f.has("stage")) return {};
  const std::string path = f.text("stage");
  if (!std::filesystem::exists(path)) throw InputError("--stage: " + path + ": no such file");
  model::StageFile s =
      model::load_stage_file(path, {.strict = false, .require_dataset_keys = false});
  model::validate(s.stage, path + ": stage");
  return s;
}

model::SimConfig sim_of(const tools::Flags& f) {
  model::SimConfig c;
  if (f.has("plant")) {
    try {
      c.plant = model::parse_plant_name(f.text("plant"));
    } catch (const InputError&) {
      throw InputError("--plant: unknown plant '" + f.text("plant") +
                       "', allowed impulse, rigid, mck");
    }
  }
  for (const std::string& e : f.all("effect")) c.effects.push_back(model::parse_effect_arg(e));
  if (c.plant == model::PlantKind::Impulse && !c.effects.empty())
    throw InputError(
        "--effect: the impulse plant is the ideal model and takes no effects, use --plant rigid or "
        "mck");
  c.seed = static_cast<std::uint64_t>(f.integer_or("seed", 1, 0, 1L << 62));
  c.noise_m = f.number_or("noise", 0.0, 0.0, 1e-6);
  return c;
}

void check_wave(double f, double d, double s, int cycles) {
  try {
    model::validate(model::TriangleWave{f, d, s, cycles});
  } catch (const InputError& e) {
    const std::string what = e.what();
    // name the flag: freq_hz -> --freq, duty -> --duty, stroke_m -> --stroke
    if (what.rfind("freq_hz", 0) == 0) throw InputError("--freq" + what.substr(7));
    if (what.rfind("stroke_m", 0) == 0) throw InputError("--stroke" + what.substr(8));
    if (what.rfind("cycles", 0) == 0) throw InputError("--cycles" + what.substr(6));
    throw InputError("--" + what);
  }
}

int regions(int argc, char** argv) {
  const tools::Flags f(argc, argv, 2, {"stage", "freq", "duty", "stroke"});
  const model::StageFile s = stage_of(f);
  const auto freqs = f.list("freq"), duties = f.list("duty");
  const auto strokes = f.has("stroke") ? f.list("stroke") : std::vector<double>{s.stage.stroke_m};
  for (double fr : freqs)
    for (double d : duties)
      for (double st : strokes) check_wave(fr, d, st, 1);
  std::printf("freq_hz,duty,stroke_m,beta,region,step_m\n");
  for (double st : strokes)
    for (double fr : freqs)
      for (double d : duties) {
        const model::ImpulseCell c = model::impulse_cell(s.stage, fr, d, st);
        std::printf("%.10g,%.10g,%.10g,%.10g,%s,%.10g\n", fr, d, st, c.beta,
                    model::region_name(c.region),
                    c.region == model::Region::Cutoff ? 0.0 : c.step_m);
      }
  return 0;
}

int simulate(int argc, char** argv) {
  const tools::Flags f(argc, argv, 2,
                       {"stage", "plant", "effect", "freq", "duty", "cycles", "sample-rate", "seed",
                        "noise", "stroke"},
                       {"effect"});
  const model::StageFile s = stage_of(f);
  const model::SimConfig c = sim_of(f);
  const double fr = f.number("freq", -1e300, 1e300);
  const double d = f.number("duty", -1e300, 1e300);
  const long cycles = f.integer("cycles", 1, 1000000);
  const double stroke = f.number_or("stroke", s.stage.stroke_m, -1e300, 1e300);
  check_wave(fr, d, stroke, static_cast<int>(cycles));
  const double rate = f.number("sample-rate", 1.0, 1e8);
  model::SimulatedStage stage(s.stage, s.interferometer, c);
  stage.reset(0.0, c.seed);
  const model::TriangleWave w{fr, d, stroke, static_cast<int>(cycles)};
  model::TrialSamples out;
  stage.run_burst(w, rate, 0.0, w.period_s(), out);
  std::printf("t_s,xi_cmd_m,x_m\n");
  for (std::size_t k = 0; k < out.t_s.size(); ++k)
    std::printf("%.10g,%.10g,%.10g\n", out.t_s[k], out.xi_cmd_m[k], out.x_m[k]);
  return 0;
}

int sweep(int argc, char** argv) {
  const tools::Flags f(argc, argv, 2,
                       {"stage", "plant", "effect", "freq", "duty", "stroke", "trials", "cycles",
                        "sample-rate", "seed", "out", "noise"},
                       {"effect"});
  const model::StageFile s = stage_of(f);
  model::SimConfig c = sim_of(f);
  analysis::SweepPlan plan;
  plan.freqs_hz = f.list("freq");
  plan.duties = f.list("duty");
  if (f.has("stroke")) plan.strokes_m = f.list("stroke");
  plan.trials = static_cast<int>(f.integer("trials", 1, 100000));
  plan.cycles = static_cast<int>(f.integer("cycles", 1, 100000));
  plan.sample_rate_hz = f.number("sample-rate", 1e3, 1e7);
  plan.seed = static_cast<std::uint64_t>(f.integer("seed", 0, 1L << 62));
  c.seed = plan.seed;
  for (double fr : plan.freqs_hz)
    for (double d : plan.duties)
      for (double st :
           plan.strokes_m.empty() ? std::vector<double>{s.stage.stroke_m} : plan.strokes_m)
        check_wave(fr, d, st, plan.cycles);
  const std::string out = f.text("out");
  if (std::filesystem::exists(std::filesystem::path(out) / "sweep.csv"))
    throw InputError("--out: " + out +
                     " already holds a sweep (sweep.csv); choose a new directory");
  const std::size_t n = analysis::run_simulated_sweep(s, c, plan, out);
  std::fprintf(stderr, "idm-model: wrote %zu trials to %s\n", n, out.c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  return idm::tools::run_subcommands(
      "idm-model", kUsage, {{"regions", regions}, {"simulate", simulate}, {"sweep", sweep}}, argc,
      argv);
}
