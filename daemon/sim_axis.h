// One axis on the simulated device on the synthetic clock: the device behind a DeviceLink that
// is serviced inline, one cycle per tick, as the daemon's I/O thread would, and a positioner
// stepped by step_axis as the daemon's real-time loop does. For tests, benchmarks and tools that
// want the daemon's motion without its threads.
#pragma once

#include <cstdint>
#include <memory>
#include <stdexcept>
#include <vector>

#include "control/calibration.h"
#include "control/positioner.h"
#include "daemon/axis_step.h"
#include "drivers/link.h"
#include "drivers/sim/sim_backend.h"
#include "model/simulation.h"

namespace idm::daemon {

// The realistic plant the positioning benchmark and the controller's tests run on: a
// mass-damper-spring actuator, an amplifier of 3 kHz, Stribeck 1.15, friction varying along the
// guide (relative sd 0.05), 2 nm rms noise; velocity jumps up to 1 m/s accepted by the decoder.
inline drivers::sim::SimDeviceConfig realistic_sim_device(std::uint64_t seed) {
  drivers::sim::SimDeviceConfig c;
  c.sim.plant = model::PlantKind::MassDamperSpring;
  c.sim.effects = {
      model::complete_effect({"amplifier", {{"cutoff_hz", 3000}}}, "realistic_sim_device"),
      model::complete_effect({"stribeck", {{"static_over_kinetic", 1.15}}}, "realistic_sim_device"),
      model::complete_effect({"friction_spread", {{"relative_sd", 0.05}}}, "realistic_sim_device"),
  };
  c.sim.seed = seed;
  c.sim.noise_m = 2e-9;
  c.interferometer.word.max_velocity_m_s = 1.0;
  return c;
}

class SimAxis {
 public:
  std::unique_ptr<drivers::DeviceLink> link;
  drivers::sim::SimBackend* sim = nullptr;
  std::unique_ptr<control::Positioner> positioner;
  PendingRequest pending;

  SimAxis(const control::RegionMap& map, const drivers::sim::SimDeviceConfig& device_config,
          const control::PositionerConfig& config = {}, control::Calibration* calibration = nullptr,
          const control::PlannerConfig& planner = {}) {
    std::vector<drivers::Device> channels;
    channels.push_back(drivers::sim::make_sim_device(device_config));
    sim = channels.back().sim.get();
    link = std::make_unique<drivers::DeviceLink>("sim", std::move(channels), drivers::LinkConfig{});
    if (drivers::DriverStatus s = link->open(); !s.ok()) throw std::runtime_error(s.message);
    positioner = std::make_unique<control::Positioner>(
        map, planner, config,
        axis_device_info(link->output_capabilities(0), link->interferometer_capabilities(0)),
        calibration);
    tick();  // the first reading
  }
  ~SimAxis() { link->close(); }
  SimAxis(const SimAxis&) = delete;
  SimAxis& operator=(const SimAxis&) = delete;

  // One cycle at the simulated time: the link, then the positioner.
  void tick() {
    link->service(sim->now_s());
    step_axis(link->port(0), *positioner, sim->now_s(), pending);
    link->service(sim->now_s());  // what the positioner asked for, at once (as a fast I/O thread)
  }
  // Ticks every tick_s of simulated time until the positioner is at rest or timeout_s passed.
  control::MotionState run(double timeout_s = 60, double tick_s = 1e-4) {
    const double t0 = sim->now_s();
    tick();
    while (!positioner->at_rest() && sim->now_s() - t0 < timeout_s) {
      sim->advance_s(tick_s);
      tick();
    }
    return positioner->status().state;
  }
  // Ticks every 0.1 ms of simulated time for duration_s, whatever the state.
  void run_for(double duration_s) {
    const double end = sim->now_s() + duration_s;
    while (sim->now_s() < end) {
      sim->advance_s(1e-4);
      tick();
    }
  }
  // Ticks until pred() holds or the positioner is at rest; returns pred().
  template <class Pred>
  bool run_until(Pred&& pred, double timeout_s = 60) {
    const double t0 = sim->now_s();
    while (!pred() && !positioner->at_rest() && sim->now_s() - t0 < timeout_s) {
      sim->advance_s(1e-4);
      tick();
    }
    return pred();
  }
};

}  // namespace idm::daemon
