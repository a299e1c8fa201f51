// idm-web's view of idmd: one thread polls the daemon over its socket (idm_client) and keeps the
// latest status of every axis, the last minute of positions, the sweep and the loop's timing;
// the HTTP handlers read copies of it and render JSON and the Prometheus text format.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "client/connection.h"
#include "client/replies.h"

namespace idm::web {

struct AxisView {
  int axis = 0;  // 1-based, as the protocol's AXIS<n>:
  std::optional<client::AxisStatus> status;
  std::string status_error;                // why status is empty
  std::optional<std::uint32_t> operation;  // STATus:OPERation?, when the daemon answers it
  std::string operation_error;             // the daemon's error when it does not
  std::optional<double> speed_limit_m_s;   // MOVE:VELocity? (0: none), when the daemon answers it
  std::string speed_limit_error;           // the daemon's error when it does not
  std::uint64_t faults_seen = 0;           // transitions into FAULT seen by this idm-web
  struct Sample {
    double t;  // seconds since the epoch
    double position_m;
  };
  std::deque<Sample> history;  // the last history_s, valid readings only
};

struct Snapshot {
  bool connected = false;
  std::string error;  // why not connected, or the last poll's failure
  std::string idn;
  double time = 0;       // seconds since the epoch, of the last poll
  double last_seen = 0;  // of the last poll that reached idmd (0: none yet)
  // While not connected, `axes` are as last seen: names and history stay, nothing of them is
  // presented as current (state_json marks them stale, metrics_text leaves them out).
  std::uint64_t polls = 0, poll_errors = 0;
  std::vector<AxisView> axes;
  std::optional<client::SweepInfo> sweep;
  std::optional<client::LoopStats> loop;
  std::string loop_error;
  // idmd's client table (SYSTem:CLIents:TABLe?): every connection to its socket, idm-web's own
  // included; empty with clients_error when idmd does not answer it.
  std::optional<client::ClientTable> clients;
  std::string clients_error;
};

struct RegionMap {
  int axis = 0;
  std::vector<double> freqs_hz, duties;
  // The axis's frequency range as idmd gave it (NaN when it did not), and where the rows came
  // from: "idmd" (the range), "--region-freq", or "default" (freq_range_error says why).
  double freq_min_hz = std::numeric_limits<double>::quiet_NaN();
  double freq_max_hz = std::numeric_limits<double>::quiet_NaN();
  std::string freq_source, freq_range_error;
  // cells[f][d]: the region ("" when the daemon refused the cell) and the predicted step
  std::vector<std::vector<client::RegionReply>> cells;
  std::string error;
  double time = 0;
};

struct MonitorOptions {
  client::Address address;
  double timeout_s = 5;
  double poll_s = 0.1;
  double history_s = 60;
  double loop_every_s = 1;
  // The region map's grid; no frequencies: rows from the axis's frequency range (idmd's).
  std::vector<double> region_freqs_hz, region_duties;
};

// The region map's default rows over [min_hz, max_hz]: min_hz, the multiples of a 1-2-5 step
// (about 20 rows) above it, and max_hz.
std::vector<double> frequency_rows(double min_hz, double max_hz);

double now_s();

class Monitor {
 public:
  explicit Monitor(MonitorOptions options);
  Monitor(const Monitor&) = delete;
  Monitor& operator=(const Monitor&) = delete;
  ~Monitor();
  void start();
  void stop();

  Snapshot snapshot() const;
  // REG? over the grid for one axis (cached for 30 s), on a connection of its own.
  RegionMap regions(int axis);
  // A command on the control connection: the daemon's error as client::DaemonError.
  void command(const std::string& line);
  const MonitorOptions& options() const { return options_; }

 private:
  void run();
  void poll_once(client::Client& c, double& next_loop);
  void region_rows(client::Client& c, RegionMap& m);

  MonitorOptions options_;
  mutable std::mutex mutex_;
  Snapshot snapshot_;
  // STOP and moves on their own connection, so that a region map being computed never holds
  // up a STOP.
  std::mutex control_mutex_;
  std::unique_ptr<client::Client> control_;
  std::mutex regions_mutex_;  // the region queries' connection and the cache
  std::unique_ptr<client::Client> regions_client_;
  std::map<int, RegionMap> regions_;
  std::mutex wake_mutex_;
  std::condition_variable wake_;
  std::atomic<bool> stopping_{false};
  std::thread thread_;
};

// JSON of the snapshot (GET /api/state), the history (GET /api/history) and a region map.
// control: POSTs are served; token_required: they need the token too.
std::string state_json(const Snapshot& s, bool control, bool token_required = false);
std::string history_json(const Snapshot& s);
std::string regions_json(const RegionMap& m);
// The Prometheus text exposition format (GET /metrics).
std::string metrics_text(const Snapshot& s, std::uint64_t http_connections,
                         std::uint64_t http_requests);
// A JSON string literal (quotes included); bytes outside printable ASCII as \u escapes.
std::string json_string(const std::string& text);
// A JSON number, null when not finite.
std::string json_number(double value);

}  // namespace idm::web
