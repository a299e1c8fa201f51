// idmd's own config sections as parameter tables (model/param_table.h): control, server,
// realtime, logging, recording and the devices. The reader, the checks, the messages and
// config/README.md's rows all come from them; the document's shape is read in config.cpp.
#include <limits>
#include <string>
#include <vector>

#include "daemon/config.h"
#include "model/yaml_util.h"
#include "recording/dataset_limits.h"

namespace idm::daemon {

using model::boolean;
using model::choice;
using model::custom;
using model::InputError;
using model::integer;
using model::located;
using model::real;
using model::text;
using model::with_default;
using Node = YAML::Node;

namespace {

using model::Range;
constexpr double kNoBound = 1e300;  // model::Range's unbounded end

// The relations of control: keys to each other and to what the axis's other sections fix
// (ControlConfig::axis, planner.resolution_m: one count). The soft limits' order and
// min_step_counts < final_step_counts come with the positioner's table.
void relate_control(std::vector<model::Param<ControlConfig>>& params) {
  using C = ControlConfig;
  model::relate(params, "min_freq_hz", "<= max_freq_hz, narrowed by the output", [](const C& c) {
    return Range{-kNoBound, highest_freq_hz(c, c.axis.output)};
  });
  model::relate(
      params, "min_stroke_m",
      "<= the largest stroke: max_stroke_m (0: stage.stroke_m), capped by the output's reach "
      "(max_voltage_v / volts_per_m)",
      [](const C& c) {
        return Range{-kNoBound, largest_stroke_m(c, c.axis.stage_stroke_m, c.axis.output)};
      });
  model::relate(params, "soft_lower_m", "within stage.travel_m", [](const C& c) {
    return Range{c.axis.travel_lower_m, c.axis.travel_upper_m};
  });
  model::relate(params, "soft_upper_m", "within stage.travel_m", [](const C& c) {
    return Range{c.axis.travel_lower_m, c.axis.travel_upper_m};
  });
  // A reading is a whole count: within a window of up to one count a move lands on the reading
  // nearest the target and says OK half a count away, so a narrower window is not what it keeps.
  model::relate(
      params, "tolerance_m", ">= one count (interferometer resolution_m)",
      [](const C& c) {
        return Range{c.planner.resolution_m, kNoBound};
      },
      true);
  // A hold window narrower than the moves' window corrects every landing again.
  model::relate(
      params, "hold_window_m", ">= the move window (tolerance_m; 0: one count)",
      [](const C& c) {
        const double t = c.positioner.tolerance_m;
        return Range{t > 0 ? t : c.planner.resolution_m, kNoBound};
      },
      true);
  // At an end stop the mean step over eot_cycles cycles is a count of noise at most: a threshold
  // below that never sees the stop (REFerence then ends in a stall).
  model::relate(
      params, "eot_step_m", "> one count / eot_cycles",
      [](const C& c) {
        return Range{c.planner.resolution_m / c.positioner.eot_cycles, kNoBound, true, false};
      },
      true);
}

}  // namespace

const model::ParamTable<ControlConfig>& control_params() {
  using C = ControlConfig;
  static const model::ParamTable<C> table([] {
    std::vector<model::Param<C>> params = model::join<C>({
        {
            real<C>(
                "freq_step_hz", "Hz", {0, 1e5, true}, "region map grid: frequency step",
                [](auto& c) -> auto& { return c.freq_step_hz; }),
            real<C>(
                "duty_step", "1", {0, 0.25, true}, "region map grid: duty step",
                [](auto& c) -> auto& { return c.duty_step; }),
            integer<C>(
                "stroke_count", "count", 1, 64, "region map grid: strokes",
                [](auto& c) -> auto& { return c.stroke_count; }),
            real<C>(
                "min_freq_hz", "Hz", recording::kFreqRangeHz,
                "lowest frequency (narrowed by the device)",
                [](auto& c) -> auto& { return c.min_freq_hz; }),
            real<C>(
                "max_freq_hz", "Hz", recording::kFreqRangeHz,
                "highest frequency (narrowed by the device)",
                [](auto& c) -> auto& { return c.max_freq_hz; }),
            real<C>(
                "min_stroke_m", "m", {0, 1e-3, true}, "smallest stroke of the map",
                [](auto& c) -> auto& { return c.min_stroke_m; }),
            with_default(real<C>(
                             "max_stroke_m", "m", {0, 1e-3},
                             "largest stroke; 0: the stage's (capped by the output)",
                             [](auto& c) -> auto& { return c.max_stroke_m; }),
                         "0 (stage.stroke_m)"),
            real<C>(
                "output_sample_rate_hz", "Hz", {0, 1e8, true},
                "buffered outputs: the DAC clock (capped by the device)",
                [](auto& c) -> auto& { return c.output_sample_rate_hz; }),
            real<C>(
                "friction_uncertainty", "1", {0, 0.45},
                "relative uncertainty of mu the map keeps a margin for",
                [](auto& c) -> auto& { return c.friction_uncertainty; }),
            text<C>(
                "calibration_file",
                "the learned step model: loaded at start, saved after moves; \"\": none",
                [](auto& c) -> auto& { return c.calibration_file; }, "a path"),
            model::nested<C>(
                "calibration", "online calibration (control.calibration.KEY below)",
                control::calibration_params(), [](auto& c) -> auto& { return c.calibration; }),
        },
        model::lifted<C>(control::planner_params(), [](auto& c) -> auto& { return c.planner; },
                         {"max_bursts"}),
        model::lifted<C>(
            control::positioner_params(), [](auto& c) -> auto& { return c.positioner; }),
    });
    relate_control(params);
    return params;
  }());
  return table;
}

const model::ParamTable<ListenConfig>& server_params() {
  using S = ListenConfig;
  static const model::ParamTable<S> table({
      text<S>(
          "tcp_address", "TCP listener address; \"\": none",
          [](auto& c) -> auto& { return c.tcp_address; }, "an address"),
      integer<S>(
          "tcp_port", "", 0, 65535, "TCP port; 0: any free port (`--port` overrides)",
          [](auto& c) -> auto& { return c.tcp_port; }),
      text<S>(
          "unix_socket", "the Unix socket; \"\": none (`--unix` overrides)",
          [](auto& c) -> auto& { return c.unix_socket; }, "a path, <= 100 characters"),
      integer<S>(
          "max_clients", "count", 1, 1024, "clients that may send any command",
          [](auto& c) -> auto& { return c.max_clients; }),
      integer<S>(
          "overflow_slots", "count", 1, 64, "with the table full, stop-only connections",
          [](auto& c) -> auto& { return c.overflow_slots; }),
      real<S>(
          "ready_timeout_s", "s", {0, 600, true},
          "every axis must read a valid position within this at start, or idmd exits 3",
          [](auto& c) -> auto& { return c.ready_timeout_s; }),
      boolean<S>(
          "allow_remote",
          "let tcp_address be other than loopback (other machines can then connect: set "
          "auth_token_file)",
          [](auto& c) -> auto& { return c.allow_remote; }),
      text<S>(
          "auth_token_file",
          "TCP clients send `*AUTH <token>` (the file's first line) before commands that move "
          "or change settings; \"\": none. Not readable by others",
          [](auto& c) -> auto& { return c.auth_token_file; }, "a path"),
  });
  return table;
}

const model::ParamTable<RealtimeConfig>& realtime_params() {
  using R = RealtimeConfig;
  static const model::ParamTable<R> table = [] {
    std::vector<model::Param<R>> params{
        real<R>(
            "period_s", "s", {1e-5, 0.1}, "the real-time loop's period",
            [](auto& c) -> auto& { return c.period_s; }),
        real<R>(
            "rest_period_s", "s", {0, 0.1},
            "the loop's period while every axis is at rest (a command then waits this long at "
            "most); 0: always period_s",
            [](auto& c) -> auto& { return c.rest_period_s; }),
        boolean<R>(
            "sched_fifo", "SCHED_FIFO when permitted (CAP_SYS_NICE)",
            [](auto& c) -> auto& { return c.sched_fifo; }),
        integer<R>(
            "priority", "", 1, 99, "SCHED_FIFO priority",
            [](auto& c) -> auto& { return c.priority; }),
        integer<R>(
            "cpu", "", -1, 1023, "pin the loop to this CPU; -1: no affinity",
            [](auto& c) -> auto& { return c.cpu; }),
        boolean<R>(
            "lock_memory", "mlockall when permitted (CAP_IPC_LOCK / RLIMIT_MEMLOCK)",
            [](auto& c) -> auto& { return c.lock_memory; }),
        real<R>(
            "histogram_bin_s", "s", {1e-7, 1e-2}, "wake-up latency histogram bin (32 bins)",
            [](auto& c) -> auto& { return c.histogram_bin_s; }),
        real<R>(
            "watchdog_stall_s", "s", {1e-3, 60}, "no tick for this long: the loop has stalled",
            [](auto& c) -> auto& { return c.watchdog_stall_s; }),
    };
    model::relate(
        params, "rest_period_s", ">= period_s (0: off)",
        [](const R& c) {
          return Range{c.period_s, kNoBound};
        },
        true);
    // The watchdog must see ticks at rest too.
    model::relate(
        params, "rest_period_s", "< watchdog_stall_s",
        [](const R& c) {
          return Range{-kNoBound, c.watchdog_stall_s, false, true};
        },
        true);
    return model::ParamTable<R>(std::move(params));
  }();
  return table;
}

const model::ParamTable<LoggingConfig>& logging_params() {
  using L = LoggingConfig;
  static const model::ParamTable<L> table({
      model::choice<L, std::string>(
          "level",
          {{"trace", "trace"},
           {"debug", "debug"},
           {"info", "info"},
           {"warn", "warn"},
           {"error", "error"},
           {"critical", "critical"},
           {"off", "off"}},
          "the least severe level logged", [](auto& c) -> auto& { return c.level; }),
      model::choice<L, std::string>(
          "format", {{"auto", "auto"}, {"console", "console"}, {"journal", "journal"}},
          "journal: <N> priority prefixes, no time stamps; auto: journal under systemd",
          [](auto& c) -> auto& { return c.format; }),
  });
  return table;
}

const model::ParamTable<RecordingConfig>& recording_params() {
  using R = RecordingConfig;
  static const model::ParamTable<R> table({
      text<R>(
          "data_dir", "SWEEP directories are created below it, and only there",
          [](auto& c) -> auto& { return c.data_dir; }, "a path"),
      real<R>(
          "sweep_rest_s", "s", {0, 1}, "command at rest before each trial's first cycle",
          [](auto& c) -> auto& { return c.sweep_rest_s; }),
      integer<R>(
          "sweep_settle_cycles", "periods", 0, 1000, "rest recorded after each trial's last cycle",
          [](auto& c) -> auto& { return c.sweep_settle_cycles; }),
      real<R>(
          "sweep_span_m", "m", {0, 1, true},
          "a trial farther than this from the sweep's start returns there first",
          [](auto& c) -> auto& { return c.sweep_span_m; }),
      integer<R>(
          "sweep_max_trials", "count", 1, 10000000, "most trials in one SWEEP",
          [](auto& c) -> auto& { return c.sweep_max_trials; }),
  });
  return table;
}

const model::ParamTable<DeviceConfig>& device_params() {
  using D = DeviceConfig;
  const auto driver_section = [](const char* name) {
    return custom<D>(name, "map", "see its section", "",
                     "the driver's own keys (only for that driver)",
                     [](D&, const Node& v, const std::string& f, const std::string& k) {
                       if (!v.IsMap()) throw InputError(located(f, v, k, "expected a map"));
                     });
  };
  static const model::ParamTable<D> table({
      text<D>(
          "driver", "the backend", [](auto& d) -> auto& { return d.driver; }, "sim, modbus, usb"),
      real<D>(
          "poll_interval_s", "s", {1e-5, 10}, "each axis's position is read this often at rest",
          [](auto& d) -> auto& { return d.link.poll_interval_s; }),
      real<D>(
          "io_period_s", "s", {1e-6, 0.1}, "the device's I/O thread cycle",
          [](auto& d) -> auto& { return d.link.io_period_s; }),
      integer<D>(
          "stream_every", "count", 1, 1000000,
          "in a burst, every Nth streamed reading goes to the controller",
          [](auto& d) -> auto& { return d.link.stream_every; }),
      real<D>(
          "reconnect_min_s", "s", {1e-3, 60},
          "first retry after the device is lost (then doubling)",
          [](auto& d) -> auto& { return d.link.reconnect_min_s; }),
      model::with_relation(real<D>(
                               "reconnect_max_s", "s", {1e-3, 3600}, "longest wait between retries",
                               [](auto& d) -> auto& { return d.link.reconnect_max_s; }),
                           ">= reconnect_min_s",
                           [](const D& d) {
                             return model::Range{d.link.reconnect_min_s, 1e300};
                           }),
      real<D>(
          "crosstalk_fraction", "1", {-1, 1},
          "sim: a step of one axis moves the device's other axes by this share of it",
          [](auto& d) -> auto& { return d.crosstalk_fraction; }),
      driver_section("sim"),
      driver_section("modbus"),
      driver_section("usb"),
  });
  return table;
}

}  // namespace idm::daemon
