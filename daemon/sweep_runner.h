// The sweep runner: SWEEP's recorder thread. It sends one trial at a time to the motion
// supervisor (the loop plays it on the axis and streams every sample of it through the device
// link's capture queue), collects the samples, adds the commanded elongation from the segment's
// triangle and writes the trial with recording::DatasetWriter (crash-safe, trial by trial). It
// never touches a device. Argument checks happen before (Daemon::sweep); this only runs jobs.
#pragma once

#include <atomic>
#include <condition_variable>
#include <limits>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "daemon/axis.h"
#include "daemon/instrument.h"
#include "daemon/supervisor.h"
#include "drivers/thread.h"
#include "recording/dataset.h"

namespace idm::daemon {

struct SweepJob {
  int axis = 0;
  std::string dir;
  std::optional<recording::DatasetWriter> writer;
  std::vector<double> freqs_hz, duties;
  int trials = 0;
  int cycles = 0;
  double stroke_m = 0;
  double sample_rate_hz = 0;  // the output clock; 0 for a parameter device
  double rest_s = 0;
  int settle_cycles = 0;
  double span_m = 0;          // a trial farther than this from the sweep's start returns first
  double stream_rate_hz = 0;  // the capture's rate (the trials' sample rate)
};

// The cells the job will play, with the values its trials carry (frequency and duty snapped to the
// output clock), in playing order; cells that snap to the same values are one cell.
std::vector<recording::PlannedCell> planned_cells(const SweepJob& job);

class SweepRunner {
 public:
  SweepRunner(MotionSupervisor& supervisor, std::vector<Axis*> axes);
  ~SweepRunner();  // quit()
  SweepRunner(const SweepRunner&) = delete;
  SweepRunner& operator=(const SweepRunner&) = delete;

  // Starts the job on the runner's thread; false when one is running.
  bool submit(std::unique_ptr<SweepJob> job);
  // Stops the running sweep (the playing trial is stopped by the loop; a trial being written
  // finishes first). `why` is what its dataset (plan.yaml) and the log say stopped it; the first
  // abort of a sweep names it. Any thread.
  void abort(const std::string& why = "stopped by a client (STOP or *RST)");
  // When the last abort() came (CLOCK_MONOTONIC), -1 never: a stopped sweep's error is dated
  // then, so that the *RST that stopped it also clears it.
  double abort_time_s() const { return abort_time_s_.load(std::memory_order_acquire); }
  bool active() const { return active_.load(std::memory_order_acquire); }
  SweepStatus status() const;
  // One line on the last finished sweep ("" before any), for the log.
  std::string report() const;
  // One line per trial that failed since the last call (not the ones a stop interrupted), for
  // the log: the axis, the sweep, the trial's cell, why, where the slider is.
  std::vector<std::string> take_trial_notes();
  void quit();

 private:
  // What one trial did to the sweep: written; failed (the sweep goes on); interrupted (a STOP,
  // *RST or the daemon stopping); or an error that ends the sweep (the motion gate refused it or
  // stopped it, the end of travel, a write failed, the loop did not answer).
  enum class TrialOutcome : std::uint8_t { Written, Failed, Interrupted, EndSweep };
  static bool ends_sweep(TrialOutcome o) {
    return o == TrialOutcome::Interrupted || o == TrialOutcome::EndSweep;
  }
  static bool ends_sweep(TrialFailure why) {
    return why == TrialFailure::Limits || why == TrialFailure::LeftLimits ||
           why == TrialFailure::EndOfTravel || why == TrialFailure::NoPosition;
  }
  // The trials of one cell so far: how far its first trial moved (NaN: none yet).
  struct CellRun {
    double first_moved_m = std::numeric_limits<double>::quiet_NaN();
  };
  void main();
  void run(SweepJob& job);
  void finish(SweepJob& job, TrialOutcome end, std::string first_error);
  TrialOutcome run_trial(SweepJob& job, const TrialRequest& request, CellRun& cell,
                         std::string& first_error);
  // run_trial's steps: the loop starts the trial (or refuses it, or the sweep is stopped), then
  // its samples are taken from the capture queue until the end mark (false: none came in time).
  enum class TrialStart : std::uint8_t { Started, Refused, Interrupted, TimedOut };
  TrialStart await_start(const TrialRequest& request, std::uint32_t& seq, TrialFailure& failure,
                         std::string& why);
  struct CapturedTrial {
    recording::TrialSeries series;
    recording::TrialInfo info;
    bool valid = true;                          // every sample's status was clean
    bool complete = false;                      // the burst played in full
    TrialFailure failure = TrialFailure::None;  // why the loop ended it early
  };
  // "" or why the trial shows the slider against a stop: a cell whose first trial moved clearly
  // moved almost nothing this time.
  std::string end_of_travel(const SweepJob& job, const CapturedTrial& trial, CellRun& cell) const;
  bool capture_trial(SweepJob& job, const TrialRequest& request, std::uint32_t seq,
                     CapturedTrial& out, std::string& why);

  MotionSupervisor& supervisor_;
  std::vector<Axis*> axes_;
  mutable std::mutex mutex_;
  std::condition_variable cv_;
  std::unique_ptr<SweepJob> pending_;
  bool quit_ = false;
  SweepStatus status_;                    // mutex_
  std::string report_;                    // mutex_
  std::vector<std::string> trial_notes_;  // mutex_
  std::atomic<bool> active_{false};
  std::atomic<bool> abort_{false};
  std::atomic<double> abort_time_s_{-1};
  std::string abort_why_;       // mutex_: what the first abort() of the sweep said
  std::uint32_t next_seq_ = 0;  // trial numbers across sweeps (runner thread)
  drivers::StackThread thread_;
};

}  // namespace idm::daemon
