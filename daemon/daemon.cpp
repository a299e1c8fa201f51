// The daemon's lifecycle: building and opening the devices, the axes, the threads; shutting them
// down; reloading the control settings. The Instrument commands are in commands.cpp.
#include "daemon/daemon.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <limits>
#include <map>
#include <thread>

#include "daemon/reference_file.h"
#include "drivers/backends.h"
#include "drivers/clock.h"
#include "drivers/sim/sim_backend.h"
#include "model/yaml_util.h"

namespace idm::daemon {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

void sleep_s(double s) {
  std::this_thread::sleep_for(std::chrono::duration<double>(s));
}

}  // namespace

Daemon::Daemon(DaemonConfig config) : config_(std::move(config)) {}

Daemon::~Daemon() {
  try {
    shutdown();
  } catch (...) {
  }
}

// ---- start ----

// One link per device; each axis is a channel of its device's link, in the order of the axes.
void Daemon::build_devices() {
  std::map<std::size_t, std::vector<drivers::Device>> channels;
  std::map<std::size_t, std::shared_ptr<drivers::sim::SimCrosstalk>> crosstalk;
  std::vector<std::size_t> link_index(config_.axes.size());
  for (std::size_t i = 0; i < config_.axes.size(); ++i) {
    const AxisConfig& a = config_.axes[i];
    const DeviceConfig& d = config_.devices[a.device];
    YAML::Node doc = a.document;
    doc["channel"] = a.channel;
    // The simulated stage's hard stops: the file's, or the ends of the travel (AxisConfig::sim).
    if (d.driver == "sim" && std::isfinite(a.sim.end_stop_low_m)) {
      YAML::Node sim = doc["sim"] ? YAML::Clone(doc["sim"]) : YAML::Node(YAML::NodeType::Map);
      if (!sim["end_stops_m"]) {
        YAML::Node stops(YAML::NodeType::Sequence);
        stops.push_back(a.sim.end_stop_low_m);
        stops.push_back(a.sim.end_stop_high_m);
        sim["end_stops_m"] = stops;
      }
      doc["sim"] = sim;
    }
    drivers::Device device;
    try {
      device = drivers::make_backend(d.driver, doc, config_.file);
    } catch (const model::InputError& e) {
      throw StartError(exit_code::kBadConfig, e.what());
    }
    if (device.sim && d.crosstalk_fraction != 0) {
      auto& group = crosstalk[a.device];
      if (!group) group = std::make_shared<drivers::sim::SimCrosstalk>(d.crosstalk_fraction);
      group->add(device.sim.get());
      device.sim->set_crosstalk(group);
    }
    link_index[i] = channels[a.device].size();
    channels[a.device].push_back(std::move(device));
  }
  std::map<std::size_t, drivers::DeviceLink*> by_device;
  for (auto& [device, list] : channels) {
    const DeviceConfig& d = config_.devices[device];
    links_.push_back(std::make_unique<drivers::DeviceLink>(d.name, std::move(list), d.link));
    by_device[device] = links_.back().get();
  }
  for (std::size_t i = 0; i < config_.axes.size(); ++i)
    axes_.push_back(
        std::make_unique<Axis>(config_.axes[i], *by_device[config_.axes[i].device], link_index[i]));
}

void Daemon::open_devices() {
  for (auto& link : links_) {
    if (drivers::DriverStatus s = link->open(); !s.ok()) {
      for (auto& l : links_) l->close();
      throw StartError(exit_code::kNoHardware,
                       s.message + " (" + drivers::driver_error_name(s.error) + ")");
    }
  }
}

void Daemon::build_axes() {
  for (auto& axis : axes_) {
    const std::string& name = axis->config().name;
    try {
      axis->build(axis->config().control);
    } catch (const model::InputError& e) {
      throw StartError(exit_code::kBadConfig,
                       axes_.size() > 1 ? "axis " + name + ": " + e.what() : std::string(e.what()));
    }
    const std::string& file = axis->config().control.calibration_file;
    if (axis->calibration() && !file.empty() && std::filesystem::exists(file)) {
      std::string error;
      // A file idmd cannot read is never overwritten: it does not start on it.
      if (!axis->calibration()->load(file, error))
        throw StartError(exit_code::kBadConfig,
                         "axis " + name + ": control.calibration_file: " + error +
                             "; idmd does not overwrite a file it cannot read: fix it or move "
                             "it away");
      else
        axis->build(axis->config().control);  // the snapshot from the loaded state
    }
    restore_reference(*axis);
  }
}

void Daemon::restore_reference(Axis& axis) {
  const std::string& file = axis.config().reference_file;
  if (file.empty() || !std::filesystem::exists(file)) return;
  const std::string name = "axis " + axis.config().name + ": ";
  try {
    const SavedReference saved = load_reference(file);
    const drivers::CountOrigin now = axis.link().count_origin(axis.channel());
    if (const std::string why = reference_holds(saved, now); !why.empty()) {
      start_notes_.push_back({saved.referenced, name + "not referenced (" + file + "): " + why});
      return;
    }
    axis.link().continue_count(axis.channel(), saved.origin.offset_counts);
    axis.restore_reference(saved.offset_m);
    axis.set_user_offset_m(saved.user_offset_m);
    start_notes_.push_back(
        {false, name + "referenced as before the restart (" + file +
                    "; the device kept its count, epoch " + std::to_string(now.epoch) + ")" +
                    (saved.user_offset_m != 0
                         ? "; user offset " + model::format_number(saved.user_offset_m) + " m"
                         : "")});
  } catch (const model::InputError& e) {
    throw StartError(exit_code::kBadConfig,
                     name + "reference_file: " + e.what() +
                         "; idmd does not overwrite a file it cannot read: fix it or move it "
                         "away");
  }
}

void Daemon::wait_until_ready() {
  const double deadline = drivers::monotonic_s() + config_.server.ready_timeout_s;
  for (;;) {
    bool ready = true;
    for (const auto& a : axes_) ready = ready && a->published().motion.position_valid;
    if (ready) return;
    if (drivers::monotonic_s() > deadline || !loop_->running()) break;
    sleep_s(1e-3);
  }
  std::string which;
  for (const auto& a : axes_) {
    if (a->published().motion.position_valid) continue;
    const drivers::LinkHealth h = a->link().health();
    which += (which.empty() ? "" : "; ") + std::string("axis ") + a->config().name + " on device " +
             a->link().name() + " (" + drivers::link_state_name(h.state) +
             (h.message[0] ? std::string(": ") + h.message : std::string()) + ")";
  }
  throw StartError(exit_code::kNoHardware,
                   "no valid position within server.ready_timeout_s (" +
                       model::format_number(config_.server.ready_timeout_s) + " s): " + which);
}

void Daemon::open_data_dir() {
  std::error_code ec;  // the configured data directory itself may be created
  std::filesystem::create_directories(config_.recording.data_dir, ec);
  try {
    data_dir_ = recording::DirFd::open(config_.recording.data_dir);
    data_dir_error_.clear();
  } catch (const std::exception& e) {
    data_dir_error_ = e.what();
  }
}

std::string Daemon::start() {
  if (started_) return {};
  open_data_dir();
  if (!data_dir_.valid())
    start_notes_.push_back({true, "recording.data_dir: " + data_dir_error_ + " (SWEEP will fail)"});
  build_devices();
  open_devices();
  try {
    build_axes();
  } catch (...) {
    for (auto& l : links_) l->close();
    throw;
  }
  std::vector<Axis*> axes;
  std::vector<drivers::DeviceLink*> links;
  for (auto& a : axes_) axes.push_back(a.get());
  for (auto& l : links_) links.push_back(l.get());
  supervisor_ = std::make_unique<MotionSupervisor>(axes);
  loop_ = std::make_unique<RtLoop>(config_.realtime, *supervisor_);
  if (loop_hook_) loop_->set_thread_hook(loop_hook_);
  for (auto& l : links_) l->start_thread();
  started_ = true;
  std::string warning = loop_->start();
  try {
    wait_until_ready();
  } catch (...) {
    shutdown();
    throw;
  }
  sweeps_ = std::make_unique<SweepRunner>(*supervisor_, axes);
  housekeeping_ = std::make_unique<Housekeeping>(axes, links, *supervisor_, *sweeps_,
                                                 control_mutex_, *this, *loop_);
  housekeeping_->start();
  return warning;
}

// ---- shutdown ----

bool Daemon::wait_at_rest(double timeout_s) {
  const double deadline = drivers::monotonic_s() + timeout_s;
  while (!supervisor_->at_rest() || (sweeps_ && sweeps_->active())) {
    if (!loop_->running() || drivers::monotonic_s() > deadline) return false;
    sleep_s(1e-3);
  }
  return true;
}

void Daemon::shutdown(const std::string& why) {
  if (!started_ || shut_down_) return;
  shut_down_ = true;
  if (sweeps_) sweeps_->abort(why);  // before the loop stops its trial: the sweep says why
  supervisor_->request_stop_all();
  double longest_chunk = 0;
  for (const auto& a : axes_)
    longest_chunk = std::max(longest_chunk, a->control().positioner.max_chunk_s);
  // The playing chunks end by themselves (at most max_chunk_s); trials are stopped at once.
  wait_at_rest(std::max(2.0, 4 * longest_chunk));
  if (sweeps_) sweeps_->quit();
  if (housekeeping_) housekeeping_->quit();  // the last calibration saves
  loop_->stop();
  for (auto& l : links_) l->stop_thread();
  // The threads have ended: this thread owns the devices again.
  for (auto& l : links_) l->close();
}

// ---- reload ----

std::string Daemon::prepare_reload(bool limits_from_file) {
  std::vector<ControlConfig> fresh;
  try {
    fresh = reload_control_configs(model::load_yaml_file(config_.file), config_.file, config_);
  } catch (const std::exception& e) {
    return e.what();
  }
  std::lock_guard<std::mutex> lock(control_mutex_);
  // Build what allocates most (a changed map) before parking.
  try {
    for (std::size_t i = 0; i < axes_.size(); ++i) axes_[i]->prepare(fresh[i]);
  } catch (const std::exception& e) {
    return e.what();
  }
  reload_plan_ = std::move(fresh);
  reload_limits_from_file_ = limits_from_file;
  return {};
}

std::string Daemon::apply_reload() {
  std::lock_guard<std::mutex> lock(control_mutex_);
  // Parked: the loop touches no axis until unparked.
  std::string build_error;
  for (std::size_t i = 0; i < axes_.size() && i < reload_plan_.size(); ++i) {
    Axis& a = *axes_[i];
    const ControlConfig old = a.control();
    if (reload_limits_from_file_)
      a.set_soft_limits_now(reload_plan_[i].positioner.soft_lower_m,
                            reload_plan_[i].positioner.soft_upper_m);
    try {
      a.build(reload_plan_[i]);
    } catch (const std::exception& e) {
      if (build_error.empty()) build_error = "axis " + a.config().name + ": " + e.what();
      a.set_soft_limits_now(a.published().soft_lower_m, a.published().soft_upper_m);
      a.prepare(old);
      a.build(old);
    }
  }
  reload_plan_.clear();
  supervisor_->request_park(MotionSupervisor::Park::None);
  while (supervisor_->parked() && loop_->running()) sleep_s(1e-5);
  return build_error;
}

bool Daemon::reload_control(std::string& error, SoftLimits limits) {
  if (error = prepare_reload(limits == SoftLimits::FromFile); !error.empty()) return false;
  double longest_chunk = 0;
  for (const auto& a : axes_)
    longest_chunk = std::max(longest_chunk, a->control().positioner.max_chunk_s);
  for (const ControlConfig& c : reload_plan_)
    longest_chunk = std::max(longest_chunk, c.positioner.max_chunk_s);
  // The motions stop at their chunks' ends (a *RST stops motion by definition).
  supervisor_->request_park(MotionSupervisor::Park::Stop);
  const double deadline = drivers::monotonic_s() + std::max(2.0, 4 * longest_chunk);
  while (!supervisor_->parked()) {
    if (drivers::monotonic_s() > deadline || !loop_->running()) {
      supervisor_->request_park(MotionSupervisor::Park::None);
      reload_plan_.clear();
      error = "the real-time loop did not come to rest within the timeout (motion in progress?)";
      return false;
    }
    sleep_s(1e-4);
  }
  error = apply_reload();
  return error.empty();
}

void Daemon::request_reload(const std::string& why) {
  if (housekeeping_) housekeeping_->request_reload(true, why);
}

bool Daemon::reload_pending() const {
  return housekeeping_ && housekeeping_->reload_pending();
}

// ---- tests and tools ----

drivers::sim::SimBackend* Daemon::sim(int axis) {
  if (axis < 0 || static_cast<std::size_t>(axis) >= axes_.size()) return nullptr;
  Axis& a = *axes_[static_cast<std::size_t>(axis)];
  return a.link().device(a.channel()).sim.get();
}

double Daemon::sim_output_m(int axis) {
  drivers::sim::SimBackend* s = sim(axis);
  return s ? s->commanded_elongation_m() : kNaN;
}

std::string Daemon::last_sweep_report() const {
  return sweeps_ ? sweeps_->report() : std::string();
}

std::vector<Housekeeping::Note> Daemon::take_notes() {
  std::vector<Housekeeping::Note> out = std::exchange(start_notes_, {});
  if (housekeeping_)
    for (auto& n : housekeeping_->take_notes()) out.push_back(std::move(n));
  return out;
}

}  // namespace idm::daemon
