// A positioner on the real `sim` backend (synthetic clock) for the control tests
// (daemon/sim_axis.h), and the maps and plants they use.
#pragma once

#include <memory>
#include <stdexcept>
#include <vector>

#include "control/calibration.h"
#include "control/positioner.h"
#include "daemon/sim_axis.h"
#include "drivers/sim/sim_backend.h"

namespace idm::control::test_rig {

// The map of the tests: the device's default limits but strokes down to 0.1 um (the finest
// robustly one-step steps near cut-off shrink with the stroke: about 4 nm on the ideal plant
// instead of 37 nm at 1 um), 10 Hz x duty 0.005 x 6 strokes; about 0.15 s to build, so once per
// test file.
inline RegionMapConfig rig_map_config(double step_correction) {
  RegionMapConfig c;
  c.stage.step_correction = step_correction;
  c.limits.min_stroke_m = 0.1e-6;
  c.grid = RegionGrid::covering(c.limits, 10, 0.005, 6);
  return c;
}

// The map of the ideal plant (alpha 1), built once.
inline const RegionMap& ideal_map() {
  static const RegionMap map(rig_map_config(1.0));
  return map;
}

using Rig = daemon::SimAxis;

// The ideal plant: the rigid plant is the impulse model's event simulation (alpha = 1).
inline drivers::sim::SimDeviceConfig ideal_device() {
  drivers::sim::SimDeviceConfig c;
  c.sim.plant = model::PlantKind::Rigid;
  // The slider's velocity jumps reach about 0.5 m/s at 2 kHz: the decoder must accept them.
  c.interferometer.word.max_velocity_m_s = 1.0;
  return c;
}

// The realistic plant (daemon::realistic_sim_device, as the positioning benchmark's).
inline drivers::sim::SimDeviceConfig realistic_device(std::uint64_t seed) {
  return daemon::realistic_sim_device(seed);
}
// The map for it: alpha 0.763 (what one 200-cycle burst at 200 Hz / duty 0.1 measures there).
inline RegionMapConfig realistic_map_config() {
  return rig_map_config(0.7628);
}

}  // namespace idm::control::test_rig
