// Housekeeping: the daemon's slow thread. Every 50 ms it saves each axis's calibration once the
// motion that changed it is done (crash-safe, control::Calibration::save; a failure is logged
// once per distinct failure and kept as the axis's daemon error), saves each axis's reference to
// its reference_file when it changed (daemon/reference_file.h), watches the device links'
// health (a device lost or back becomes a log line naming the device, and the axes' error), logs
// every axis's faults and failed motions (one line each, from the loop's notes) and the sweep's
// failed trials, warns when the real-time loop misses too many deadlines, hands the sweep
// runner's report to the log, and carries out the reloads that wait (SIGHUP, and a *RST that
// came during a sweep): once no sweep runs, it parks the loop without stopping anything (new
// motions are refused meanwhile) and swaps the settings once every motion in progress has ended,
// so that a reload never cuts another client's move short. It touches no device and never blocks
// the loop; idmd's main thread takes its notes.
#pragma once

#include <atomic>
#include <condition_variable>
#include <functional>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "daemon/axis.h"
#include "daemon/reference_file.h"
#include "daemon/rt_loop.h"
#include "daemon/supervisor.h"
#include "daemon/sweep_runner.h"
#include "drivers/link.h"
#include "drivers/thread.h"

namespace idm::daemon {

// What carries out a reload (the daemon core): prepare_reload() reads the file and builds what
// allocates, apply_reload() swaps the settings with the loop parked and lets it go; each returns
// "" or why it failed (the old settings then stay).
class Reloader {
 public:
  virtual ~Reloader() = default;
  virtual std::string prepare_reload(bool limits_from_file) = 0;
  virtual std::string apply_reload() = 0;
};

class Housekeeping {
 public:
  // `control_mutex`: held by whoever rebuilds an axis's settings (reads of them take it too).
  // `loop`: its deadline misses are watched (a warning when too many, at most one a minute).
  Housekeeping(std::vector<Axis*> axes, std::vector<drivers::DeviceLink*> links,
               MotionSupervisor& supervisor, SweepRunner& sweeps, std::mutex& control_mutex,
               Reloader& reloader, const RtLoop& loop);
  ~Housekeeping();  // quit()
  Housekeeping(const Housekeeping&) = delete;
  Housekeeping& operator=(const Housekeeping&) = delete;

  void start();
  // Ends the thread; then saves every calibration one last time (the caller's thread).
  void quit();
  // A reload that waits for the running sweep, then for every motion in progress, to end (SIGHUP:
  // the soft limits from the file; a *RST during a sweep: kept); pending until it is done. `why`
  // names it in the log ("SIGHUP", "*RST after the sweep"). A second request while one is
  // pending joins it.
  void request_reload(bool limits_from_file, std::string why);
  bool reload_pending() const { return reload_pending_.load(std::memory_order_acquire); }
  // Lines to log (warnings and news) since the last call.
  struct Note {
    bool warning = true;
    std::string text;
  };
  std::vector<Note> take_notes();
  // A line to log from another thread (the server's: a user offset set).
  void note(bool warning, std::string text) { add_note(warning, std::move(text)); }
  // The latest housekeeping error of an axis (a failed save, a device lost, a sweep's failures),
  // with when it happened; *RST hides the ones before it.
  ErrorNote error(std::size_t axis) const;

 private:
  void main();
  void cycle();
  void save_calibration(std::size_t axis, bool force);
  void save_reference(std::size_t axis);
  // A failed save: the axis's error, logged once per distinct failure.
  void save_failed(std::size_t axis, std::string& last, const std::string& text);
  void watch_links();
  void watch_sweep();  // the sweep runner's report of a sweep that ended, to the log
  // Every axis's faults and failed motions (Axis::take_motion_note) and the sweep's failed
  // trials, one log line each.
  void watch_motions();
  void add_note(bool warning, std::string text);
  void set_error(std::size_t axis, const std::string& text, double t_s = -1);

  std::vector<Axis*> axes_;
  std::vector<drivers::DeviceLink*> links_;
  MotionSupervisor& supervisor_;
  SweepRunner& sweeps_;
  std::mutex& control_mutex_;
  Reloader& reloader_;
  const RtLoop& loop_;
  DeadlineMissWatch miss_watch_;  // housekeeping's thread
  // The pending reload: requested, then parking (the loop waits for the motions to end).
  enum class ReloadPhase : std::uint8_t { Idle, Requested, Parking };
  void reload_cycle();
  ReloadPhase reload_phase_ = ReloadPhase::Idle;  // housekeeping's thread
  bool reload_from_file_ = false;                 // mutex_
  std::string reload_why_;                        // mutex_
  std::vector<std::uint64_t> saved_updates_;
  std::vector<std::string> save_errors_;
  std::vector<std::optional<SavedReference>> saved_references_;  // nullopt: not written yet
  std::vector<std::string> reference_errors_;
  std::vector<std::uint32_t> reference_reconnects_;  // the link's reconnects at the last look
  std::vector<std::uint64_t> notes_dropped_;         // Axis::motion_notes_dropped at the last look
  std::vector<drivers::LinkHealth> seen_health_;
  std::string seen_report_;
  std::atomic<bool> reload_pending_{false};
  mutable std::mutex mutex_;
  std::condition_variable cv_;
  bool quit_ = false;
  std::vector<Note> notes_;        // mutex_
  std::vector<ErrorNote> errors_;  // mutex_
  drivers::StackThread thread_;
};

}  // namespace idm::daemon
