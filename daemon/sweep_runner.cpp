#include "daemon/sweep_runner.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <sstream>
#include <thread>

#include "drivers/clock.h"
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
  thread_ = drivers::StackThread(drivers::kRecorderStackBytes, [this] { main(); });
}

SweepRunner::~SweepRunner() {
  quit();
}

void SweepRunner::abort() {
  if (active_.load(std::memory_order_acquire) && !abort_.load(std::memory_order_acquire))
    abort_time_s_.store(drivers::monotonic_s(), std::memory_order_release);
  abort_.store(true, std::memory_order_release);
}

void SweepRunner::quit() {
  abort();
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
  double sweep_start_m = kNaN, last_m = kNaN;
  std::uint32_t index = 0;
  bool stopped = false;
  for (double f : job.freqs_hz) {
    for (double d : job.duties) {
      for (int t = 0; t < job.trials && !stopped; ++t, ++index) {
        if (abort_.load(std::memory_order_acquire)) {
          stopped = true;
          break;
        }
        TrialRequest req;
        req.index = index;
        req.seq = 0x80000000u | (++next_seq_ & 0x7FFFFFFFu);  // apart from the positioners' chunks
        req.axis = job.axis;
        req.segment = trial_segment(job, f, d);
        req.return_to_m = kNaN;
        if (std::isfinite(sweep_start_m) && std::isfinite(last_m) &&
            std::fabs(last_m - sweep_start_m) > job.span_m)
          req.return_to_m = sweep_start_m;
        const std::uint64_t written_before = status().written;
        if (!run_trial(job, req, first_error)) stopped = true;
        const recording::Dataset& ds = job.writer->dataset();
        if (status().written > written_before && !ds.trials.empty()) {
          if (!std::isfinite(sweep_start_m)) sweep_start_m = ds.trials.back().guide_pos_m;
          last_m = axes_[static_cast<std::size_t>(job.axis)]->published().motion.position_m;
        }
      }
    }
  }
  // The dataset's mark: complete when the whole plan was played (failed trials are missing from
  // it), stopped with why otherwise.
  std::string why;
  if (stopped)
    why = abort_.load(std::memory_order_acquire) ? "stopped by a client (STOP or *RST)"
          : supervisor_.stopping()               ? "the daemon stopped"
          : first_error.empty()                  ? "stopped"
                                                 : first_error;
  try {
    job.writer->finish(stopped ? recording::SweepStatus::Stopped : recording::SweepStatus::Complete,
                       why);
  } catch (const std::exception& e) {
    if (first_error.empty()) first_error = std::string("marking the dataset: ") + e.what();
  }
  std::ostringstream line;
  std::lock_guard<std::mutex> lock(mutex_);
  status_.state =
      stopped ? "STOPPED" : (status_.failed > 0 && status_.written == 0 ? "FAILED" : "DONE");
  line << "sweep " << job.dir << " (axis "
       << axes_[static_cast<std::size_t>(job.axis)]->config().name << "): " << status_.written
       << " trials written, " << status_.failed << " failed" << (stopped ? ", stopped" : "")
       << (first_error.empty() ? "" : " (first: " + first_error + ")");
  report_ = line.str();
}

SweepRunner::TrialStart SweepRunner::await_start(const TrialRequest& req, std::uint32_t& seq,
                                                 std::string& why) {
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
      while (supervisor_.next_notice(notice)) {  // a failure while it played (the end mark follows)
      }
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

bool SweepRunner::run_trial(SweepJob& job, const TrialRequest& req, std::string& first_error) {
  auto failed = [&](const std::string& why) {
    std::lock_guard<std::mutex> lock(mutex_);
    ++status_.failed;
    if (first_error.empty()) first_error = "trial " + std::to_string(req.index) + ": " + why;
  };
  std::uint32_t seq = 0;
  std::string why;
  switch (await_start(req, seq, why)) {
    case TrialStart::Started:
      break;
    case TrialStart::Interrupted:
      return false;  // interrupted, not failed
    case TrialStart::Refused:
      failed(why);
      return true;
    case TrialStart::TimedOut:
      failed(why);
      return false;
  }
  CapturedTrial trial;
  if (!capture_trial(job, req, seq, trial, why)) {
    failed(why);
    return false;
  }
  if (!trial.complete || !trial.valid || trial.series.size() < 2 ||
      std::isnan(trial.info.guide_pos_m)) {
    const bool stopped = abort_.load(std::memory_order_acquire) || supervisor_.stopping();
    if (stopped) return false;  // interrupted, not failed
    failed(!trial.valid ? "invalid interferometer samples" : "the trial did not play in full");
    return true;
  }
  try {
    job.writer->add_trial(trial.info, trial.series);
    std::lock_guard<std::mutex> lock(mutex_);
    ++status_.written;
  } catch (const std::exception& e) {
    failed(e.what());
  }
  return true;
}

}  // namespace idm::daemon
