#include "web/monitor.h"

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string_view>

namespace idm::web {

namespace {

constexpr int kMaxAxes = 64;
constexpr double kRegionCacheS = 30;
// A frequency no device plays: the configuration allows at most 1 MHz (daemon/config_tables.cpp).

std::string axis_prefix(int axis) {
  return "AXIS" + std::to_string(axis) + ":";
}

std::string number_text(double value) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.12g", value);
  return buf;
}

// Runs `query` (a query and the parse of its reply): the daemon's error or the reply's
// problem as text, or "" when it succeeded.
template <class Query>
std::string query_error(const Query& query) {
  try {
    query();
  } catch (const client::DaemonError& e) {
    return e.what();
  } catch (const client::ReplyError& e) {
    return e.what();
  }
  return "";
}

// Axis `axis`'s status and operation bits into a (what failed in its *_error fields); `old`: the
// axis as last polled on this connection (nullptr: none).
void poll_axis(client::Client& c, int axis, const AxisView* old, AxisView& a) {
  a.axis = axis;
  const std::string prefix = axis_prefix(axis);
  a.status_error = query_error([&] { a.status = client::parse_status(c.query(prefix + "STAT?")); });
  // MOVE:VELocity? likewise: a daemon without it answers -113 once per connection.
  if (old && !old->speed_limit_m_s && old->speed_limit_error.rfind("-113,", 0) == 0)
    a.speed_limit_error = old->speed_limit_error;
  else
    a.speed_limit_error = query_error(
        [&] { a.speed_limit_m_s = client::parse_reply_number(c.query(prefix + "MOVE:VEL?")); });
  // STATus:OPERation? is in the protocol's extension; a daemon without it answers -113 once
  // per connection, and is not asked again until idm-web reconnects.
  const bool unsupported = old && !old->operation && old->operation_error.rfind("-113,", 0) == 0;
  if (unsupported) {
    a.operation_error = old->operation_error;
    return;
  }
  a.operation_error = query_error([&] {
    const std::uint64_t bits = client::parse_reply_count(c.query(prefix + "STAT:OPER?"));
    if (bits > 0xffffffffu) throw client::ReplyError("STAT:OPER? out of range");
    a.operation = static_cast<std::uint32_t>(bits);
  });
}

// Each axis's position history and FAULT count carried over from the last poll (old_axes, moved
// from), the position at t_s appended and history older than history_s dropped.
void carry_history(std::vector<AxisView>& old_axes, std::vector<AxisView>& axes, double t_s,
                   double history_s) {
  for (std::size_t k = 0; k < axes.size(); ++k) {
    AxisView& a = axes[k];
    if (k < old_axes.size()) {
      a.history = std::move(old_axes[k].history);
      a.faults_seen = old_axes[k].faults_seen;
      const bool was_fault = old_axes[k].status && old_axes[k].status->state == "FAULT";
      if (a.status && a.status->state == "FAULT" && !was_fault) ++a.faults_seen;
    } else if (a.status && a.status->state == "FAULT") {
      ++a.faults_seen;
    }
    if (a.status && a.status->position_valid) a.history.push_back({t_s, a.status->position_m});
    while (!a.history.empty() && a.history.front().t < t_s - history_s) a.history.pop_front();
  }
}

}  // namespace

double now_s() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

Monitor::Monitor(MonitorOptions options) : options_(std::move(options)) {}

Monitor::~Monitor() {
  stop();
}

void Monitor::start() {
  thread_ = std::thread([this] { run(); });
}

void Monitor::stop() {
  {
    std::lock_guard<std::mutex> lock(wake_mutex_);
    stopping_ = true;
  }
  wake_.notify_all();
  if (thread_.joinable()) thread_.join();
}

Snapshot Monitor::snapshot() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return snapshot_;
}

void Monitor::run() {
  std::unique_ptr<client::Client> c;
  double next_loop = 0;
  while (!stopping_) {
    const auto start = std::chrono::steady_clock::now();
    double pause_s = options_.poll_s;
    try {
      if (!c) c = std::make_unique<client::Client>(options_.address, options_.timeout_s);
      poll_once(*c, next_loop);
    } catch (const std::exception& e) {
      c.reset();
      std::lock_guard<std::mutex> lock(mutex_);
      snapshot_.connected = false;
      snapshot_.error = e.what();
      snapshot_.time = now_s();
      ++snapshot_.poll_errors;
      pause_s = 1;  // try to reconnect once a second
    }
    std::unique_lock<std::mutex> lock(wake_mutex_);
    wake_.wait_until(lock,
                     start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                 std::chrono::duration<double>(pause_s)),
                     [this] { return stopping_.load(); });
  }
}

void Monitor::poll_once(client::Client& c, double& next_loop) {
  Snapshot old = snapshot();
  Snapshot next;
  next.connected = true;
  next.polls = old.polls + 1;
  next.poll_errors = old.poll_errors;
  next.idn = old.connected ? old.idn : c.query("*IDN?");
  std::size_t count = old.axes.size();
  if (!old.connected || count == 0) {
    const std::uint64_t n = client::parse_reply_count(c.query("AXIS:COUNt?"));
    if (n < 1 || n > kMaxAxes)
      throw client::ReplyError("AXIS:COUNt? answered " + std::to_string(n) + ", expected 1.." +
                               std::to_string(kMaxAxes));
    count = n;
    old.axes.clear();
  }
  next.axes.resize(count);
  for (std::size_t k = 0; k < count; ++k)
    poll_axis(c, static_cast<int>(k) + 1, k < old.axes.size() ? &old.axes[k] : nullptr,
              next.axes[k]);
  // SYSTem:CLIents:TABLe? is this repo's extension: a daemon without it answers -113 once per
  // connection, and is not asked again until idm-web reconnects.
  if (old.connected && !old.clients && old.clients_error.rfind("-113,", 0) == 0)
    next.clients_error = old.clients_error;
  else
    next.clients_error =
        query_error([&] { next.clients = client::parse_client_table(c.query("SYST:CLI:TABL?")); });
  // SWEEP?: no sweep shown when it fails
  query_error([&] { next.sweep = client::parse_sweep(c.query("SWEEP?")); });
  const double t = now_s();
  next.loop = old.loop;
  next.loop_error = old.loop_error;
  if (t >= next_loop) {
    next_loop = t + options_.loop_every_s;
    try {
      next.loop = client::parse_loop(c.query("SYST:LOOP?"));
      next.loop_error.clear();
    } catch (const client::DaemonError& e) {
      next.loop.reset();
      next.loop_error = e.what();
    } catch (const client::ReplyError& e) {
      next.loop.reset();
      next.loop_error = e.what();
    }
  }
  next.time = t;
  next.last_seen = t;
  carry_history(old.axes, next.axes, t, options_.history_s);
  std::lock_guard<std::mutex> lock(mutex_);
  snapshot_ = std::move(next);
}

void Monitor::command(const std::string& line) {
  std::lock_guard<std::mutex> lock(control_mutex_);
  // A connection kept from before may have been closed by a daemon that restarted: once more on
  // a new one (the control lines, STOP and an absolute move, may be sent twice).
  for (int attempt = 0;; ++attempt) {
    try {
      if (!control_)
        control_ = std::make_unique<client::Client>(options_.address, options_.timeout_s);
      control_->command(line);
      return;
    } catch (const client::DaemonError&) {
      throw;
    } catch (...) {
      control_.reset();
      if (attempt > 0) throw;
    }
  }
}

std::vector<double> frequency_rows(double min_hz, double max_hz) {
  std::vector<double> rows;
  if (!(min_hz > 0) || !std::isfinite(max_hz) || !(max_hz >= min_hz)) return rows;
  rows.push_back(min_hz);
  if (max_hz <= min_hz * (1 + 1e-9)) return rows;
  const double raw = (max_hz - min_hz) / 20;
  const double decade = std::pow(10.0, std::floor(std::log10(raw)));
  double step = 10 * decade;
  for (const double m : {1.0, 2.0, 5.0})
    if (m * decade >= raw * (1 - 1e-9)) {
      step = m * decade;
      break;
    }
  for (double k = std::floor(min_hz / step * (1 + 1e-9)) + 1; k * step < max_hz * (1 - 1e-9); ++k)
    rows.push_back(k * step);
  rows.push_back(max_hz);
  return rows;
}

// The rows of axis m.axis's map: --region-freq's, else over the axis's frequency range
// (REGion:RANGe?, the map's range with the device's limits applied); an idmd without that query
// gets the default rows and the page says why.
void Monitor::region_rows(client::Client& c, RegionMap& m) {
  if (!options_.region_freqs_hz.empty()) {
    m.freqs_hz = options_.region_freqs_hz;
    m.freq_source = "--region-freq";
    return;
  }
  try {
    const std::vector<double> range =
        client::parse_number_list(c.query(axis_prefix(m.axis) + "REG:RANG?"));
    if (range.size() == 4 && std::isfinite(range[0]) && std::isfinite(range[1]) && range[0] > 0 &&
        range[1] >= range[0]) {
      m.freq_min_hz = range[0];
      m.freq_max_hz = range[1];
      m.freqs_hz = frequency_rows(m.freq_min_hz, m.freq_max_hz);
      m.freq_source = "idmd";
      return;
    }
    m.freq_range_error = "idmd's REG:RANG? reply is not a frequency range";
  } catch (const client::DaemonError& e) {
    if (e.code == -114) throw;  // no such axis
    m.freq_range_error = std::string("idmd did not say the axis's frequency range: ") + e.what();
  }
  for (double f = 100; f <= 1000 + 1e-9; f += 50) m.freqs_hz.push_back(f);
  m.freq_source = "default";
}

RegionMap Monitor::regions(int axis) {
  std::lock_guard<std::mutex> lock(regions_mutex_);
  const double t = now_s();
  if (const auto it = regions_.find(axis);
      it != regions_.end() && t - it->second.time < kRegionCacheS)
    return it->second;
  RegionMap m;
  m.axis = axis;
  m.duties = options_.region_duties;
  m.time = t;
  try {
    if (!regions_client_)
      regions_client_ = std::make_unique<client::Client>(options_.address, options_.timeout_s);
    region_rows(*regions_client_, m);
    for (const double f : m.freqs_hz) {
      std::vector<client::RegionReply> row;
      for (const double d : m.duties) {
        client::RegionReply r;
        try {
          r = client::parse_region(regions_client_->query(axis_prefix(axis) + "REG? " +
                                                          number_text(f) + "," + number_text(d)));
        } catch (const client::DaemonError& e) {
          if (e.code == -114) throw;  // no such axis: no map at all
          r.region.clear();           // a cell the daemon refuses (e.g. outside the device's range)
        }
        row.push_back(r);
      }
      m.cells.push_back(std::move(row));
    }
  } catch (const client::DaemonError& e) {
    m.cells.clear();
    m.error = e.what();
  } catch (const std::exception& e) {
    regions_client_.reset();
    m.cells.clear();
    m.error = e.what();
    return m;  // not cached: the daemon may come back
  }
  regions_[axis] = m;
  return m;
}

std::string json_string(const std::string& text) {
  std::string out = "\"";
  for (const char ch : text) {
    const unsigned char c = static_cast<unsigned char>(ch);
    if (c == '"') {
      out += "\\\"";
    } else if (c == '\\') {
      out += "\\\\";
    } else if (c < 0x20 || c >= 0x7f || c == '<' || c == '>' || c == '&') {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\u%04x", c);
      out += buf;
    } else {
      out += ch;
    }
  }
  return out + "\"";
}

std::string json_number(double value) {
  return std::isfinite(value) ? number_text(value) : "null";
}

namespace {

std::string json_bool(bool b) {
  return b ? "true" : "false";
}

// An axis as last seen while idmd is not reached: its name, and its last position only as
// `last_position_m` (position_valid false, position_m null), marked stale.
std::string stale_axis_json(const AxisView& a, double last_seen) {
  const bool known = a.status.has_value();
  return "{\"axis\":" + std::to_string(a.axis) +
         ",\"name\":" + json_string(known ? a.status->name : "axis" + std::to_string(a.axis)) +
         ",\"stale\":true,\"state\":null,\"position_valid\":false,\"position_m\":null" +
         ",\"last_position_m\":" +
         json_number(known && a.status->position_valid ? a.status->position_m
                                                       : std::numeric_limits<double>::quiet_NaN()) +
         ",\"last_seen\":" + (last_seen > 0 ? json_number(last_seen) : "null") +
         ",\"status_error\":" + json_string("idmd not reached") +
         ",\"status_bits\":null,\"faults_seen\":" + std::to_string(a.faults_seen) + "}";
}

std::string axis_json(const AxisView& a) {
  std::string o = "{\"axis\":" + std::to_string(a.axis) + ",\"stale\":false";
  if (a.status) {
    const client::AxisStatus& s = *a.status;
    o += ",\"name\":" + json_string(s.name) + ",\"state\":" + json_string(s.state) +
         ",\"done\":" + json_bool(s.done) + ",\"position_valid\":" + json_bool(s.position_valid) +
         ",\"position_m\":" + json_number(s.position_m) +
         ",\"target_m\":" + json_number(s.target_m) + ",\"lower_m\":" + json_number(s.lower_m) +
         ",\"upper_m\":" + json_number(s.upper_m) + ",\"referenced\":" + json_bool(s.referenced) +
         ",\"fault\":" + json_string(s.fault) + ",\"device\":" + json_string(s.device) +
         ",\"eot\":" + json_string(s.eot) + ",\"daemon_error\":" + json_string(s.daemon_error) +
         ",\"moves\":" + std::to_string(s.moves) + ",\"bursts\":" + std::to_string(s.bursts) +
         ",\"cycles\":" + std::to_string(s.cycles) + ",\"offset_m\":" + json_number(s.offset_m);
    o += a.speed_limit_m_s ? ",\"speed_limit_m_s\":" + json_number(*a.speed_limit_m_s)
                           : ",\"speed_limit_m_s\":null,\"speed_limit_error\":" +
                                 json_string(a.speed_limit_error);
  } else {
    o += ",\"name\":" + json_string("axis" + std::to_string(a.axis)) +
         ",\"status_error\":" + json_string(a.status_error);
  }
  if (a.operation) {
    o += ",\"status_bits\":" + std::to_string(*a.operation) + ",\"status_words\":[";
    const auto words = client::operation_bit_words(*a.operation);
    for (std::size_t k = 0; k < words.size(); ++k) o += (k ? "," : "") + json_string(words[k]);
    o += "]";
  } else {
    o += ",\"status_bits\":null,\"status_bits_error\":" + json_string(a.operation_error);
  }
  return o + ",\"faults_seen\":" + std::to_string(a.faults_seen) + "}";
}

}  // namespace

std::string state_json(const Snapshot& s, bool control, bool token_required) {
  std::string o =
      "{\"connected\":" + json_bool(s.connected) + ",\"error\":" + json_string(s.error) +
      ",\"idn\":" + json_string(s.idn) + ",\"control\":" + json_bool(control) +
      ",\"token_required\":" + json_bool(token_required) + ",\"time\":" + json_number(s.time) +
      ",\"last_seen\":" + (s.last_seen > 0 ? json_number(s.last_seen) : "null") + ",\"axes\":[";
  for (std::size_t k = 0; k < s.axes.size(); ++k)
    o += (k ? "," : "") +
         (s.connected ? axis_json(s.axes[k]) : stale_axis_json(s.axes[k], s.last_seen));
  o += "],\"sweep\":";
  // SWEEP?'s axis is 1-based, 0 before the first sweep (daemon/README.md).
  if (s.sweep && s.connected) {
    o += "{\"state\":" + json_string(s.sweep->state) + ",\"axis\":" +
         (s.sweep->axis >= 1 && s.sweep->state != "NONE" ? std::to_string(s.sweep->axis) : "null") +
         ",\"written\":" + std::to_string(s.sweep->written) +
         ",\"failed\":" + std::to_string(s.sweep->failed) +
         ",\"planned\":" + std::to_string(s.sweep->planned) +
         ",\"directory\":" + json_string(s.sweep->directory) + "}";
  } else {
    o += "null";
  }
  o += ",\"loop\":";
  if (s.loop && s.connected) {
    o += "{\"period_s\":" + json_number(s.loop->period_s) +
         ",\"wakeups\":" + std::to_string(s.loop->wakeups) +
         ",\"misses\":" + std::to_string(s.loop->misses) +
         ",\"max_latency_s\":" + json_number(s.loop->max_s) +
         ",\"avg_latency_s\":" + json_number(s.loop->avg_s) + "}";
  } else {
    o += "null";
  }
  o += ",\"clients\":";
  if (s.clients && s.connected) {
    o += "{\"connected\":" + std::to_string(s.clients->connected) +
         ",\"slots\":" + std::to_string(s.clients->slots) +
         ",\"max_clients\":" + std::to_string(s.clients->max_clients) +
         ",\"stop_only\":" + std::to_string(s.clients->stop_only) +
         ",\"overflow_slots\":" + std::to_string(s.clients->overflow_slots) +
         ",\"draining\":" + std::to_string(s.clients->draining) + "}";
  } else {
    o += "null,\"clients_error\":" + json_string(s.clients_error);
  }
  return o + "}";
}

std::string history_json(const Snapshot& s) {
  std::string o = "{\"time\":" + json_number(s.time) + ",\"connected\":" + json_bool(s.connected) +
                  ",\"axes\":[";
  for (std::size_t k = 0; k < s.axes.size(); ++k) {
    const AxisView& a = s.axes[k];
    o += (k ? "," : "") + std::string("{\"axis\":") + std::to_string(a.axis) +
         ",\"name\":" + json_string(a.status ? a.status->name : "axis" + std::to_string(a.axis)) +
         ",\"t\":[";
    for (std::size_t i = 0; i < a.history.size(); ++i)
      o += (i ? "," : "") + json_number(a.history[i].t - s.time);
    o += "],\"position_m\":[";
    for (std::size_t i = 0; i < a.history.size(); ++i)
      o += (i ? "," : "") + json_number(a.history[i].position_m);
    o += "]}";
  }
  return o + "]}";
}

std::string regions_json(const RegionMap& m) {
  std::string o = "{\"axis\":" + std::to_string(m.axis) + ",\"error\":" + json_string(m.error) +
                  ",\"freq_range_hz\":";
  o += std::isfinite(m.freq_min_hz)
           ? "[" + json_number(m.freq_min_hz) + "," + json_number(m.freq_max_hz) + "]"
           : std::string("null");
  o += ",\"freq_source\":" + json_string(m.freq_source) +
       ",\"freq_range_error\":" + json_string(m.freq_range_error) + ",\"freqs_hz\":[";
  for (std::size_t k = 0; k < m.freqs_hz.size(); ++k)
    o += (k ? "," : "") + json_number(m.freqs_hz[k]);
  o += "],\"duties\":[";
  for (std::size_t k = 0; k < m.duties.size(); ++k) o += (k ? "," : "") + json_number(m.duties[k]);
  o += "],\"cells\":[";
  for (std::size_t f = 0; f < m.cells.size(); ++f) {
    o += f ? ",[" : "[";
    for (std::size_t d = 0; d < m.cells[f].size(); ++d) {
      const client::RegionReply& r = m.cells[f][d];
      o += d ? "," : "";
      o += r.region.empty() ? std::string("null")
                            : "{\"region\":" + json_string(r.region) +
                                  ",\"step_m\":" + json_number(r.step_m) + "}";
    }
    o += "]";
  }
  return o + "]}";
}

namespace {

// A Prometheus label value: backslash, quote and newline escaped.
std::string label(const std::string& v) {
  std::string out;
  for (const char c : v) {
    if (c == '\\')
      out += "\\\\";
    else if (c == '"')
      out += "\\\"";
    else if (c == '\n')
      out += "\\n";
    else
      out += c;
  }
  return out;
}

std::string prom_number(double v) {
  if (std::isnan(v)) return "NaN";
  if (std::isinf(v)) return v > 0 ? "+Inf" : "-Inf";
  return number_text(v);
}

void family(std::string& out, const char* name, const char* type, const char* help) {
  out += std::string("# HELP ") + name + " " + help + "\n# TYPE " + name + " " + type + "\n";
}

// The axes' families (position, target, limits, state, counters, status bits) and the sweep's.
void append_axis_metrics(std::string& o, const Snapshot& s) {
  std::vector<std::pair<std::string, const client::AxisStatus*>> axes;
  for (const AxisView& a : s.axes)
    if (a.status) axes.emplace_back(label(a.status->name), &*a.status);
  family(o, "idm_position_meters", "gauge", "Position of the axis (NaN when not valid).");
  for (const auto& [n, st] : axes)
    o += "idm_position_meters{axis=\"" + n + "\"} " + prom_number(st->position_m) + "\n";
  family(o, "idm_target_meters", "gauge", "Target of the axis's last move.");
  for (const auto& [n, st] : axes)
    o += "idm_target_meters{axis=\"" + n + "\"} " + prom_number(st->target_m) + "\n";
  family(o, "idm_soft_limit_meters", "gauge", "Soft limits of the axis.");
  for (const auto& [n, st] : axes) {
    o += "idm_soft_limit_meters{axis=\"" + n + "\",side=\"lower\"} " + prom_number(st->lower_m) +
         "\n";
    o += "idm_soft_limit_meters{axis=\"" + n + "\",side=\"upper\"} " + prom_number(st->upper_m) +
         "\n";
  }
  family(o, "idm_axis_state", "gauge", "1 for the axis's current motion state.");
  for (const auto& [n, st] : axes) {
    bool listed = false;
    for (const char* state : {"IDLE", "MOVING", "SETTLING", "FAULT"}) {
      listed = listed || st->state == state;
      o += "idm_axis_state{axis=\"" + n + "\",state=\"" + state + "\"} " +
           (st->state == state ? "1" : "0") + "\n";
    }
    if (!listed) o += "idm_axis_state{axis=\"" + n + "\",state=\"" + label(st->state) + "\"} 1\n";
  }
  family(o, "idm_position_valid", "gauge", "1 when the axis's position can be trusted.");
  for (const auto& [n, st] : axes)
    o += "idm_position_valid{axis=\"" + n + "\"} " + (st->position_valid ? "1" : "0") + "\n";
  family(o, "idm_referenced", "gauge", "1 when the axis is referenced.");
  for (const auto& [n, st] : axes)
    o += "idm_referenced{axis=\"" + n + "\"} " + (st->referenced ? "1" : "0") + "\n";
  family(o, "idm_moves_total", "counter", "Closed-loop moves the daemon started on the axis.");
  for (const auto& [n, st] : axes)
    o += "idm_moves_total{axis=\"" + n + "\"} " + std::to_string(st->moves) + "\n";
  family(o, "idm_bursts_total", "counter", "Bursts the daemon played on the axis.");
  for (const auto& [n, st] : axes)
    o += "idm_bursts_total{axis=\"" + n + "\"} " + std::to_string(st->bursts) + "\n";
  family(o, "idm_faults_total", "counter",
         "Times idm-web saw the axis enter FAULT (since idm-web started).");
  for (const AxisView& a : s.axes)
    if (a.status)
      o += "idm_faults_total{axis=\"" + label(a.status->name) + "\"} " +
           std::to_string(a.faults_seen) + "\n";
  bool any_bits = false;
  for (const AxisView& a : s.axes) any_bits = any_bits || (a.status && a.operation);
  if (any_bits) {
    family(o, "idm_status_bits", "gauge", "STATus:OPERation? of the axis.");
    for (const AxisView& a : s.axes)
      if (a.status && a.operation)
        o += "idm_status_bits{axis=\"" + label(a.status->name) + "\"} " +
             std::to_string(*a.operation) + "\n";
  }
  if (s.sweep) {
    family(o, "idm_sweep_running", "gauge", "1 while a sweep runs.");
    o += std::string("idm_sweep_running ") + (s.sweep->state == "RUNNING" ? "1" : "0") + "\n";
    family(o, "idm_sweep_trials", "gauge", "Trials of the last or running sweep.");
    o += "idm_sweep_trials{kind=\"planned\"} " + std::to_string(s.sweep->planned) + "\n";
    o += "idm_sweep_trials{kind=\"written\"} " + std::to_string(s.sweep->written) + "\n";
    o += "idm_sweep_trials{kind=\"failed\"} " + std::to_string(s.sweep->failed) + "\n";
  }
}

// The real-time loop's families: wake-ups, misses, period and the latency histogram.
void append_loop_metrics(std::string& o, const client::LoopStats& l) {
  family(o, "idm_loop_wakeups_total", "counter", "Wake-ups of the daemon's real-time loop.");
  o += "idm_loop_wakeups_total " + std::to_string(l.wakeups) + "\n";
  family(o, "idm_loop_deadline_misses_total", "counter", "Deadlines the real-time loop missed.");
  o += "idm_loop_deadline_misses_total " + std::to_string(l.misses) + "\n";
  family(o, "idm_loop_period_seconds", "gauge", "Period of the real-time loop.");
  o += "idm_loop_period_seconds " + prom_number(l.period_s) + "\n";
  family(o, "idm_loop_latency_seconds", "histogram", "Wake-up latency of the real-time loop.");
  std::uint64_t cumulative = 0;
  for (std::size_t k = 0; k < l.hist.size(); ++k) {
    cumulative += l.hist[k];
    // The last bin holds everything above the others: it is +Inf's.
    if (k + 1 < l.hist.size())
      o += "idm_loop_latency_seconds_bucket{le=\"" +
           prom_number(static_cast<double>(k + 1) * l.bin_width_s) + "\"} " +
           std::to_string(cumulative) + "\n";
  }
  o += "idm_loop_latency_seconds_bucket{le=\"+Inf\"} " + std::to_string(cumulative) + "\n";
  o += "idm_loop_latency_seconds_sum " + prom_number(l.avg_s * static_cast<double>(cumulative)) +
       "\n";
  o += "idm_loop_latency_seconds_count " + std::to_string(cumulative) + "\n";
}

}  // namespace

std::string metrics_text(const Snapshot& s, std::uint64_t http_connections,
                         std::uint64_t http_requests) {
  std::string o;
  family(o, "idm_up", "gauge", "1 when idm-web reaches idmd and its last poll succeeded.");
  o += "idm_up " + std::string(s.connected ? "1" : "0") + "\n";
  // Not connected: nothing of idmd's is current, so none of it is exported (idm_up 0 says why).
  if (s.connected) append_axis_metrics(o, s);
  if (s.connected && s.loop) append_loop_metrics(o, *s.loop);
  if (s.connected && s.clients) {
    family(
        o, "idm_clients_connected", "gauge",
        "Connections open to idmd's command socket (idm-web's own and stop-only ones included).");
    o += "idm_clients_connected " + std::to_string(s.clients->connected) + "\n";
    family(o, "idm_clients_stop_only", "gauge",
           "Of those, in a stop-only slot (they came while idmd's client table was full).");
    o += "idm_clients_stop_only " + std::to_string(s.clients->stop_only) + "\n";
    family(o, "idm_clients_max", "gauge", "idmd's client table size (server.max_clients).");
    o += "idm_clients_max " + std::to_string(s.clients->max_clients) + "\n";
  }
  family(o, "idm_web_clients_connected", "gauge", "HTTP connections open to idm-web.");
  o += "idm_web_clients_connected " + std::to_string(http_connections) + "\n";
  family(o, "idm_web_requests_total", "counter", "HTTP requests idm-web answered.");
  o += "idm_web_requests_total " + std::to_string(http_requests) + "\n";
  family(o, "idm_web_polls_total", "counter", "Polls of idmd by idm-web.");
  o += "idm_web_polls_total " + std::to_string(s.polls) + "\n";
  family(o, "idm_web_poll_errors_total", "counter", "Polls that failed (idmd not reached).");
  o += "idm_web_poll_errors_total " + std::to_string(s.poll_errors) + "\n";
  return o;
}

}  // namespace idm::web
