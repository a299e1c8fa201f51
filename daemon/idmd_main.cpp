// idmd: the daemon. `idmd --config FILE [--port N] [--unix PATH]`, `idmd --check-config FILE`.
// Exit codes: daemon/README.md (0 ok, 1 runtime error, 2 bad usage or config, 3 hardware not
// available, 4 cannot listen).
#include <grp.h>
#include <poll.h>
#include <pwd.h>
#include <signal.h>
#include <spdlog/pattern_formatter.h>
#include <spdlog/sinks/stdout_sinks.h>
#include <spdlog/spdlog.h>
#include <sys/signalfd.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <iostream>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "daemon/config.h"
#include "daemon/daemon.h"
#include "daemon/file_checks.h"
#include "daemon/notify.h"
#include "daemon/server.h"
#include "model/stage.h"
#include "model/yaml_util.h"

#ifndef IDM_VERSION
#define IDM_VERSION "0"
#endif

namespace {

using namespace idm::daemon;

constexpr const char* kDefaultConfig = IDMD_DEFAULT_CONFIG;

void usage(std::FILE* to) {
  std::fprintf(to,
               "usage: idmd [--config FILE] [--port N] [--unix PATH]\n"
               "       idmd --check-config FILE [--user NAME]\n"
               "       idmd --version\n"
               "       idmd --config-reference   (the generated key tables of config/README.md)\n"
               "  --config FILE        configuration (default %s)\n"
               "  --port N             TCP port of the command protocol (0: any free port)\n"
               "  --unix PATH          Unix socket of the command protocol (\"\": none)\n"
               "  --check-config FILE  check a configuration and exit (0 ok, 2 bad)\n"
               "  --user NAME          with --check-config: check as the user the service runs as\n"
               "                       (its files and directories with NAME's permissions; root)\n"
               "exit codes: 0 ok, 1 runtime error, 2 bad usage or configuration,\n"
               "            3 hardware not available, 4 cannot listen\n",
               kDefaultConfig);
}

// journald reads "<N>" priority prefixes on stderr/stdout lines (sd-daemon(3)).
class JournalPriority final : public spdlog::custom_flag_formatter {
 public:
  void format(const spdlog::details::log_msg& msg, const std::tm&,
              spdlog::memory_buf_t& dest) override {
    static const char* const kPrefix[] = {"<7>", "<7>", "<6>", "<4>", "<3>", "<2>", "<6>"};
    const char* p = kPrefix[static_cast<int>(msg.level)];
    dest.append(p, p + 3);
  }
  std::unique_ptr<custom_flag_formatter> clone() const override {
    return std::make_unique<JournalPriority>();
  }
};

void setup_logging(const LoggingConfig& cfg) {
  auto logger =
      std::make_shared<spdlog::logger>("idmd", std::make_shared<spdlog::sinks::stderr_sink_mt>());
  const bool journal =
      cfg.format == "journal" ||
      (cfg.format == "auto" && (std::getenv("JOURNAL_STREAM") || Notifier::under_systemd()));
  auto formatter = std::make_unique<spdlog::pattern_formatter>();
  if (journal) {
    formatter->add_flag<JournalPriority>('*').set_pattern("%*%v");
  } else {
    formatter->set_pattern("%Y-%m-%d %H:%M:%S.%e idmd %l: %v");
  }
  logger->set_formatter(std::move(formatter));
  logger->set_level(spdlog::level::from_str(cfg.level));
  logger->flush_on(spdlog::level::trace);
  spdlog::set_default_logger(logger);
}

// "axis x on card (sim), axis y on card (sim)"
std::string axes_text(const DaemonConfig& c) {
  std::string s;
  for (const AxisConfig& a : c.axes) {
    const DeviceConfig& d = c.devices[a.device];
    s += (s.empty() ? "" : ", ") + std::string("axis ") + a.name + " on " + d.name + " (" +
         d.driver + ")";
  }
  return s;
}

std::string describe(const DaemonConfig& c) {
  std::string s = axes_text(c);
  s += ", loop " + idm::model::format_number(1.0 / c.realtime.period_s) + " Hz";
  if (!c.server.tcp_address.empty())
    s += ", tcp " + c.server.tcp_address + ":" + std::to_string(c.server.tcp_port);
  if (!c.server.unix_socket.empty()) s += ", unix " + c.server.unix_socket;
  return s;
}

void log_notes(Daemon& daemon) {
  for (const Housekeeping::Note& note : daemon.take_notes()) {
    if (note.warning)
      spdlog::warn("{}", note.text);
    else
      spdlog::info("{}", note.text);
  }
}

bool parse_int(const std::string& text, long lo, long hi, int& out) {
  char* end = nullptr;
  errno = 0;
  const long v = std::strtol(text.c_str(), &end, 10);
  if (errno != 0 || end == text.c_str() || *end != '\0' || v < lo || v > hi) return false;
  out = static_cast<int>(v);
  return true;
}

// The command line: a config to run or one to check, and the listeners' overrides.
struct Options {
  std::string config_path = kDefaultConfig;
  std::string check_path;
  std::string check_user;  // --user: --check-config with this user's permissions
  bool have_port = false, have_unix = false;
  int port = 0;
  std::string unix_path;
};

// Reads argv into `o`; returns an exit code when idmd is done (--version, --help, a bad argument).
std::optional<int> parse_arguments(int argc, char** argv, Options& o) {
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&](const char* name) -> std::optional<std::string> {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "idmd: %s needs a value\n", name);
        usage(stderr);
        return std::nullopt;
      }
      return std::string(argv[++i]);
    };
    std::optional<std::string> v;
    if (a == "--config" || a == "-c") {
      if (!(v = value("--config"))) return exit_code::kBadConfig;
      o.config_path = *v;
    } else if (a == "--check-config") {
      if (!(v = value("--check-config"))) return exit_code::kBadConfig;
      o.check_path = *v;
    } else if (a == "--user") {
      if (!(v = value("--user"))) return exit_code::kBadConfig;
      o.check_user = *v;
    } else if (a == "--port") {
      if (!(v = value("--port"))) return exit_code::kBadConfig;
      if (!parse_int(*v, 0, 65535, o.port)) {
        std::fprintf(stderr, "idmd: --port: '%s' is not a port, allowed 0..65535\n", v->c_str());
        return exit_code::kBadConfig;
      }
      o.have_port = true;
    } else if (a == "--unix") {
      if (!(v = value("--unix"))) return exit_code::kBadConfig;
      o.unix_path = *v;
      o.have_unix = true;
    } else if (a == "--version") {
      std::printf("idmd %s\n", IDM_VERSION);
      return exit_code::kOk;
    } else if (a == "--config-reference") {
      std::fputs(config_reference().c_str(), stdout);
      return exit_code::kOk;
    } else if (a == "--help" || a == "-h") {
      usage(stdout);
      return exit_code::kOk;
    } else {
      std::fprintf(stderr, "idmd: unknown argument '%s'\n", a.c_str());
      usage(stderr);
      return exit_code::kBadConfig;
    }
  }
  if (!o.check_user.empty() && o.check_path.empty()) {
    std::fprintf(stderr,
                 "idmd: --user is for --check-config (the service's unit sets the user idmd runs "
                 "as: User=)\n");
    return exit_code::kBadConfig;
  }
  return std::nullopt;
}

// --check-config --user NAME: this process takes NAME's user, group and supplementary groups for
// good (it exits after the check), so that every file check below (access(), reading the config,
// the token, the calibrations) is NAME's. "" or why not.
std::string become_user(const std::string& name) {
  const passwd* pw = ::getpwnam(name.c_str());
  if (pw == nullptr) return "no user '" + name + "' on this machine";
  const uid_t uid = pw->pw_uid;
  const gid_t gid = pw->pw_gid;
  if (uid == ::getuid() && uid == ::geteuid()) return {};
  if (::initgroups(name.c_str(), gid) != 0 || ::setgid(gid) != 0 || ::setuid(uid) != 0)
    return std::string("cannot take its permissions (") + std::strerror(errno) +
           "): run the check as root (sudo)";
  return {};
}

int check_config(const std::string& path, const std::string& user) {
  if (!user.empty()) {
    if (const std::string why = become_user(user); !why.empty()) {
      std::fprintf(stderr, "idmd: --user %s: %s\n", user.c_str(), why.c_str());
      return exit_code::kBadConfig;
    }
  }
  try {
    const DaemonConfig c = load_daemon_config(path);
    if (!c.server.auth_token_file.empty()) (void)read_token_file(c.server.auth_token_file);
    const FileFindings files = check_config_files(c);
    std::vector<std::string> warnings = config_warnings(c);
    warnings.insert(warnings.end(), files.warnings.begin(), files.warnings.end());
    for (const std::string& w : warnings)
      std::fprintf(stderr, "idmd: %s: warning: %s\n", path.c_str(), w.c_str());
    for (const std::string& n : files.notes)
      std::fprintf(stderr, "idmd: %s: note: %s\n", path.c_str(), n.c_str());
    for (const std::string& e : files.errors)
      std::fprintf(stderr, "idmd: %s: %s\n", path.c_str(), e.c_str());
    if (!files.errors.empty()) return exit_code::kBadConfig;
    std::printf("%s: ok (%s)\n", path.c_str(), describe(c).c_str());
    return exit_code::kOk;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "idmd: %s\n", e.what());
    return exit_code::kBadConfig;
  }
}

// SIGTERM, SIGINT and SIGHUP, read from a signalfd by the main thread; every thread started later
// inherits the mask. -1 when there is none.
int signal_fd() {
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGHUP);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  const int sfd = signalfd(-1, &signals, SFD_CLOEXEC);
  if (sfd < 0) spdlog::error("signalfd: {}", std::strerror(errno));
  signal(SIGPIPE, SIG_IGN);
  signal(SIGXFSZ, SIG_IGN);  // a file past RLIMIT_FSIZE is a failed write (EFBIG), not an exit
  return sfd;
}

// Serves until SIGTERM or SIGINT (SIGHUP reloads the control settings) or the loop ends; returns
// the exit code, and in `why` what stopped the daemon (what a sweep it stops says).
int serve_until_signal(int sfd, Daemon& daemon, Notifier& notifier, const std::string& config_path,
                       const std::string& where, std::string& why) {
  bool reloading = false;  // a SIGHUP's reload on its way (housekeeping logs how it ended)
  for (;;) {
    pollfd pfd{sfd, POLLIN, 0};
    const int r = poll(&pfd, 1, 100);
    if (r < 0 && errno != EINTR) {
      spdlog::error("poll: {}", std::strerror(errno));
      return exit_code::kRuntimeError;
    }
    log_notes(daemon);
    if (reloading && !daemon.reload_pending()) {
      reloading = false;
      notifier.ready("Ready: control settings reloaded, listening on " + where);
    }
    if (!daemon.loop_running()) {
      spdlog::error("the real-time loop has ended");
      why = "the daemon stopped (the real-time loop ended)";
      return exit_code::kRuntimeError;
    }
    if (r <= 0 || !(pfd.revents & POLLIN)) continue;
    signalfd_siginfo si{};
    if (read(sfd, &si, sizeof si) != static_cast<ssize_t>(sizeof si)) continue;
    if (si.ssi_signo != SIGHUP) {
      const char* name = si.ssi_signo == SIGTERM ? "SIGTERM" : "SIGINT";
      spdlog::info("{}: stopping motion and shutting down", name);
      why = std::string("the daemon stopped (") + name + ")";
      return exit_code::kOk;
    }
    spdlog::info(
        "SIGHUP: reloading the control settings from {} (no motion in progress is "
        "stopped: the reload waits for it)",
        config_path);
    notifier.send_reloading();
    daemon.request_reload("SIGHUP");
    reloading = true;
  }
}

// "tcp 127.0.0.1:5025, unix /run/idmd/idmd.sock"
std::string listeners_text(const Server& server, const ServerConfig& sc) {
  std::string where;
  if (server.tcp_port() >= 0)
    where = "tcp " + sc.tcp_host + ":" + std::to_string(server.tcp_port());
  if (!sc.unix_path.empty())
    where += (where.empty() ? "" : ", ") + std::string("unix ") + sc.unix_path;
  return where;
}

void log_stopped(Daemon& daemon) {
  std::string outputs;
  for (int a = 0; a < daemon.axis_count(); ++a) {
    const double xi = daemon.sim_output_m(a);
    if (!std::isnan(xi))
      outputs += (outputs.empty() ? " (commanded elongation " : ", ") + daemon.axis_name(a) + " " +
                 idm::model::format_number(xi) + " m";
  }
  spdlog::info("stopped: every output at zero{}, devices shut down",
               outputs.empty() ? "" : outputs + ")");
}

// The command server's settings from the config's server: section (the token already read).
ServerConfig server_config(const DaemonConfig& config, const std::string& token) {
  ServerConfig sc;
  sc.tcp_host = config.server.tcp_address;
  sc.tcp_port = config.server.tcp_port;
  sc.unix_path = config.server.unix_socket;
  sc.max_clients = config.server.max_clients;
  sc.overflow_slots = config.server.overflow_slots;
  sc.tcp_token = token;
  sc.log = [](std::string_view line) { spdlog::debug("{}", line); };  // "command server: ..."
  sc.warn = [](std::string_view line) { spdlog::warn("{}", line); };
  return sc;
}

// Listens first (a second idmd on the same sockets stops here, before it touches a device),
// opens the devices, serves until a signal, shuts down; returns the exit code.
int run(const DaemonConfig& config, const std::string& config_path, const std::string& token,
        int sfd) {
  Notifier notifier;
  spdlog::info("idmd {} starting: {} ({})", IDM_VERSION, config_path, describe(config));
  for (const std::string& w : config_warnings(config)) spdlog::warn("{}", w);
  const ServerConfig sc = server_config(config, token);
  Daemon daemon(config);
  Server server(daemon, sc);
  if (const std::string err = server.listen(); !err.empty()) {
    spdlog::error("cannot listen: {}", err);
    notifier.status("Failed: cannot listen: " + err);
    return exit_code::kListenFailed;
  }
  notifier.status("Opening the devices: " + axes_text(config));
  try {
    const std::string warning = daemon.start();
    if (!warning.empty()) spdlog::warn("{}", warning);
  } catch (const StartError& e) {
    spdlog::error("{}", e.what());
    notifier.status(std::string("Failed: ") + e.what());
    return e.exit_code();
  } catch (const std::exception& e) {
    spdlog::error("start: {}", e.what());
    return exit_code::kRuntimeError;
  }
  log_notes(daemon);  // calibrations that could not be loaded
  if (const std::string err = server.start(); !err.empty()) {
    spdlog::error("cannot serve: {}", err);
    notifier.status("Failed: cannot serve: " + err);
    daemon.shutdown();
    return exit_code::kListenFailed;
  }
  const std::string where = listeners_text(server, sc);
  // One line on stdout that scripts and tests read for the port.
  std::printf("idmd: listening on %s\n", where.c_str());
  std::fflush(stdout);
  spdlog::info("ready: listening on {}", where);
  notifier.ready("Ready: " + axes_text(config) + ", listening on " + where);
  if (const double wd = notifier.start_watchdog([&daemon] { return daemon.loop_ticks(); }); wd > 0)
    spdlog::info("watchdog: every {} s while the real-time loop advances",
                 idm::model::format_number(wd / 4));

  std::string why = "the daemon stopped";
  const int exit_status = serve_until_signal(sfd, daemon, notifier, config_path, where, why);
  notifier.stopping("Stopping: bringing the actuator to rest");
  notifier.stop_watchdog();
  server.stop();
  daemon.shutdown(why);
  log_notes(daemon);
  log_stopped(daemon);
  return exit_status;
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  if (const std::optional<int> done = parse_arguments(argc, argv, o)) return *done;
  if (!o.check_path.empty()) return check_config(o.check_path, o.check_user);
  DaemonConfig config;
  std::string token;
  FileFindings file_findings;
  try {
    config = load_daemon_config(o.config_path);
    if (!config.server.auth_token_file.empty())
      token = read_token_file(config.server.auth_token_file);
    file_findings = check_config_files(config);
    if (!file_findings.errors.empty()) {
      for (const std::string& e : file_findings.errors)
        std::fprintf(stderr, "idmd: %s: %s\n", o.config_path.c_str(), e.c_str());
      return exit_code::kBadConfig;
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "idmd: %s\n", e.what());
    return exit_code::kBadConfig;
  }
  if (o.have_port) config.server.tcp_port = o.port;
  if (o.have_unix) config.server.unix_socket = o.unix_path;
  setup_logging(config.logging);
  const int sfd = signal_fd();
  if (sfd < 0) return exit_code::kRuntimeError;
  for (const std::string& w : file_findings.warnings) spdlog::warn("{}", w);
  for (const std::string& n : file_findings.notes) spdlog::info("{}", n);
  const int exit_status = run(config, o.config_path, token, sfd);
  close(sfd);
  return exit_status;
}
