// Online calibration: the RLS estimate of (alpha, mu), the second of two identical moves needing
// fewer corrections, and the calibration file (round trip; corrupt, truncated, foreign files
// reported and ignored).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <string>

#include "positioner_rig.h"

using namespace idm;
using namespace idm::control;

namespace {

// The file the daemon writes (it writes the same text crash-safe: recording::write_file_durably).
void save(const Calibration& cal, const std::string& path) {
  std::ofstream(path, std::ios::binary) << Calibration::serialize(cal.state());
}

using test_rig::ideal_map;

std::string temp_path(const std::string& name) {
  return std::string(::testing::TempDir()) + "idm_calibration_" + name;
}

std::string read_text(const std::string& path) {
  std::ifstream in(path);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

void write_text(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::trunc);
  out << text;
}

// A usable cell of the map moving `sign`, with a step near `step_m`.
const RegionCell& cell_near(const RegionMap& map, int sign, double step_m) {
  const RegionCell* best = nullptr;
  for (std::size_t i : map.usable_cells()) {
    const RegionCell& c = map.cells()[i];
    if (c.direction() != sign) continue;
    if (best == nullptr ||
        std::fabs(std::fabs(c.step_m) - step_m) < std::fabs(std::fabs(best->step_m) - step_m))
      best = &c;
  }
  return *best;
}

TEST(Calibration, RlsRecoversAlphaAndMuFromExactBursts) {
  // The "true" stage: alpha 0.42, mu 0.43; the nominal one: 0.35, 0.4. Bursts of several cells
  // predicted by the true stage's model (same regressors) must pull the estimate to the truth.
  model::StageParams nominal;
  RegionMapConfig cfg = test_rig::rig_map_config(nominal.step_correction);
  const RegionMap map(cfg);
  CalibrationConfig cc;
  cc.forgetting = 1.0;
  Calibration cal(nominal, cc);
  const double alpha = 0.42, mu = 0.43;
  auto truth = [&](const RegionCell& c, std::uint64_t n) {
    const double d = c.duty < 0.5 ? c.duty : 1 - c.duty;
    const double T = 1 / c.freq_hz;
    const double a = nominal.mass_ratio() * c.stroke_m / (1 - d);
    const double b = nominal.gravity_m_s2 * d * d * T * T;
    const double transient =
        c.direction() * (c.single_burst_m - c.step_m) / nominal.step_correction;
    return c.direction() * (alpha * (static_cast<double>(n) * a + transient) -
                            alpha * mu * static_cast<double>(n) * b);
  };
  const double steps[] = {2e-6, 1e-6, 3e-7, 1e-7, 3e-8, 1.5e-8};
  for (int round = 0; round < 8; ++round) {
    for (double s : steps) {
      const RegionCell& c = cell_near(map, 1, s);
      const double measured = truth(c, 20);
      if (std::fabs(measured) < 3 * 9.89e-9) continue;
      cal.update(c, 20, measured, 9.89e-9);
    }
  }
  EXPECT_GT(cal.total_updates(), 6u);
  EXPECT_NEAR(cal.alpha(model::Region::OneStep, 1), alpha, 2e-3);
  EXPECT_NEAR(cal.mu(model::Region::OneStep, 1), mu, 3e-3);
  // The other direction was never updated.
  EXPECT_EQ(cal.estimate(model::Region::OneStep, -1).updates, 0u);
  EXPECT_DOUBLE_EQ(cal.alpha(model::Region::OneStep, -1), 0.35);
  const RegionCell& c = cell_near(map, 1, 1e-7);
  // Outliers (a stall) do not move the estimate.
  const CalibrationState before = cal.state();
  EXPECT_FALSE(cal.update(c, 20, 0.1 * truth(c, 20), 9.89e-9));
  EXPECT_EQ(cal.state().estimates[1][1].alpha, before.estimates[1][1].alpha);
  cal.reset();
  EXPECT_EQ(cal.total_updates(), 0u);
}

// Identical moves on a stage whose friction is 10 % above the nominal one (within the map's 15 %
// uncertainty): the map's fine steps near cut-off are then off by much more than 10 %. The same
// five targets are visited twice from 0; corrections and chunks are summed per round.
struct TwoRounds {
  std::uint32_t corrections[2] = {0, 0};
  std::uint64_t chunks[2] = {0, 0};
};
TwoRounds two_identical_rounds(Calibration* calibration) {
  drivers::sim::SimDeviceConfig dev = test_rig::ideal_device();
  dev.faults.friction_scale = 1.1;
  test_rig::Rig rig(ideal_map(), dev, {}, calibration);
  Positioner& p = *rig.positioner;
  TwoRounds r;
  const double targets[] = {37.3e-6, -4.21e-6, 612e-9, -151.7e-6, 2.9e-6};
  for (int round = 0; round < 2; ++round) {
    for (double target : targets) {
      for (double t : {target, 0.0}) {
        EXPECT_EQ(p.move_absolute(t), Refusal::None);
        EXPECT_EQ(rig.run(), MotionState::Idle) << motion_fault_name(p.status().fault);
        EXPECT_LE(std::fabs(p.status().position_m - t), p.count_m());
        if (t == 0.0) continue;
        r.corrections[round] += p.status().corrections;
        r.chunks[round] += p.move_chunks();
      }
    }
  }
  return r;
}

// A correction is every chunk after the first of a move: the chunks of a move measure how many
// times it had to read and correct (a final chunk cut short to stay behind the target is one too).
TEST(Calibration, SecondOfTwoIdenticalMovesNeedsFewerCorrections) {
  const TwoRounds without = two_identical_rounds(nullptr);
  // Without calibration the rung estimates start from the map's seeds at every move (only the
  // session's dead-rung marks carry over), so round 2 is not helped by what round 1 measured.
  EXPECT_GE(without.chunks[1] * 10, without.chunks[0] * 9);
  Calibration cal(ideal_map().config().stage);
  const TwoRounds with = two_identical_rounds(&cal);
  EXPECT_LT(with.chunks[1], with.chunks[0]);
  EXPECT_LT(with.chunks[1] * 10, without.chunks[1] * 9)
      << "at least 10 % fewer chunks than without";
  // The tries at the last half count depend on the finest steps, not on what was learned: a few.
  EXPECT_LE(with.corrections[1], 6u);
  EXPECT_GT(cal.total_updates(), 10u);
  std::printf(
      "corrections without calibration %u, %u; with %u, %u; chunks %llu, %llu / %llu, %llu\n",
      without.corrections[0], without.corrections[1], with.corrections[0], with.corrections[1],
      static_cast<unsigned long long>(without.chunks[0]),
      static_cast<unsigned long long>(without.chunks[1]),
      static_cast<unsigned long long>(with.chunks[0]),
      static_cast<unsigned long long>(with.chunks[1]));
}

TEST(Calibration, FileRoundTrip) {
  Calibration cal(model::StageParams{});
  CalibrationState s = cal.state();
  s.estimates[1][1].alpha = 0.3712345678901234;
  s.estimates[1][1].alpha_mu = 0.151;
  s.estimates[1][1].updates = 17;
  s.total_updates = 17;
  cal.set_state(s);
  const std::string path = temp_path("roundtrip");
  save(cal, path);
  Calibration other(model::StageParams{});
  std::string error;
  ASSERT_TRUE(other.load(path, error)) << error;
  EXPECT_TRUE(error.empty());
  EXPECT_EQ(other.state().estimates[1][1].alpha, 0.3712345678901234);
  EXPECT_EQ(other.state().estimates[1][1].updates, 17u);
  EXPECT_EQ(other.total_updates(), 17u);
  EXPECT_EQ(Calibration::serialize(other.state()), read_text(path));
}

TEST(Calibration, CorruptFileIsReportedAndIgnored) {
  Calibration source(model::StageParams{});
  CalibrationState s = source.state();
  s.estimates[1][0].alpha = 0.5;
  s.estimates[1][0].alpha_mu = 0.2;
  s.estimates[1][0].updates = 3;
  source.set_state(s);
  const std::string path = temp_path("corrupt");
  save(source, path);
  const std::string good = read_text(path);

  auto expect_ignored = [&](const std::string& text, const std::string& what) {
    write_text(path, text);
    Calibration cal(model::StageParams{});
    const std::string before = Calibration::serialize(cal.state());
    std::string error;
    EXPECT_FALSE(cal.load(path, error)) << what;
    EXPECT_NE(error.find(path), std::string::npos) << what << ": " << error;
    EXPECT_NE(error.find(what), std::string::npos) << error;
    EXPECT_EQ(Calibration::serialize(cal.state()), before) << "the calibration stays nominal";
  };
  // One digit changed: the checksum catches it (names the line of the checksum).
  std::string flipped = good;
  flipped[flipped.find("0.5") + 2] = '7';
  expect_ignored(flipped, "checksum mismatch");
  expect_ignored(good.substr(0, good.size() / 2), "truncated");
  expect_ignored("garbage\n", ":1: not a calibration file");
  expect_ignored("", ":1: not a calibration file");
  // A well-formed file of another stage.
  model::StageParams other_stage;
  other_stage.slider_mass_kg = 0.2;
  Calibration other(other_stage);
  save(other, path);
  expect_ignored(read_text(path), "another stage");
  // A negative alpha with a valid checksum: the line is named.
  CalibrationState bad = source.state();
  std::string text = Calibration::serialize(bad);
  const std::size_t at = text.find("estimate one-step negative 3 ");
  ASSERT_NE(at, std::string::npos);
  text.replace(at, std::string("estimate one-step negative 3 0.5").size(),
               "estimate one-step negative 3 -0.5");
  // Re-sign it so only the value is wrong.
  text = text.substr(0, text.find("checksum"));
  {
    std::uint64_t h = 1469598103934665603ull;
    for (unsigned char c : text) {
      h ^= c;
      h *= 1099511628211ull;
    }
    char line[64];
    std::snprintf(line, sizeof line, "checksum %016llx\n", static_cast<unsigned long long>(h));
    text += line;
  }
  expect_ignored(text, ":5: alpha and alpha_mu must be finite and > 0");
  // Missing file.
  Calibration cal(model::StageParams{});
  std::string error;
  EXPECT_FALSE(cal.load(temp_path("missing"), error));
  EXPECT_NE(error.find("cannot open"), std::string::npos) << error;
}

TEST(Calibration, SetStateRefusesAnotherStage) {
  Calibration a(model::StageParams{});
  model::StageParams other;
  other.stroke_m = 10e-6;
  Calibration b(other);
  EXPECT_THROW(a.set_state(b.state()), model::InputError);
  CalibrationConfig bad;
  bad.forgetting = 0;
  try {
    validate(bad);
    FAIL();
  } catch (const model::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("control.calibration.forgetting"), std::string::npos);
  }
}

}  // namespace
