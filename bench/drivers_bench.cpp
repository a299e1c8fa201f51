// Drivers benchmarks, each side by side with its reference in the same run:
//   1. position-sample ingest (decode, unwrap, to metres) against a plain memcpy of the same
//   buffer;
//   2. the simulated stage's real-time factor: a 100 kHz burst through the `sim` backend with the
//      mass-damper-spring plant, wall time against the simulated time it covers.
//   drivers_bench [--quick]
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <vector>

#include "drivers/backends.h"
#include "drivers/position_word.h"
#include "model/waveform.h"

using namespace idm::drivers;

namespace {
double now_s() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}
template <class F>
double best_of(int runs, F&& f) {
  double best = 1e300;
  for (int r = 0; r < runs; ++r) {
    const double t0 = now_s();
    f();
    best = std::min(best, now_s() - t0);
  }
  return best;
}
}  // namespace

int main(int argc, char** argv) {
  const bool quick = argc > 1 && std::strcmp(argv[1], "--quick") == 0;

  // 1. Ingest: 36-bit words of a slider moving back and forth across the counter's wrap.
  PositionWordConfig cfg;
  cfg.width = WordWidth::Bits36;
  cfg.sample_interval_s = 1e-5;
  cfg.max_velocity_m_s = 0.1;
  const std::size_t n = quick ? (1u << 18) : (1u << 23);
  std::vector<std::uint64_t> words(n), copy(n);
  const std::int64_t wrap = std::int64_t{1} << 35;
  for (std::size_t i = 0; i < n; ++i) {
    const double counts =
        wrap - 5000.0 + 20000.0 * std::sin(2e-4 * static_cast<double>(i)) + (i % 7);
    words[i] =
        encode_position_word(static_cast<std::int64_t>(counts), cfg.width, position_word::kValid);
  }
  std::vector<double> metres(n);
  std::vector<std::uint8_t> status(n);
  PositionDecoder decoder(cfg);
  const int runs = quick ? 3 : 9;
  const double t_decode = best_of(runs, [&] {
    decoder.reset();
    decoder.decode(words.data(), n, metres.data(), status.data());
  });
  const double t_copy =
      best_of(runs, [&] { std::memcpy(copy.data(), words.data(), n * sizeof(std::uint64_t)); });
  std::size_t invalid = 0;
  for (std::uint8_t s : status) invalid += s != 0;
  std::printf("ingest: %zu 36-bit words, best of %d\n", n, runs);
  std::printf("  decode+unwrap+metres: %8.1f M words/s\n", n / t_decode / 1e6);
  std::printf("  memcpy (reference):   %8.1f M words/s\n", n / t_copy / 1e6);
  std::printf("  ratio decode/memcpy:  %8.3f   (invalid samples: %zu, checksum %.6g)\n",
              t_copy / t_decode, invalid, metres[n / 2] + static_cast<double>(copy[n / 3] & 0xff));

  // 2. Real-time factor of the simulated stage, synthetic clock, mass-damper-spring plant.
  const double seconds = quick ? 0.05 : 1.0;
  Device dev = make_backend(
      "sim", YAML::Load("sim: {plant: mck}\ndaq: {sim: {stream_rate_hz: 100000}}"), "bench.yaml");
  if (!dev.configure().ok() || !dev.activate().ok()) {
    std::fprintf(stderr, "drivers_bench: sim device did not come up\n");
    return 1;
  }
  const idm::model::TriangleWave wave{200.0, 0.1, 20.35e-6, static_cast<int>(seconds * 200)};
  std::vector<double> xi;
  idm::model::sample(wave, 1e5, 0.0,
                     static_cast<std::size_t>(std::lround(wave.duration_s() * 1e5)) + 1, xi);
  xi.back() = 0.0;
  std::vector<TimedWord> buf(1u << 16);
  std::size_t samples = 0;
  const double t_sim = best_of(quick ? 1 : 3, [&] {
    samples = 0;
    dev.output->write_burst(xi.data(), xi.size(), 1e5);
    dev.output->start();
    dev.output->wait_done(1e6);
    for (std::size_t got = 1; got > 0;) {
      dev.interferometer->read_stream(buf.data(), buf.size(), got);
      samples += got;
    }
  });
  const double simulated_s = static_cast<double>(xi.size()) / 1e5;
  std::printf("sim stage: %.3g s of a 200 Hz burst at 100 kHz (mck plant), %zu stream words\n",
              simulated_s, samples);
  std::printf("  wall %.4f s, real-time factor %.1fx (simulated s per wall s)\n", t_sim,
              simulated_s / t_sim);
  dev.shutdown();
  return 0;
}
