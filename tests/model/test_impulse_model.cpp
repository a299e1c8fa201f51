// The impulse model against the reference vectors, the paper's Fig. 4 and independent derivations.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "model/impulse_model.h"

using namespace idm::model;

namespace {

struct ReferenceRow {
  double freq_hz, duty, beta;
  std::string region;
  double step_ideal_m, step_eq22_m;
  double x_m[4];
};

std::vector<ReferenceRow> load_reference() {
  const std::string path = std::string(IDM_TEST_DATA_DIR) + "/impulse-model-vectors.csv";
  std::ifstream in(path);
  EXPECT_TRUE(in.good()) << "cannot open " << path;
  std::vector<ReferenceRow> rows;
  std::string line;
  bool header = false;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    if (!header) {
      EXPECT_EQ(line, "freq_hz,duty,beta,region,step_ideal_m,step_eq22_m,x1_m,x2_m,x3_m,x4_m");
      header = true;
      continue;
    }
    std::stringstream ss(line);
    std::string cell;
    std::vector<std::string> cells;
    while (std::getline(ss, cell, ',')) cells.push_back(cell);
    EXPECT_EQ(cells.size(), 10u) << line;
    ReferenceRow r{};
    r.freq_hz = std::stod(cells[0]);
    r.duty = std::stod(cells[1]);
    r.beta = std::stod(cells[2]);
    r.region = cells[3];
    r.step_ideal_m = std::stod(cells[4]);
    r.step_eq22_m = std::stod(cells[5]);
    for (int i = 0; i < 4; ++i) r.x_m[i] = std::stod(cells[6 + i]);
    rows.push_back(r);
  }
  return rows;
}

bool near_boundary(double beta, double duty) {
  const double d = duty < 0.5 ? duty : 1 - duty;
  const RegionBoundaries b = region_boundaries(d);
  for (double x : {b.cutoff, b.stop_in_ext, b.first_rest_a, b.first_rest_b})
    if (std::fabs(beta - x) < 1e-9) return true;
  return false;
}

}  // namespace

TEST(ImpulseModel, ReproducesEveryReferenceRow) {
  const StageParams table1;  // the defaults are Table 1
  const auto rows = load_reference();
  ASSERT_EQ(rows.size(), 456u);
  int region_mismatches = 0;
  for (const ReferenceRow& r : rows) {
    SCOPED_TRACE(::testing::Message() << "f=" << r.freq_hz << " duty=" << r.duty);
    const ImpulseCell c = impulse_cell(table1, r.freq_hz, r.duty, table1.stroke_m);
    EXPECT_NEAR(c.beta, r.beta, 1e-8 * r.beta);
    if (r.region != region_name(c.region)) {
      ++region_mismatches;
      EXPECT_TRUE(near_boundary(c.beta, r.duty))
          << "region " << region_name(c.region) << " expected " << r.region;
    }
    EXPECT_NEAR(c.step_ideal_m, r.step_ideal_m, 1e-14 + 1e-8 * std::fabs(r.step_ideal_m));
    EXPECT_NEAR(c.step_m, r.step_eq22_m, 1e-14 + 1e-8 * std::fabs(r.step_eq22_m));
    TriangleWave w{r.freq_hz, r.duty, table1.stroke_m, 4};
    const std::vector<double> x = cycle_end_positions_m(table1, w);
    for (int i = 0; i < 4; ++i) EXPECT_NEAR(x[i], r.x_m[i], 1e-12) << "x" << i + 1;
  }
  EXPECT_EQ(region_mismatches, 0);
}

TEST(ImpulseModel, PaperFigure4Cases) {
  const StageParams s;
  struct Case {
    double duty, freq_hz, beta;
    Region region;
  } cases[] = {{0.10, 200, 0.054, Region::OneStep},
               {0.40, 200, 0.054, Region::Cutoff},
               {0.35, 600, 0.482, Region::MultiStep},
               {0.47, 350, 0.164, Region::MultiStep},
               {0.40, 300, 0.121, Region::OneStep}};
  for (const Case& c : cases) {
    const ImpulseCell cell = impulse_cell(s, c.freq_hz, c.duty, s.stroke_m);
    EXPECT_NEAR(cell.beta, c.beta, 0.0005) << c.freq_hz;
    EXPECT_EQ(cell.region, c.region) << "duty " << c.duty << " f " << c.freq_hz;
  }
}

TEST(ImpulseModel, ImpulseRatioIsEq18) {
  StageParams s;
  s.slider_mass_kg = 0.3;
  s.counter_mass_kg = 0.1;
  s.friction_coefficient = 0.2;
  s.gravity_m_s2 = 9.81;
  // m S f^2 / ((M+m) mu g), written out independently
  const double f = 437.0, S = 12e-6;
  EXPECT_DOUBLE_EQ(impulse_ratio(s, f, S), 0.1 * S * f * f / (0.4 * 0.2 * 9.81));
}

// The closed form (eqs 19, 23, 26-29) agrees with an exact event simulation on the grid of
// docs/model.md (50-1000 Hz by 10 Hz, duty 0.005-0.495 by 0.005): an independent derivation.
TEST(ImpulseModel, ClosedFormRegionsAgreeWithEventSimulation) {
  const StageParams s;
  int points = 0, disagree = 0;
  for (int fi = 50; fi <= 1000; fi += 10) {
    for (int di = 1; di <= 99; ++di) {
      const double duty = di * 0.005;
      const double beta = impulse_ratio(s, fi, s.stroke_m);
      ++points;
      const Region closed = region_closed_form(beta, duty);
      const Region simulated = region_by_event_simulation(beta, duty);
      if (closed != simulated && !near_boundary(beta, duty)) {
        ++disagree;
        ADD_FAILURE() << "f=" << fi << " duty=" << duty << " closed " << region_name(closed)
                      << " simulated " << region_name(simulated);
      }
    }
  }
  EXPECT_EQ(points, 9504);
  EXPECT_EQ(disagree, 0);
}

// Mirroring the duty < 0.5 boundaries for duty > 0.5 is wrong for bursts from rest (docs/model.md):
// the event simulation must disagree with the mirrored closed form at many grid points.
TEST(ImpulseModel, MirroredBoundariesAreNotTheReverseRegions) {
  const StageParams s;
  int differ = 0;
  for (int fi = 50; fi <= 1000; fi += 10)
    for (int di = 1; di <= 99; ++di) {
      const double duty = 1.0 - di * 0.005;
      const double beta = impulse_ratio(s, fi, s.stroke_m);
      if (region(beta, duty) != region_closed_form(beta, 1.0 - duty)) ++differ;
    }
  EXPECT_EQ(differ, 1089);
}

TEST(ImpulseModel, FirstCycleVelocitiesMatchEventSimulation) {
  const StageParams s;
  for (double f : {100.0, 200.0, 350.0, 600.0, 900.0})
    for (double duty = 0.02; duty < 0.5; duty += 0.03) {
      const FirstCycleVelocities v = first_cycle_velocities(s, f, duty, s.stroke_m);
      ImpulseEventSimulator sim(s);
      TriangleWave w{f, duty, s.stroke_m, 1};
      sim.corner(w.extension_rate_m_s());
      sim.advance(w.extension_s());
      EXPECT_NEAR(sim.velocity_m_s(), v.end_of_extension_m_s, 1e-12) << f << " " << duty;
      sim.corner(w.retraction_rate_m_s());
      sim.advance(w.retraction_s());
      EXPECT_NEAR(sim.velocity_m_s(), v.end_of_cycle_m_s, 1e-12) << f << " " << duty;
    }
}

// Eq 21 from the event simulation: in one-step cells the second and later steps are the steady
// step.
TEST(ImpulseModel, SteadyStepIsTheEventSimulationStep) {
  const StageParams s;
  for (double f : {100.0, 250.0, 400.0})
    for (double duty : {0.05, 0.1, 0.2, 0.3, 0.7, 0.8, 0.9, 0.95}) {
      const ImpulseCell c = impulse_cell(s, f, duty, s.stroke_m);
      if (c.region != Region::OneStep) continue;
      const auto x = cycle_end_positions_m(s, TriangleWave{f, duty, s.stroke_m, 6});
      for (int k = 1; k < 6; ++k) EXPECT_NEAR(x[k] - x[k - 1], c.step_ideal_m, 1e-15);
    }
}

TEST(ImpulseModel, StepVanishesAtTheCutoffBoundary) {
  const StageParams s;
  // beta = (1-d) d^2 exactly at f* = sqrt((1-d) d^2 mu g / (ratio S))
  const double d = 0.1;
  const double f_star =
      std::sqrt((1 - d) * d * d * s.friction_decel_m_s2() / (s.mass_ratio() * s.stroke_m));
  EXPECT_NEAR(steady_step_ideal_m(s, f_star * (1 + 1e-9), d, s.stroke_m), 0.0, 1e-13);
  EXPECT_LT(steady_step_ideal_m(s, f_star * 1.01, d, s.stroke_m), -1e-9);
  EXPECT_EQ(steady_step_ideal_m(s, f_star * 0.99, d, s.stroke_m), 0.0);
}
