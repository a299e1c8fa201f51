// The interfaces' lifecycle and argument checks, the backend table, and the simulated stage as a
// backend: bursts through the plant read back through the codec, clocks, determinism, faults.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <string>
#include <thread>
#include <vector>

#include "drivers/backends.h"
#include "drivers/config.h"
#include "drivers/sim/sim_backend.h"
#include "model/impulse_model.h"
#include "model/waveform.h"

using namespace idm::drivers;
using idm::model::InputError;
using idm::model::TriangleWave;

namespace {

Device sim_device(const std::string& yaml) {
  return make_backend("sim", YAML::Load(yaml), "test.yaml");
}

std::string config_error(const std::string& yaml) {
  try {
    make_backend_from_config(YAML::Load(yaml), "idmd.yaml");
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

void bring_up(Device& d) {
  ASSERT_TRUE(d.configure().ok());
  ASSERT_TRUE(d.activate().ok());
}

// The wave sampled at rate (corners on samples when rate * duty / f is whole), ending at 0.
std::vector<double> sampled(const TriangleWave& w, double rate_hz) {
  std::vector<double> xi;
  idm::model::sample(w, rate_hz, 0.0,
                     static_cast<std::size_t>(std::lround(w.duration_s() * rate_hz)) + 1, xi);
  xi.back() = 0.0;
  return xi;
}

// Every stream word of the last burst decoded; returns the last valid position and counts the
// samples with each status.
struct Decoded {
  std::vector<double> t_s, x_m;
  std::vector<std::uint8_t> status;
  std::vector<std::size_t> marks;  // indices of the words with the reference mark
};
Decoded drain(Device& d, std::size_t chunk = 64) {
  Decoded out;
  PositionDecoder decoder(d.interferometer->capabilities().word);
  std::vector<TimedWord> buf(chunk);
  for (;;) {
    std::size_t n = 0;
    EXPECT_TRUE(d.interferometer->read_stream(buf.data(), buf.size(), n).ok());
    if (n == 0) break;
    for (std::size_t i = 0; i < n; ++i) {
      const PositionSample s = decoder.decode(buf[i].word);
      if (s.mark) out.marks.push_back(out.x_m.size());
      out.t_s.push_back(buf[i].t_s);
      out.x_m.push_back(s.position_m);
      out.status.push_back(s.status);
    }
  }
  return out;
}

// The ideal model's slider travel for a burst followed by settle_s at rest.
double predicted_travel_m(const TriangleWave& w, double settle_s) {
  idm::model::ImpulseEventSimulator sim{idm::model::StageParams{}};
  sim.reset();
  sim.run(w);
  sim.advance(settle_s);
  return sim.position_m();
}

}  // namespace

// ---- lifecycle and arguments ----

TEST(DriverLifecycle, StepsInOrderAndWrongStateIsAnError) {
  Device d = sim_device("{}");
  EXPECT_EQ(d.output->state(), LifecycleState::Unconfigured);
  DriverStatus s = d.output->activate();
  EXPECT_EQ(s.error, DriverError::InvalidState);
  EXPECT_NE(s.message.find("sim waveform output"), std::string::npos) << s.message;
  EXPECT_NE(s.message.find("activate"), std::string::npos) << s.message;
  std::uint64_t word = 0;
  EXPECT_EQ(d.interferometer->latch(word).error, DriverError::InvalidState);

  ASSERT_TRUE(d.configure().ok());
  EXPECT_EQ(d.output->state(), LifecycleState::Inactive);
  EXPECT_TRUE(d.interferometer->latch(word).ok()) << "positions are readable while inactive";
  EXPECT_EQ(d.output->start().error, DriverError::InvalidState);
  EXPECT_EQ(d.configure().error, DriverError::InvalidState);
  ASSERT_TRUE(d.activate().ok());
  EXPECT_EQ(d.output->state(), LifecycleState::Active);
  ASSERT_TRUE(d.deactivate().ok());
  EXPECT_EQ(d.interferometer->state(), LifecycleState::Inactive);
  ASSERT_TRUE(d.activate().ok());
  // shutdown from active deactivates first and always ends finalized
  EXPECT_TRUE(d.shutdown().ok());
  EXPECT_EQ(d.output->state(), LifecycleState::Finalized);
  EXPECT_EQ(d.interferometer->latch(word).error, DriverError::InvalidState);
  EXPECT_TRUE(d.shutdown().ok());
}

TEST(DriverLifecycle, StartWithoutBurstSaysWhatIsMissing) {
  Device d = sim_device("{}");
  bring_up(d);
  const DriverStatus s = d.output->start();
  EXPECT_EQ(s.error, DriverError::InvalidState);
  EXPECT_NE(s.message.find("no burst loaded"), std::string::npos) << s.message;
}

TEST(WaveformOutputArguments, BurstsAreCheckedBeforeTheBackendSeesThem) {
  Device d = sim_device("{}");
  bring_up(d);
  const OutputCapabilities& c = d.output->capabilities();
  EXPECT_EQ(c.mode, OutputMode::BufferedSamples);
  std::vector<double> xi = {0.0, 1e-6, 0.0};
  EXPECT_TRUE(d.output->write_burst(xi.data(), xi.size(), 1e5).ok());
  EXPECT_EQ(d.output->write_burst(xi.data(), 1, 1e5).error, DriverError::InvalidArgument);
  EXPECT_EQ(d.output->write_burst(xi.data(), xi.size(), 2 * c.max_sample_rate_hz).error,
            DriverError::InvalidArgument);
  EXPECT_EQ(d.output->write_burst(xi.data(), xi.size(), std::nan("")).error,
            DriverError::InvalidArgument);
  std::vector<double> not_at_zero = {1e-6, 0.0};
  DriverStatus s = d.output->write_burst(not_at_zero.data(), 2, 1e5);
  EXPECT_EQ(s.error, DriverError::InvalidArgument);
  EXPECT_NE(s.message.find("start and end at 0"), std::string::npos) << s.message;
  std::vector<double> too_far = {0.0, 2 * c.max_elongation_m(), 0.0};
  s = d.output->write_burst(too_far.data(), 3, 1e5);
  EXPECT_EQ(s.error, DriverError::InvalidArgument);
  EXPECT_NE(s.message.find("sample 1"), std::string::npos) << s.message;
  s = d.output->write_burst_parameters(TriangleWave{});
  EXPECT_EQ(s.error, DriverError::Unsupported);
  EXPECT_NE(s.message.find("write_burst"), std::string::npos) << s.message;
}

TEST(WaveformOutputArguments, ParameterDevicesCheckTheWave) {
  Device d = sim_device("daq: {sim: {output: parameters, max_freq_hz: 1000, max_cycles: 50}}");
  bring_up(d);
  EXPECT_EQ(d.output->capabilities().mode, OutputMode::BurstParameters);
  EXPECT_TRUE(d.output->write_burst_parameters(TriangleWave{200, 0.1, 20e-6, 10}).ok());
  EXPECT_EQ(d.output->write_burst_parameters(TriangleWave{2000, 0.1, 20e-6, 10}).error,
            DriverError::InvalidArgument);
  EXPECT_EQ(d.output->write_burst_parameters(TriangleWave{200, 0.1, 20e-6, 51}).error,
            DriverError::InvalidArgument);
  EXPECT_EQ(d.output->write_burst_parameters(TriangleWave{200, 1.5, 20e-6, 10}).error,
            DriverError::InvalidArgument);
  EXPECT_EQ(d.output->write_burst_parameters(TriangleWave{200, 0.1, 1e-3, 10}).error,
            DriverError::InvalidArgument);
  std::vector<double> xi = {0.0, 0.0};
  EXPECT_EQ(d.output->write_burst(xi.data(), 2, 1e5).error, DriverError::Unsupported);
}

// ---- the backend table and the config ----

TEST(BackendTable, UnknownDriverListsTheKnownOnes) {
  const std::string e = config_error("daq:\n  driver: nidaq\n");
  EXPECT_NE(e.find("idmd.yaml:2: daq.driver: unknown driver 'nidaq', known: sim, modbus, usb"),
            std::string::npos)
      << e;
  EXPECT_THROW(make_backend("nidaq", YAML::Load("{}"), "x.yaml"), InputError);
  EXPECT_NE(known_backends().find("sim"), std::string::npos);
  Device d = make_backend_from_config(YAML::Load("daq: {driver: sim}"), "idmd.yaml");
  EXPECT_EQ(d.driver, "sim");
  EXPECT_NE(d.sim, nullptr);
}

TEST(SimConfig, UnknownKeysAndBadValuesNameFileLineAndKey) {
  std::string e = config_error("daq:\n  driver: sim\n  sim:\n    clock: wall\n    speed: 3\n");
  EXPECT_NE(e.find("idmd.yaml:5: daq.sim.speed: unknown key"), std::string::npos) << e;
  e = config_error("daq:\n  sim:\n    clock: fast\n");
  EXPECT_NE(e.find("idmd.yaml:3: daq.sim.clock: unknown clock 'fast'"), std::string::npos) << e;
  e = config_error("daq:\n  sim:\n    faults:\n      glitch_probability: 2\n");
  EXPECT_NE(e.find("idmd.yaml:4: daq.sim.faults.glitch_probability"), std::string::npos) << e;
  e = config_error("daq:\n  sim:\n    faults:\n      fire: true\n");
  EXPECT_NE(e.find("idmd.yaml:4: daq.sim.faults.fire: unknown key"), std::string::npos) << e;
  e = config_error("daq:\n  sdk: 1\n");
  EXPECT_NE(e.find("idmd.yaml:2: daq.sdk: unknown key"), std::string::npos) << e;
  e = config_error("interferometer:\n  word_bits: 33\n");
  EXPECT_NE(e.find("idmd.yaml:2: interferometer.word_bits"), std::string::npos) << e;
  e = config_error("interferometer:\n  resolution_m: 5e-9\n");
  EXPECT_NE(e.find("disagrees"), std::string::npos) << e;
  e = config_error("sim:\n  plant: rigid\n  seeds: 3\n");
  EXPECT_NE(e.find("idmd.yaml:3: sim.seeds: unknown key"), std::string::npos) << e;
  e = config_error("daq:\n  sim:\n    min_voltage_v: 5\n");
  EXPECT_NE(e.find("idmd.yaml:3: daq.sim.min_voltage_v"), std::string::npos) << e;
}

TEST(SimConfig, InterferometerSectionSetsTheCodec) {
  const InterferometerConfig c = parse_interferometer_yaml(
      YAML::Load("interferometer: {word_bits: 36, optics: plane_mirror, air: {temperature_c: 20, "
                 "pressure_pa: 101325, relative_humidity_pct: 50}}"),
      "f.yaml");
  EXPECT_EQ(c.word.width, WordWidth::Bits36);
  EXPECT_NEAR(c.word.air_index, 1.000271374, 2e-9);
  EXPECT_NEAR(c.word.count_m(), 632.991e-9 / (128 * 1.000271374), 1e-15);
  EXPECT_DOUBLE_EQ(c.sensor.resolution_m, c.word.count_m());
}

TEST(SimConfig, AirIndexUsesTheWavelengthWhereverItIsWritten) {
  // The air's index depends on the wavelength: air: before lambda_vac_m must give the same index
  // as after it (the keys are read in file order, then combined).
  const char* air = "air: {temperature_c: 20, pressure_pa: 101325, relative_humidity_pct: 50}";
  const InterferometerConfig before = parse_interferometer_yaml(
      YAML::Load(std::string("interferometer: {") + air + ", lambda_vac_m: 0.9e-6}"), "f.yaml");
  const InterferometerConfig after = parse_interferometer_yaml(
      YAML::Load(std::string("interferometer: {lambda_vac_m: 0.9e-6, ") + air + "}"), "f.yaml");
  const InterferometerConfig red =
      parse_interferometer_yaml(YAML::Load(std::string("interferometer: {") + air + "}"), "f.yaml");
  EXPECT_DOUBLE_EQ(before.word.air_index, after.word.air_index);
  EXPECT_LT(before.word.air_index, red.word.air_index) << "air disperses: n falls with wavelength";
}

TEST(SimConfig, DriverSectionsNameTheKeyTheLineAndTheAllowedValues) {
  const auto error_of = [](const std::string& text) {
    try {
      sim::parse_sim_device_yaml(YAML::Load(text), "idmd.yaml");
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  std::string e = error_of("daq:\n  sim:\n    faults: {friction_scale: 0}\n");
  EXPECT_NE(
      e.find("idmd.yaml:3: daq.sim.faults.friction_scale: 0 is out of range, allowed (0, 100]"),
      std::string::npos)
      << e;
  e = error_of("daq:\n  sim:\n    faults: {beam_lots: true}\n");
  EXPECT_NE(
      e.find("daq.sim.faults.beam_lots: unknown key, did you mean 'beam_lost'? allowed beam_lost,"),
      std::string::npos)
      << e;
  e = error_of("daq:\n  sim:\n    output: volts\n");
  EXPECT_NE(
      e.find("idmd.yaml:3: daq.sim.output: unknown output 'volts', allowed samples, parameters"),
      std::string::npos)
      << e;
  e = error_of("interferometer:\n  optics: custom\n");
  EXPECT_NE(e.find("interferometer.divisor: required with optics: custom"), std::string::npos) << e;
  e = error_of("interferometer:\n  divisor: 64\n");
  EXPECT_NE(e.find("idmd.yaml:2: interferometer.divisor: only with optics: custom"),
            std::string::npos)
      << e;
  e = error_of("interferometer:\n  air_index: 1.0003\n  air: {co2_ppm: 400}\n");
  EXPECT_NE(e.find("give either air_index or air conditions, not both"), std::string::npos) << e;
  e = error_of("interferometer:\n  air: {co2_ppm: 4000}\n");
  EXPECT_NE(e.find("interferometer.air.co2_ppm: 4000 is out of range, allowed [0, 2000]"),
            std::string::npos)
      << e;
  e = error_of("interferometer:\n  lambda_vac_m: 1.5e-6\n  air: {co2_ppm: 400}\n");
  EXPECT_NE(e.find("idmd.yaml:3: interferometer: air.lambda_vac_m: 1.5e-6 is out of range"),
            std::string::npos)
      << e;
}

// ---- bursts through the plant ----

TEST(SimBackend, SampledBurstMovesTheSliderByTheImpulseModelsAmount) {
  Device d = sim_device("sim: {plant: rigid}");
  bring_up(d);
  const TriangleWave w{200, 0.1, 20.35e-6, 10};
  const std::vector<double> xi = sampled(w, 1e5);
  ASSERT_TRUE(d.output->write_burst(xi.data(), xi.size(), 1e5).ok());
  ASSERT_TRUE(d.output->start().ok());
  bool done = false;
  ASSERT_TRUE(d.output->is_done(done).ok());
  EXPECT_TRUE(done) << "the synthetic clock plays the whole burst at start()";
  const Decoded s = drain(d);
  const double settle = d.sim->config().settle_s;
  ASSERT_EQ(s.t_s.size(),
            static_cast<std::size_t>(std::lround((w.duration_s() + settle) * 1e5)) + 1);
  for (std::uint8_t st : s.status) ASSERT_EQ(st, 0);
  EXPECT_DOUBLE_EQ(s.t_s[0], 0.0);
  EXPECT_NEAR(s.t_s[1], 1e-5, 1e-15);
  const double predicted = predicted_travel_m(w, settle);
  const double count = d.interferometer->capabilities().word.count_m();
  EXPECT_LT(predicted, -100 * count) << "duty 0.1 moves the slider in the negative direction";
  EXPECT_NEAR(s.x_m.back(), predicted, 1.0 * count);
  EXPECT_NEAR(d.sim->true_position_m(), predicted, 1e-12);
  // A latch after the burst reads the same place.
  std::uint64_t word = 0;
  ASSERT_TRUE(d.interferometer->latch(word).ok());
  PositionDecoder decoder(d.interferometer->capabilities().word);
  EXPECT_NEAR(decoder.decode(word).position_m, predicted, 1.0 * count);
}

TEST(SimBackend, ParameterBurstIsPlayedWithExactCornersBothDirections) {
  Device d = sim_device("sim: {plant: rigid}\ndaq: {sim: {output: parameters, settle_s: 0.001}}");
  bring_up(d);
  for (double duty : {0.1, 0.9}) {
    const double x0 = d.sim->true_position_m();
    const TriangleWave w{300, duty, 20.35e-6, 7};
    ASSERT_TRUE(d.output->write_burst_parameters(w).ok());
    ASSERT_TRUE(d.output->start().ok());
    const double predicted = predicted_travel_m(w, 0.001);
    EXPECT_NEAR(d.sim->true_position_m() - x0, predicted, 1e-12) << "duty " << duty;
    EXPECT_GT(std::fabs(predicted), 1e-7);
  }
}

TEST(SimBackend, SameSeedSameWordsOtherSeedOtherNoise) {
  const std::string base =
      "sim: {plant: rigid, noise_m: 5e-9, seed: SEED}\n"
      "daq: {sim: {faults: {glitch_probability: 0.05}}}";
  auto words = [&](const std::string& seed) {
    std::string yaml = base;
    yaml.replace(yaml.find("SEED"), 4, seed);
    Device d = sim_device(yaml);
    bring_up(d);
    const std::vector<double> xi = sampled(TriangleWave{200, 0.1, 20e-6, 3}, 1e5);
    EXPECT_TRUE(d.output->write_burst(xi.data(), xi.size(), 1e5).ok());
    EXPECT_TRUE(d.output->start().ok());
    std::vector<TimedWord> buf(100000);
    std::size_t n = 0;
    EXPECT_TRUE(d.interferometer->read_stream(buf.data(), buf.size(), n).ok());
    std::vector<std::uint64_t> out;
    for (std::size_t i = 0; i < n; ++i) out.push_back(buf[i].word);
    return out;
  };
  const auto a = words("7"), b = words("7"), c = words("8");
  ASSERT_GT(a.size(), 1000u);
  EXPECT_EQ(a, b);
  EXPECT_NE(a, c);
}

TEST(SimBackend, WallClockGivesTheSameMotionAsTheSyntheticClock) {
  const TriangleWave w{500, 0.1, 20.35e-6, 5};  // 10 ms
  auto final_position = [&](const char* clock) {
    Device d = sim_device(std::string("sim: {plant: rigid}\ndaq: {sim: {clock: ") + clock + "}}");
    EXPECT_TRUE(d.configure().ok());
    EXPECT_TRUE(d.activate().ok());
    const std::vector<double> xi = sampled(w, 1e5);
    EXPECT_TRUE(d.output->write_burst(xi.data(), xi.size(), 1e5).ok());
    EXPECT_TRUE(d.output->start().ok());
    EXPECT_TRUE(d.output->wait_done(5.0).ok());
    bool done = false;
    EXPECT_TRUE(d.output->is_done(done).ok());
    EXPECT_TRUE(done);
    const Decoded s = drain(d);
    EXPECT_EQ(s.t_s.size(),
              static_cast<std::size_t>(std::lround((w.duration_s() + 2e-3) * 1e5)) + 1);
    return d.sim->true_position_m();
  };
  // The same motion, not the same bits: the wall clock also splits the plant's integration
  // wherever the test happens to look at the clock (timing: another split under a sanitizer),
  // which moves the last digits (seen: 5e-20 m apart). 1e-12 m is a thousandth of a nanometre, far
  // below one count (9.9 nm), and far above rounding.
  EXPECT_NEAR(final_position("wall"), final_position("synthetic"), 1e-12);
}

TEST(SimBackend, AWallClockSimulationThatFallsBehindRunsSlowInsteadOfCatchingUp) {
  // The caller away for 0.4 s (as when the plant cannot keep up): the simulation does not owe
  // the wall clock more than kMaxLagS, so the next call (a stop at shutdown, say) simulates at
  // most that much, and the burst simply plays later.
  Device d = sim_device("sim: {plant: rigid}\ndaq: {sim: {clock: wall}}");
  ASSERT_TRUE(d.configure().ok());
  ASSERT_TRUE(d.activate().ok());
  const TriangleWave w{200, 0.1, 20.35e-6, 400};  // 2 s
  const std::vector<double> xi = sampled(w, 1e5);
  ASSERT_TRUE(d.output->write_burst(xi.data(), xi.size(), 1e5).ok());
  ASSERT_TRUE(d.output->start().ok());
  const double t0 = d.sim->now_s();
  EXPECT_EQ(d.sim->wall_time_dropped_s(), 0.0);
  std::this_thread::sleep_for(std::chrono::milliseconds(400));
  bool done = true;
  ASSERT_TRUE(d.output->is_done(done).ok());
  EXPECT_FALSE(done);
  const double simulated_s = d.sim->now_s() - t0;
  EXPECT_LE(simulated_s, sim::SimBackend::kMaxLagS + 0.2);  // 0.2: the call's own time, generously
  EXPECT_GE(d.sim->wall_time_dropped_s(), 0.4 - simulated_s - 1e-9);
  ASSERT_TRUE(d.output->stop().ok());
  ASSERT_TRUE(d.output->is_done(done).ok());
  EXPECT_TRUE(done);
}

TEST(SimBackend, StopEndsABurstWithTheOutputAtZero) {
  Device d = sim_device("daq: {sim: {clock: wall, output: parameters}}");
  bring_up(d);
  ASSERT_TRUE(d.output->write_burst_parameters(TriangleWave{100, 0.1, 20e-6, 1000}).ok());  // 10 s
  ASSERT_TRUE(d.output->start().ok());
  bool done = true;
  ASSERT_TRUE(d.output->is_done(done).ok());
  EXPECT_FALSE(done);
  EXPECT_EQ(d.output->wait_done(0.01).error, DriverError::Timeout);
  ASSERT_TRUE(d.output->stop().ok());
  ASSERT_TRUE(d.output->is_done(done).ok());
  EXPECT_TRUE(done);
  EXPECT_EQ(d.sim->commanded_elongation_m(), 0.0);
  EXPECT_TRUE(d.shutdown().ok());
}

// ---- faults ----

TEST(SimFaults, BeamLossMarksEveryWordAndTheDecoderRejectsIt) {
  Device d = sim_device("daq: {sim: {faults: {beam_lost: true}}}");
  bring_up(d);
  std::uint64_t word = 0;
  ASSERT_TRUE(d.interferometer->latch(word).ok());
  EXPECT_NE(word & position_word::kMeasurementSignalLost, 0u);
  PositionDecoder decoder(d.interferometer->capabilities().word);
  PositionSample s = decoder.decode(word);
  EXPECT_FALSE(s.valid());
  EXPECT_TRUE(std::isnan(s.position_m));
  d.sim->set_beam_lost(false);
  ASSERT_TRUE(d.interferometer->latch(word).ok());
  decoder.reset();
  EXPECT_TRUE(decoder.decode(word).valid());
}

TEST(SimFaults, GlitchesAreWildCountsFlaggedOrCaughtAsJumps) {
  Device d = sim_device("{}");
  bring_up(d);
  PositionDecoder decoder(d.interferometer->capabilities().word);
  std::uint64_t word = 0;
  ASSERT_TRUE(d.interferometer->latch(word).ok());
  ASSERT_TRUE(decoder.decode(word).valid());
  d.sim->set_glitch_probability(1.0, true);
  ASSERT_TRUE(d.interferometer->latch(word).ok());
  EXPECT_NE(word & position_word::kGlitch, 0u);
  EXPECT_NE(decoder.decode(word).status & sample_status::kGlitchFlagged, 0);
  d.sim->set_glitch_probability(1.0, false);
  ASSERT_TRUE(d.interferometer->latch(word).ok());
  EXPECT_EQ(word & position_word::kGlitch, 0u);
  EXPECT_NE(decoder.decode(word).status & sample_status::kJumpTooFast, 0);
  d.sim->set_glitch_probability(0.0);
  ASSERT_TRUE(d.interferometer->latch(word).ok());
  const PositionSample s = decoder.decode(word);
  EXPECT_TRUE(s.valid()) << describe_sample_status(s.status);
  EXPECT_NEAR(s.position_m, 0.0, 1e-12);
  EXPECT_THROW(d.sim->set_glitch_probability(1.5), InputError);
}

TEST(SimFaults, StalledSliderDoesNotMoveAndFrictionJumpShortensTheStep) {
  const TriangleWave w{200, 0.1, 20.35e-6, 10};
  const double d_settle_s = sim::SimDeviceConfig{}.settle_s;
  auto travel = [&](const std::string& faults) {
    Device d = sim_device("sim: {plant: rigid}\ndaq: {sim: {output: parameters, faults: {" +
                          faults + "}}}");
    EXPECT_TRUE(d.configure().ok());
    EXPECT_TRUE(d.activate().ok());
    EXPECT_TRUE(d.output->write_burst_parameters(w).ok());
    EXPECT_TRUE(d.output->start().ok());
    return d.sim->true_position_m();
  };
  const double normal = travel("");
  EXPECT_LT(normal, -1e-6);
  EXPECT_EQ(travel("slider_stalled: true"), 0.0);
  const double sticky = travel("friction_scale: 1.5");
  idm::model::StageParams stage;
  stage.friction_coefficient *= 1.5;
  idm::model::ImpulseEventSimulator model(stage);
  model.run(w);
  model.advance(d_settle_s);
  EXPECT_NEAR(sticky, model.position_m(), 1e-12);
  EXPECT_GT(std::fabs(sticky - normal), 1e-7);

  // and at run time
  Device d = sim_device("sim: {plant: rigid}\ndaq: {sim: {output: parameters}}");
  bring_up(d);
  d.sim->set_slider_stalled(true);
  ASSERT_TRUE(d.output->write_burst_parameters(w).ok());
  ASSERT_TRUE(d.output->start().ok());
  EXPECT_EQ(d.sim->true_position_m(), 0.0);
  d.sim->set_slider_stalled(false);
  d.sim->set_friction_scale(1.5);
  ASSERT_TRUE(d.output->start().ok());
  EXPECT_NEAR(d.sim->true_position_m(), sticky, 1e-12);
}

TEST(SimFaults, DisconnectFailsEveryCallUntilReconnect) {
  Device d = sim_device("daq: {sim: {output: parameters}}");
  bring_up(d);
  ASSERT_TRUE(d.output->write_burst_parameters(TriangleWave{200, 0.1, 20e-6, 2}).ok());
  d.sim->disconnect();
  std::uint64_t word = 0;
  bool done = false;
  std::size_t n = 0;
  TimedWord buf[4];
  for (const DriverStatus& s :
       {d.output->start(), d.output->stop(), d.output->is_done(done), d.interferometer->latch(word),
        d.interferometer->read_stream(buf, 4, n),
        d.output->write_burst_parameters(TriangleWave{200, 0.1, 20e-6, 2})}) {
    EXPECT_EQ(s.error, DriverError::Disconnected);
    EXPECT_NE(s.message.find("disconnected"), std::string::npos) << s.message;
  }
  d.sim->reconnect();
  EXPECT_TRUE(d.output->start().ok());
  EXPECT_TRUE(d.interferometer->latch(word).ok());

  Device cold = sim_device("daq: {sim: {faults: {disconnected: true}}}");
  const DriverStatus s = cold.configure();
  EXPECT_EQ(s.error, DriverError::Disconnected);
  EXPECT_NE(s.message.find("sim interferometer: configure: "), std::string::npos) << s.message;
  EXPECT_EQ(cold.interferometer->state(), LifecycleState::Unconfigured);
}

TEST(SimFaults, TimeoutsFailReadsWithATimeout) {
  Device d = sim_device("daq: {sim: {timeout_s: 0.2}}");
  bring_up(d);
  d.sim->set_timeouts(true);
  std::uint64_t word = 0;
  DriverStatus s = d.interferometer->latch(word);
  EXPECT_EQ(s.error, DriverError::Timeout);
  EXPECT_NE(s.message.find("0.2 s"), std::string::npos) << s.message;
  TimedWord buf[4];
  std::size_t n = 7;
  EXPECT_EQ(d.interferometer->read_stream(buf, 4, n).error, DriverError::Timeout);
  EXPECT_EQ(n, 0u);
  d.sim->set_timeouts(false);
  EXPECT_TRUE(d.interferometer->latch(word).ok());
}

TEST(SimFaults, AFullStreamMarksTheOverrun) {
  Device d = sim_device("daq: {sim: {stream_capacity: 10}}");
  bring_up(d);
  const std::vector<double> xi = sampled(TriangleWave{200, 0.1, 20e-6, 1}, 1e5);
  ASSERT_TRUE(d.output->write_burst(xi.data(), xi.size(), 1e5).ok());
  ASSERT_TRUE(d.output->start().ok());
  EXPECT_GT(d.sim->stream_dropped(), 0u);
  const Decoded s = drain(d);
  ASSERT_EQ(s.status.size(), 10u);
  EXPECT_NE(s.status.back() & sample_status::kSampleOverrun, 0);
}

// ---- the reference mark ----

namespace {

bool latch_marked(Device& d) {
  std::uint64_t word = 0;
  EXPECT_TRUE(d.interferometer->latch(word).ok());
  return (word & position_word::kReferenceMark) != 0;
}

}  // namespace

TEST(SimReferenceMark, TheWordAfterACrossingCarriesTheMarkEitherWay) {
  const double mark = -0.5e-6;
  Device d = sim_device(
      "sim: {plant: rigid, reference_mark_m: -0.5e-6}\n"
      "daq: {sim: {output: parameters}}");
  bring_up(d);
  EXPECT_TRUE(d.interferometer->capabilities().reference_mark);
  const double count = d.interferometer->capabilities().word.count_m();
  for (int i = 0; i < 3; ++i) EXPECT_FALSE(latch_marked(d)) << "at rest, not crossed";
  // Negative across the mark: exactly one streamed word carries it, the first past the mark.
  for (double duty : {0.1, 0.9}) {
    const TriangleWave w{200, duty, 20.35e-6, 10};
    ASSERT_TRUE(d.output->write_burst_parameters(w).ok());
    ASSERT_TRUE(d.output->start().ok());
    const int sign = duty < 0.5 ? -1 : 1;
    EXPECT_GT(sign * (d.sim->true_position_m() - mark), 1e-7) << "the burst crossed the mark";
    const Decoded s = drain(d);
    EXPECT_EQ(static_cast<std::size_t>(std::count(s.status.begin(), s.status.end(), 0)),
              s.status.size())
        << "all valid";
    ASSERT_EQ(s.marks.size(), 1u) << "duty " << duty;
    const std::size_t k = s.marks[0];
    ASSERT_GT(k, 0u);
    EXPECT_LE(sign * (s.x_m[k - 1] - mark), count) << "the word before: not yet past the mark";
    EXPECT_GE(sign * (s.x_m[k] - mark), -count) << "the marked word: past it";
    EXPECT_FALSE(latch_marked(d)) << "the mark went with the stream's word";
  }
  // A burst that stays on one side: no mark.
  ASSERT_TRUE(d.output->write_burst_parameters(TriangleWave{200, 0.9, 20.35e-6, 3}).ok());
  ASSERT_TRUE(d.output->start().ok());
  EXPECT_TRUE(drain(d).marks.empty());
  // A push across it: the next latch carries the mark, the one after does not.
  d.sim->push(mark - d.sim->true_position_m() - 50e-9);
  EXPECT_TRUE(latch_marked(d));
  EXPECT_FALSE(latch_marked(d));
  d.sim->push(100e-9);
  EXPECT_TRUE(latch_marked(d));
  EXPECT_FALSE(latch_marked(d));
}

TEST(SimReferenceMark, NoMarkConfiguredNoMarkBitAndNoCapability) {
  Device d = sim_device("sim: {plant: rigid}\ndaq: {sim: {output: parameters}}");
  bring_up(d);
  EXPECT_FALSE(d.interferometer->capabilities().reference_mark);
  for (double duty : {0.1, 0.9, 0.9}) {
    ASSERT_TRUE(d.output->write_burst_parameters(TriangleWave{200, duty, 20.35e-6, 10}).ok());
    ASSERT_TRUE(d.output->start().ok());
    EXPECT_TRUE(drain(d).marks.empty());
    EXPECT_FALSE(latch_marked(d));
  }
}
