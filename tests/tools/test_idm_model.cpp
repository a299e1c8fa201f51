// idm-model as a user runs it: output formats, a sweep read back by the dataset reader, and bad
// input answered by one line naming the argument and the allowed range, with exit status 2.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <sstream>
#include <string>

#include "model/impulse_model.h"
#include "recording/dataset.h"
#include "tests/tools/run_tool.h"

namespace {

using Result = idm::test::ToolResult;

Result run(const std::string& args) {
  return idm::test::run_tool("idm-model", args);
}

}  // namespace

TEST(IdmModel, RegionsCsvMatchesTheModel) {
  const Result r = run("regions --freq 200,300 --duty 0.1:0.4:0.3");
  ASSERT_EQ(r.status, 0) << r.out;
  std::istringstream in(r.out);
  std::string line;
  std::getline(in, line);
  EXPECT_EQ(line, "freq_hz,duty,stroke_m,beta,region,step_m");
  int rows = 0;
  const idm::model::StageParams s;
  while (std::getline(in, line)) {
    ++rows;
    double f, d, stroke, beta, step;
    char region[32];
    ASSERT_EQ(std::sscanf(line.c_str(), "%lf,%lf,%lf,%lf,%31[^,],%lf", &f, &d, &stroke, &beta,
                          region, &step),
              6)
        << line;
    const auto c = idm::model::impulse_cell(s, f, d, stroke);
    EXPECT_STREQ(region, idm::model::region_name(c.region));
    EXPECT_NEAR(step, c.step_m, 1e-15);
  }
  EXPECT_EQ(rows, 4);
  EXPECT_NE(r.out.find("200,0.4,2.035e-05,0.05360199327,cutoff,0"), std::string::npos);
}

TEST(IdmModel, SimulateEndsWhereTheEventSimulationDoes) {
  const Result r =
      run("simulate --plant impulse --freq 250 --duty 0.1 --cycles 4 --sample-rate 20000");
  ASSERT_EQ(r.status, 0) << r.out;
  EXPECT_EQ(r.out.rfind("t_s,xi_cmd_m,x_m\n", 0), 0u);
  // the row at t = 4 T = 16 ms
  const auto pos = r.out.find("\n0.016,");
  ASSERT_NE(pos, std::string::npos);
  const double x = std::stod(r.out.substr(r.out.find(',', r.out.find(',', pos + 1) + 1) + 1));
  const idm::model::StageParams s;
  const auto ends = idm::model::cycle_end_positions_m(s, {250, 0.1, s.stroke_m, 4});
  EXPECT_NEAR(x, ends.back(), 9.9e-9);  // one interferometer count
}

TEST(IdmModel, SweepIsAReadableDataset) {
  const auto dir =
      std::filesystem::temp_directory_path() / ("idm_model_sweep_" + std::to_string(getpid()));
  std::filesystem::remove_all(dir);
  const Result r =
      run("sweep --plant mck --effect amplifier:cutoff_hz=3000 --freq 100,400 --duty 0.1,0.9 "
          "--trials 2 --cycles 4 --sample-rate 20000 --seed 3 --noise 2e-9 --out " +
          dir.string());
  ASSERT_EQ(r.status, 0) << r.out;
  const auto ds = idm::recording::read_dataset(dir.string());
  ASSERT_EQ(ds.trials.size(), 8u);
  const auto t = idm::recording::read_trial(ds, 0);
  EXPECT_EQ(t.t_s.front() < 0, true);
  EXPECT_DOUBLE_EQ(ds.trials[0].guide_pos_m, t.x_m.front());
  // a second sweep into the same directory is refused, the first left as it was
  const Result again =
      run("sweep --freq 100 --duty 0.1 --trials 1 --cycles 1 --sample-rate 20000 --seed 1 --out " +
          dir.string());
  EXPECT_EQ(again.status, 2);
  EXPECT_NE(again.out.find("already holds a sweep"), std::string::npos);
  EXPECT_EQ(idm::recording::read_dataset(dir.string()).trials.size(), 8u);
  std::filesystem::remove_all(dir);
}

TEST(IdmModel, BadInputIsOneLineNamingTheArgument) {
  const struct {
    const char* args;
    const char* message;
  } cases[] = {
      {"regions --freq 100 --duty 1.5", "--duty: 1.5 is out of range, allowed (0, 1)\n"},
      {"regions --freq 0 --duty 0.1", "--freq: 0 is out of range, allowed (0, 1e6]\n"},
      {"regions --freq nan --duty 0.1", "--freq: 'nan' is not finite\n"},
      {"regions --freq 100 --duty 0.1 --wobble 1", "--wobble: unknown flag"},
      {"regions --stage /nonexistent.yaml --freq 100 --duty 0.1",
       "--stage: /nonexistent.yaml: no such file\n"},
      {"simulate --freq 100 --duty 0.1 --cycles 2 --sample-rate 1e4 --effect wobble",
       "unknown effect 'wobble'"},
      {"simulate --freq 100 --duty 0.1 --cycles 2 --sample-rate 1e4 --plant magic",
       "--plant: unknown plant 'magic'"},
      {"simulate --freq 100 --duty 0.1 --sample-rate 1e4", "--cycles: missing (required)\n"},
      {"frobnicate", "unknown command 'frobnicate'"},
  };
  for (const auto& c : cases) {
    const Result r = run(c.args);
    EXPECT_EQ(r.status, 2) << c.args;
    EXPECT_NE(r.out.find(c.message), std::string::npos) << c.args << " -> " << r.out;
    EXPECT_EQ(std::count(r.out.begin(), r.out.end(), '\n'), 1) << r.out;
  }
}

TEST(IdmModel, NegativeMassInAStageFileNamesTheKey) {
  const auto path = std::filesystem::temp_directory_path() /
                    ("idm_bad_stage_" + std::to_string(getpid()) + ".yaml");
  {
    std::FILE* f = std::fopen(path.c_str(), "w");
    std::fputs("stage:\n  slider_mass_kg: 0.2\n  counter_mass_kg: -0.05\n", f);
    std::fclose(f);
  }
  const Result r = run("regions --stage " + path.string() + " --freq 100 --duty 0.1");
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.out.find(path.string() +
                       ":3: stage.counter_mass_kg: -0.05 is out of range, allowed [1e-06, 1000]"),
            std::string::npos)
      << r.out;
  std::filesystem::remove(path);
}
