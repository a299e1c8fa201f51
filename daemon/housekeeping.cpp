#include "daemon/housekeeping.h"

#include <chrono>
#include <utility>

#include "drivers/clock.h"
#include "recording/durable_file.h"

namespace idm::daemon {

Housekeeping::Housekeeping(std::vector<Axis*> axes, std::vector<drivers::DeviceLink*> links,
                           MotionSupervisor& supervisor, SweepRunner& sweeps,
                           std::mutex& control_mutex, Reloader& reloader, const RtLoop& loop)
    : axes_(std::move(axes)),
      links_(std::move(links)),
      supervisor_(supervisor),
      sweeps_(sweeps),
      control_mutex_(control_mutex),
      reloader_(reloader),
      loop_(loop),
      saved_updates_(axes_.size(), 0),
      save_errors_(axes_.size()),
      saved_references_(axes_.size()),
      reference_errors_(axes_.size()),
      reference_reconnects_(axes_.size(), 0),
      notes_dropped_(axes_.size(), 0),
      errors_(axes_.size()) {
  for (std::size_t i = 0; i < axes_.size(); ++i)
    saved_updates_[i] = axes_[i]->calibration_snapshot().total_updates;
  for (drivers::DeviceLink* l : links_) seen_health_.push_back(l->health());
}

Housekeeping::~Housekeeping() {
  quit();
}

void Housekeeping::start() {
  thread_ = drivers::StackThread("idmd-house", drivers::kSmallStackBytes * 4, [this] { main(); });
}

void Housekeeping::quit() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (quit_ && !thread_.joinable()) return;
    quit_ = true;
  }
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
  watch_links();
  watch_motions();
  watch_sweep();  // a sweep the shutdown stopped (the runner has ended before this)
  for (std::size_t i = 0; i < axes_.size(); ++i) {
    save_calibration(i, true);
    save_reference(i);
  }
}

std::vector<Housekeeping::Note> Housekeeping::take_notes() {
  std::lock_guard<std::mutex> lock(mutex_);
  return std::exchange(notes_, {});
}

ErrorNote Housekeeping::error(std::size_t axis) const {
  std::lock_guard<std::mutex> lock(mutex_);
  return axis < errors_.size() ? errors_[axis] : ErrorNote{};
}

void Housekeeping::main() {
  std::unique_lock<std::mutex> lock(mutex_);
  while (!quit_) {
    cv_.wait_for(lock, std::chrono::milliseconds(50), [&] { return quit_; });
    if (quit_) break;
    lock.unlock();
    cycle();
    lock.lock();
  }
}

void Housekeeping::cycle() {
  watch_links();
  watch_motions();
  watch_sweep();
  if (std::string w = miss_watch_.update(loop_.stats(), drivers::monotonic_s()); !w.empty())
    add_note(true, std::move(w));
  reload_cycle();
  if (supervisor_.at_rest())
    for (std::size_t i = 0; i < axes_.size(); ++i) save_calibration(i, false);
  for (std::size_t i = 0; i < axes_.size(); ++i) save_reference(i);
}

void Housekeeping::watch_motions() {
  for (std::size_t i = 0; i < axes_.size(); ++i) {
    Axis& axis = *axes_[i];
    MotionNote n;
    while (axis.take_motion_note(n)) add_note(true, motion_note_text(axis.config().name, n));
    if (const std::uint64_t dropped = axis.motion_notes_dropped(); dropped != notes_dropped_[i]) {
      add_note(true, "axis " + axis.config().name + ": " +
                         std::to_string(dropped - notes_dropped_[i]) +
                         " faults or failed motions came too fast to be logged");
      notes_dropped_[i] = dropped;
    }
  }
  for (const std::string& line : sweeps_.take_trial_notes()) add_note(true, line);
}

void Housekeeping::watch_sweep() {
  const std::string r = sweeps_.report();
  if (r == seen_report_) return;
  seen_report_ = r;
  const SweepStatus s = sweeps_.status();
  // Failed trials, or a sweep stopped before its end, are the axis's error (SWEEP? says which);
  // a stopped sweep's error is dated when the stop came, so the *RST that stopped it clears it.
  if (s.failed > 0 || s.state == "STOPPED") {
    if (s.axis >= 0 && static_cast<std::size_t>(s.axis) < axes_.size())
      set_error(static_cast<std::size_t>(s.axis), r,
                s.state == "STOPPED" ? sweeps_.abort_time_s() : drivers::monotonic_s());
    add_note(s.failed > 0, r);
  } else {
    add_note(false, r);
  }
}

void Housekeeping::request_reload(bool limits_from_file, std::string why) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (reload_pending_.load(std::memory_order_acquire)) return;  // joins the one on its way
  reload_from_file_ = limits_from_file;
  reload_why_ = std::move(why);
  reload_pending_.store(true, std::memory_order_release);
}

void Housekeeping::reload_cycle() {
  if (!reload_pending_.load(std::memory_order_acquire)) return;
  std::string why;
  bool from_file = false;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    why = reload_why_;
    from_file = reload_from_file_;
  }
  const auto done = [&](const std::string& error) {
    if (error.empty()) {
      add_note(false, why + ": control settings reloaded");
    } else {
      for (std::size_t i = 0; i < axes_.size(); ++i) set_error(i, why + ": " + error);
      add_note(true, why + ": reload failed, the old settings stay: " + error);
    }
    reload_phase_ = ReloadPhase::Idle;
    reload_pending_.store(false, std::memory_order_release);
  };
  if (reload_phase_ == ReloadPhase::Idle) reload_phase_ = ReloadPhase::Requested;
  if (reload_phase_ == ReloadPhase::Requested) {
    if (sweeps_.active()) return;  // the sweep winds down first
    if (const std::string e = reloader_.prepare_reload(from_file); !e.empty()) return done(e);
    if (!supervisor_.at_rest())
      add_note(false, why +
                          ": the reload waits for the motions in progress to end (new ones "
                          "are refused until then)");
    supervisor_.request_park(MotionSupervisor::Park::Wait);
    reload_phase_ = ReloadPhase::Parking;
  }
  if (reload_phase_ == ReloadPhase::Parking && supervisor_.parked()) done(reloader_.apply_reload());
}

void Housekeeping::save_calibration(std::size_t i, bool force) {
  Axis& axis = *axes_[i];
  std::string path;
  control::CalibrationConfig cal_config;
  {
    std::lock_guard<std::mutex> lock(control_mutex_);
    path = axis.control().calibration_file;
    cal_config = axis.control().calibration;
  }
  const control::CalibrationState state = axis.calibration_snapshot();
  if (!force && state.total_updates == saved_updates_[i]) return;
  if (force && state.total_updates == saved_updates_[i] && save_errors_[i].empty()) return;
  saved_updates_[i] = state.total_updates;  // a failure is retried at the next change
  if (path.empty() || axis.calibration() == nullptr) return;
  std::string error;
  try {
    // A copy of the loop's calibration, so that the loop's own object is never read here (its
    // set_state checks the snapshot belongs to this stage).
    control::Calibration copy(axis.config().stage.stage, cal_config);
    copy.set_state(state);
    recording::write_file_durably(path, control::Calibration::serialize(copy.state()));
  } catch (const std::exception& e) {
    error = e.what();
  }
  if (error.empty())
    save_errors_[i].clear();
  else
    save_failed(i, save_errors_[i], "cannot save the calibration to " + path + ": " + error);
}

void Housekeeping::save_failed(std::size_t i, std::string& last, const std::string& text) {
  set_error(i, text);
  if (text != last) add_note(true, text);  // once per distinct failure
  last = text;
}

void Housekeeping::save_reference(std::size_t i) {
  Axis& axis = *axes_[i];
  const std::string& path = axis.config().reference_file;
  if (path.empty()) return;
  // Just reconnected: the loop may not have seen yet whether the count was kept (and cleared the
  // referenced flag if not). The next look, 50 ms on, has.
  const drivers::LinkHealth h = axis.link().health();
  const bool settled =
      h.state == drivers::LinkState::Up && h.reconnects == reference_reconnects_[i];
  reference_reconnects_[i] = h.reconnects;
  if (!settled) return;
  const AxisPublished p = axis.published();
  SavedReference now;
  now.referenced = p.referenced;
  if (now.referenced) {
    now.origin = axis.link().count_origin(axis.channel());
    now.offset_m = p.motion.offset_m;
    now.user_offset_m = axis.user_offset_m();
  }
  if (saved_references_[i] && *saved_references_[i] == now) return;
  try {
    daemon::save_reference(path, now, axis.config().name);
    saved_references_[i] = now;
    reference_errors_[i].clear();
  } catch (const std::exception& e) {
    save_failed(i, reference_errors_[i], "cannot save the reference to " + path + ": " + e.what());
  }
}

void Housekeeping::watch_links() {
  for (std::size_t k = 0; k < links_.size(); ++k) {
    const drivers::LinkHealth h = links_[k]->health();
    drivers::LinkHealth& seen = seen_health_[k];
    const std::string device = "device " + links_[k]->name();
    if (h.losses != seen.losses) {
      const std::string text =
          device + " lost: " + h.message + " (the output is stopped; reconnecting by itself)";
      add_note(true, text);
      for (std::size_t i = 0; i < axes_.size(); ++i)
        if (&axes_[i]->link() == links_[k]) set_error(i, text);
    } else if (h.message_version != seen.message_version && h.message[0] != '\0' &&
               h.state == drivers::LinkState::Lost) {
      add_note(false, device + " still lost: " + h.message);
    }
    if (h.reconnects != seen.reconnects) {
      std::string text = device + " back after " + std::to_string(h.reconnects) + " reconnect" +
                         (h.reconnects == 1 ? "" : "s");
      for (std::size_t i = 0; i < axes_.size(); ++i) {
        if (&axes_[i]->link() != links_[k]) continue;
        if (!axes_[i]->published().referenced)
          text += "; axis " + axes_[i]->config().name + " not referenced";
      }
      add_note(true, text);
    }
    if (h.readings_dropped != seen.readings_dropped && seen.readings_dropped == 0)
      add_note(true, device + ": a controller's queue was full, readings were dropped");
    seen = h;
  }
}

void Housekeeping::add_note(bool warning, std::string text) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (notes_.size() < 200) notes_.push_back({warning, std::move(text)});
}

void Housekeeping::set_error(std::size_t axis, const std::string& text, double t_s) {
  ErrorNote note;
  set_note(note, t_s < 0 ? drivers::monotonic_s() : t_s, text.c_str());
  std::lock_guard<std::mutex> lock(mutex_);
  if (axis < errors_.size()) errors_[axis] = note;
}

}  // namespace idm::daemon
