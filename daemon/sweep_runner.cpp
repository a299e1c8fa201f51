#include "daemon/sweep_runner.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <sstream>
#include <thread>
#include <utility>

#include "drivers/clock.h"
#include "model/stage.h"
#include "model/waveform.h"

namespace idm::daemon {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

void nap() {
  std::this_thread::sleep_for(std::chrono::microseconds(500));
}

model::Segment trial_segment(const SweepJob& job, double freq_hz, double duty) {
  return model::make_segment(freq_hz, duty, job.stroke_m, static_cast<std::uint64_t>(job.cycles),
                             job.sample_rate_hz, job.rest_s, job.settle_cycles * (1.0 / freq_hz));
}

}  // namespace

std::vector<recording::PlannedCell> planned_cells(const SweepJob& job) {
  std::vector<recording::PlannedCell> cells;
  for (double f : job.freqs_hz)
    for (double d : job.duties) {
      const model::Segment s = trial_segment(job, f, d);
      auto same = [&](const recording::PlannedCell& c) {
        return recording::same_cell(c, s.freq_hz, s.duty, s.stroke_m);
      };
      if (auto it = std::find_if(cells.begin(), cells.end(), same); it != cells.end())
        it->trials += job.trials;
      else
        cells.push_back({s.freq_hz, s.duty, s.stroke_m, job.trials});
    }
  return cells;
}

SweepRunner::SweepRunner(MotionSupervisor& supervisor, std::vector<Axis*> axes)
    : supervisor_(supervisor), axes_(std::move(axes)) {
  thread_ = drivers::StackThread("idmd-sweep", drivers::kRecorderStackBytes, [this] { main(); });
}

SweepRunner::~SweepRunner() {
  quit();
}

void SweepRunner::abort(const std::string& why) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!abort_.load(std::memory_order_acquire)) {
    abort_why_ = why;
    if (active_.load(std::memory_order_acquire))
      abort_time_s_.store(drivers::monotonic_s(), std::memory_order_release);
  }
  abort_.store(true, std::memory_order_release);
}

void SweepRunner::quit() {
  abort("the daemon stopped");
  {
    std::lock_guard<std::mutex> lock(mutex_);
    quit_ = true;
  }
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

bool SweepRunner::submit(std::unique_ptr<SweepJob> job) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (active_.load() || pending_) return false;
  abort_.store(false, std::memory_order_release);
  abort_why_.clear();
  status_ = SweepStatus{};
  status_.state = "RUNNING";
  status_.axis = job->axis;
  status_.directory = job->dir;
  status_.planned =
      job->freqs_hz.size() * job->duties.size() * static_cast<std::uint64_t>(job->trials);
  active_.store(true, std::memory_order_release);
  pending_ = std::move(job);
  cv_.notify_all();
  return true;
}

SweepStatus SweepRunner::status() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return status_;
}

std::string SweepRunner::report() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return report_;
}

std::vector<std::string> SweepRunner::take_trial_notes() {
  std::lock_guard<std::mutex> lock(mutex_);
  return std::exchange(trial_notes_, {});
}

void SweepRunner::main() {
  for (;;) {
    std::unique_ptr<SweepJob> job;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      cv_.wait(lock, [&] { return quit_ || pending_; });
      if (quit_ && !pending_) return;
      job = std::move(pending_);
    }
    run(*job);
    active_.store(false, std::memory_order_release);
  }
}

void SweepRunner::run(SweepJob& job) {
  std::string first_error;
  const control::MotionStatus at_start =
      axes_[static_cast<std::size_t>(job.axis)]->published().motion;
  // The sweep's start: trials that stray farther than span_m from it, or that the motion gate
  // refuses where the slider is, return there first.
  const double home_m = at_start.position_valid ? at_start.position_m : kNaN;
  double last_m = kNaN;
  std::uint32_t index = 0;
  TrialOutcome end = TrialOutcome::Written;  // Interrupted or EndSweep once it ends early
  for (std::size_t fi = 0; fi < job.freqs_hz.size() && !ends_sweep(end); ++fi) {
    for (std::size_t di = 0; di < job.duties.size() && !ends_sweep(end); ++di) {
      CellRun cell;
      for (int t = 0; t < job.trials && !ends_sweep(end); ++t, ++index) {
        if (abort_.load(std::memory_order_acquire)) {
          end = TrialOutcome::Interrupted;
          break;
        }
        TrialRequest req;
        req.index = index;
        req.seq = 0x80000000u | (++next_seq_ & 0x7FFFFFFFu);  // apart from the positioners' chunks
        req.axis = job.axis;
        req.segment = trial_segment(job, job.freqs_hz[fi], job.duties[di]);
        req.home_m = home_m;
        req.return_to_m = kNaN;
        if (std::isfinite(home_m) && std::isfinite(last_m) &&
            std::fabs(last_m - home_m) > job.span_m)
          req.return_to_m = home_m;
        const TrialOutcome outcome = run_trial(job, req, cell, first_error);
        if (outcome == TrialOutcome::Written)
          last_m = axes_[static_cast<std::size_t>(job.axis)]->published().motion.position_m;
        else if (ends_sweep(outcome))
          end = outcome;
      }
    }
  }
  finish(job, end, first_error);
}

void SweepRunner::finish(SweepJob& job, TrialOutcome end, std::string first_error) {
  // The dataset's mark: complete when the whole plan was played (failed trials are missing from
  // it), stopped (a client, the daemon) or failed (an error that ended it) with why otherwise.
  const bool stopped = end == TrialOutcome::Interrupted;
  const bool failed = end == TrialOutcome::EndSweep;
  std::string why;
  if (stopped) {
    std::lock_guard<std::mutex> lock(mutex_);
    why = !abort_why_.empty()      ? abort_why_
          : supervisor_.stopping() ? "the daemon stopped"
                                   : "stopped";
  }
  if (failed) why = first_error;
  try {
    job.writer->finish(failed    ? recording::SweepStatus::Failed
                       : stopped ? recording::SweepStatus::Stopped
                                 : recording::SweepStatus::Complete,
                       why);
  } catch (const std::exception& e) {
    if (first_error.empty()) first_error = std::string("marking the dataset: ") + e.what();
  }
  std::ostringstream line;
  std::lock_guard<std::mutex> lock(mutex_);
  status_.state = failed || (status_.failed > 0 && status_.written == 0) ? "FAILED"
                  : stopped                                              ? "STOPPED"
                                                                         : "DONE";
  status_.error = failed ? first_error : "";
  line << "sweep " << job.dir << " (axis "
       << axes_[static_cast<std::size_t>(job.axis)]->config().name << "): " << status_.written
       << " trials written, " << status_.failed << " failed"
       << (failed    ? ", ended by an error"
           : stopped ? ", stopped: " + why
                     : "")
       << (first_error.empty() ? "" : " (first: " + first_error + ")");
  report_ = line.str();
}

SweepRunner::TrialStart SweepRunner::await_start(const TrialRequest& req, std::uint32_t& seq,
                                                 TrialFailure& failure, std::string& why) {
  while (!supervisor_.send_trial(req)) {
    if (supervisor_.stopping()) return TrialStart::Interrupted;
    nap();
  }
  // The loop starts it (a Started notice) or says why not.
  const double deadline_s = drivers::monotonic_s() + 60.0;
  TrialNotice notice;
  for (;;) {
    if (supervisor_.next_notice(notice)) {
      if (notice.seq != req.seq) continue;  // a late notice of an earlier trial (or sweep)
      if (notice.kind == TrialNotice::Kind::Started) {
        seq = notice.seq;
        return TrialStart::Started;
      }
      if (notice.why == TrialFailure::Stopped) return TrialStart::Interrupted;
      failure = notice.why;
      why = trial_failure_text(notice.why);
      return TrialStart::Refused;
    }
    if (drivers::monotonic_s() > deadline_s) {
      why = "the loop did not start it within 60 s";
      return TrialStart::TimedOut;
    }
    nap();
  }
}

bool SweepRunner::capture_trial(SweepJob& job, const TrialRequest& req, std::uint32_t seq,
                                CapturedTrial& out, std::string& why) {
  out.failure = TrialFailure::None;
  Axis& axis = *axes_[static_cast<std::size_t>(job.axis)];
  const model::TriangleWave wave = req.segment.wave();
  const double t0 = req.segment.start_offset_s();
  out.info.freq_hz = req.segment.freq_hz;
  out.info.duty = req.segment.duty;
  out.info.stroke_m = req.segment.stroke_m;
  out.info.cycles = static_cast<int>(req.segment.cycles);
  out.info.sample_rate_hz = job.stream_rate_hz;
  out.info.guide_pos_m = kNaN;
  const double duration_s =
      (static_cast<double>(req.segment.cycles) + job.settle_cycles) / req.segment.freq_hz +
      job.rest_s;
  const double deadline_s = drivers::monotonic_s() + duration_s + 30.0;
  drivers::CaptureRecord rec;
  TrialNotice notice;
  for (;;) {
    if (!axis.port().capture.pop(rec)) {
      while (supervisor_.next_notice(notice))  // a failure while it played (the end mark follows)
        if (notice.seq == seq && notice.kind == TrialNotice::Kind::Failed) out.failure = notice.why;
      if (drivers::monotonic_s() > deadline_s) {
        why = "no end of the trial's samples within " +
              std::to_string(static_cast<int>(duration_s + 30)) + " s";
        return false;
      }
      nap();
      continue;
    }
    if (rec.seq != seq) continue;  // left over from an earlier trial
    if (rec.end) {
      out.complete = rec.complete;
      return true;
    }
    if (rec.status != 0) out.valid = false;
    const double t = rec.t_s - t0;
    if (!out.series.t_s.empty() && !(t > out.series.t_s.back())) continue;
    if (std::isnan(out.info.guide_pos_m) && rec.status == 0) out.info.guide_pos_m = rec.position_m;
    out.series.t_s.push_back(t);
    out.series.xi_cmd_m.push_back(wave.xi_m(t));
    out.series.x_m.push_back(rec.position_m);
  }
}

SweepRunner::TrialOutcome SweepRunner::run_trial(SweepJob& job, const TrialRequest& req,
                                                 CellRun& cell, std::string& first_error) {
  const Axis& axis = *axes_[static_cast<std::size_t>(job.axis)];
  auto failed = [&](const std::string& why) {
    const std::string trial = "trial " + std::to_string(req.index) + " (" +
                              model::format_number(req.segment.freq_hz) + " Hz, duty " +
                              model::format_number(req.segment.duty) + ")";
    const control::MotionStatus m = axis.published().motion;
    std::lock_guard<std::mutex> lock(mutex_);
    ++status_.failed;
    if (first_error.empty()) first_error = trial + ": " + why;
    if (trial_notes_.size() < 200)
      trial_notes_.push_back(
          "axis " + axis.config().name + ": sweep " + job.dir + " " + trial +
          " ended FAILED: " + why + "; position " +
          (m.position_valid ? model::format_number(m.position_m) + " m" : std::string("unknown")));
  };
  const auto interrupted = [&] {
    return abort_.load(std::memory_order_acquire) || supervisor_.stopping();
  };
  std::uint32_t seq = 0;
  TrialFailure failure = TrialFailure::None;
  std::string why;
  switch (await_start(req, seq, failure, why)) {
    case TrialStart::Started:
      break;
    case TrialStart::Interrupted:
      return TrialOutcome::Interrupted;
    case TrialStart::Refused:
      failed(why);
      return ends_sweep(failure) ? TrialOutcome::EndSweep : TrialOutcome::Failed;
    case TrialStart::TimedOut:
      failed(why);
      return TrialOutcome::EndSweep;
  }
  CapturedTrial trial;
  if (!capture_trial(job, req, seq, trial, why)) {
    failed(why);
    return TrialOutcome::EndSweep;
  }
  if (!trial.complete || !trial.valid || trial.series.size() < 2 ||
      std::isnan(trial.info.guide_pos_m)) {
    if (trial.failure == TrialFailure::LeftLimits) {
      failed(trial_failure_text(trial.failure));
      return TrialOutcome::EndSweep;
    }
    if (interrupted()) return TrialOutcome::Interrupted;
    failed(!trial.valid ? "invalid interferometer samples" : "the trial did not play in full");
    return TrialOutcome::Failed;
  }
  if (const std::string eot = end_of_travel(job, trial, cell); !eot.empty()) {
    failed(eot);
    return TrialOutcome::EndSweep;
  }
  try {
    job.writer->add_trial(trial.info, trial.series);
  } catch (const std::exception& e) {
    failed(std::string("cannot write it: ") + e.what());  // a full disk: nothing more is played
    return TrialOutcome::EndSweep;
  }
  std::lock_guard<std::mutex> lock(mutex_);
  ++status_.written;
  return TrialOutcome::Written;
}

std::string SweepRunner::end_of_travel(const SweepJob& job, const CapturedTrial& trial,
                                       CellRun& cell) const {
  const Axis& axis = *axes_[static_cast<std::size_t>(job.axis)];
  const double moved_m = trial.series.x_m.back() - trial.series.x_m.front();
  if (std::isnan(cell.first_moved_m)) {
    cell.first_moved_m = moved_m;
    return {};
  }
  // The same cell played again: it moved clearly the first time, so a collapse now is the slider
  // against a stop, not the cell (a cell that does not move never moved).
  const double eot_step_m = axis.published().settings.eot_step_m;
  const double cycles = static_cast<double>(job.cycles);
  const double first = std::fabs(cell.first_moved_m);
  if (eot_step_m <= 0 || first < std::max(20.0 * axis.count_m(), 4.0 * eot_step_m * cycles))
    return {};
  const double along = cell.first_moved_m > 0 ? moved_m : -moved_m;
  if (along >= std::max(0.1 * first, eot_step_m * cycles)) return {};
  return "the end of travel: the slider moved " + model::format_number(moved_m) + " m at " +
         model::format_number(trial.series.x_m.back()) + " m where this cell's first trial moved " +
         model::format_number(cell.first_moved_m) +
         " m (a stop, or stage.travel_m is wider than the stage)";
}

}  // namespace idm::daemon
