// idm-web: a status page and Prometheus metrics for idmd, as a separate process and a client of
// the daemon's socket (README.md here).
//
//   idm-web [--idmd HOST:PORT | --unix PATH] [--listen HOST:PORT] [--allow-host NAME]...
//           [--control [--allow-remote-control] [--token-file FILE]] [--gap-report FILE]
//           [--poll S] [--timeout S] [--region-freq LIST] [--region-duty LIST]
//           [--max-connections N] [--version]
#include <poll.h>
#include <signal.h>
#include <sys/eventfd.h>
#include <sys/signalfd.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <iterator>
#include <optional>
#include <string>
#include <thread>
#include <utility>

#include "client/connection.h"
#include "daemon/protocol.h"
#include "model/stage.h"
#include "tools/cli.h"
#include "web/access.h"
#include "web/http_server.h"
#include "web/monitor.h"
#include "web/page.h"

using idm::model::InputError;
using idm::web::HttpRequest;
using idm::web::HttpResponse;

namespace {

const char* kUsage =
    "usage: idm-web [--idmd HOST:PORT | --unix PATH] [--listen HOST:PORT] [--allow-host NAME]...\n"
    "               [--control [--allow-remote-control] [--token-file FILE]]\n"
    "               [--gap-report FILE] [--poll S] [--timeout S] [--region-freq LIST]\n"
    "               [--region-duty LIST] [--max-connections N] [--version]\n"
    "A status page (/), JSON (/api/state, /api/history, /api/regions?axis=N, /api/gap) and\n"
    "Prometheus metrics (/metrics) for idmd, as a client of its socket.\n"
    "  --idmd HOST:PORT   idmd's TCP address (default: IDMD_SOCKET or IDMD_ADDRESS from the\n"
    "                     environment, else 127.0.0.1:5025)\n"
    "  --unix PATH        idmd's Unix socket instead\n"
    "  --listen HOST:PORT where to serve (default 127.0.0.1:8080; port 0: a free port)\n"
    "  --allow-host NAME  a Host name requests may carry besides localhost, 127.x and [::1] and\n"
    "                     the listen address (repeatable): how other machines name it\n"
    "  --control          allow STOP, moves, jogs and the speed limit from the page (POST);\n"
    "                     without it only GET\n"
    "  --allow-remote-control  allow --control on a listen address that is not loopback (needs\n"
    "                     a token)\n"
    "  --token-file FILE  control requests must carry this token (Authorization: Bearer TOKEN);\n"
    "                     the file is yours and mode 600; or IDM_WEB_TOKEN in the environment\n"
    "  --gap-report FILE  the JSON of idm-gap diagnose --json to show (read at each request,\n"
    "                     never through a symbolic link)\n"
    "  --poll S           how often idmd is polled (default 0.1 s)\n"
    "  --timeout S        longest wait for one of idmd's replies (default 5 s)\n"
    "  --region-freq LIST, --region-duty LIST  the region map's grid (default: rows over\n"
    "                     the axis's frequency range from idmd; duty 0.05:0.95:0.05 but 0.5)\n"
    "  --max-connections N  HTTP connections open at once (default 128, 1..1000)\n"
    "  --version          print the version\n";

constexpr std::size_t kMaxGapReportBytes = std::size_t{16} * 1024 * 1024;
constexpr int kMaxAxes = 64;

// An axis number from a request: digits only, 1..kMaxAxes; 0 when absent, -1 when bad.
int axis_param(const HttpRequest& req) {
  const auto v = req.param("axis");
  if (!v) return 0;
  if (v->empty() || v->size() > 2 || v->find_first_not_of("0123456789") != std::string::npos)
    return -1;
  const int n = std::stoi(*v);
  return n >= 1 && n <= kMaxAxes ? n : -1;
}

HttpResponse json_reply(int status, std::string body) {
  HttpResponse res;
  res.status = status;
  res.content_type = "application/json";
  res.body = std::move(body);
  res.headers.emplace_back("Cache-Control", "no-store");
  return res;
}

HttpResponse json_error(int status, const std::string& text) {
  return json_reply(status, "{\"ok\":false,\"error\":" + idm::web::json_string(text) + "}");
}

HttpResponse text_reply(int status, std::string body) {
  HttpResponse res;
  res.status = status;
  res.body = std::move(body);
  return res;
}

std::string format_number(double v) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.12g", v);
  return buf;
}

// What the command line asks for.
struct WebOptions {
  idm::web::MonitorOptions monitor;
  std::string listen_host = "127.0.0.1";
  int listen_port = 8080;
  std::vector<std::string> allow_hosts;
  bool control = false;
  bool allow_remote_control = false;
  std::string token_file;
  std::string gap_report;
  long max_connections = 128;
  bool help = false;     // --help: print the usage and do nothing else
  bool version = false;  // --version: the same
};

// The flags that take a value.
const char* const kValueFlags[] = {
    "--idmd", "--unix",    "--listen",      "--allow-host",  "--token-file",     "--gap-report",
    "--poll", "--timeout", "--region-freq", "--region-duty", "--max-connections"};

// One flag's value (a flag of kValueFlags) into `o`.
void take_value(WebOptions& o, const std::string& flag, const std::string& value, bool& have_idmd,
                bool& have_unix) {
  idm::web::MonitorOptions& options = o.monitor;
  if (flag == "--idmd") {
    const auto a = idm::client::parse_host_port(value);
    options.address.host = a.host;
    options.address.port = a.port;
    have_idmd = true;
  } else if (flag == "--unix") {
    if (value.empty()) throw InputError("--unix: an empty path");
    options.address.unix_path = value;
    have_unix = true;
  } else if (flag == "--listen") {
    const auto a = idm::client::parse_host_port(value, 8080, true);
    o.listen_host = a.host;
    o.listen_port = a.port;
  } else if (flag == "--allow-host") {
    idm::web::HostPolicy check;
    if (!check.allow(value))
      throw InputError("--allow-host: '" + value.substr(0, 100) + "' is not a host name");
    o.allow_hosts.push_back(value);
  } else if (flag == "--token-file") {
    o.token_file = value;
  } else if (flag == "--gap-report") {
    o.gap_report = value;
  } else if (flag == "--poll") {
    options.poll_s = idm::tools::parse_number(value, flag);
    if (options.poll_s < 0.01 || options.poll_s > 60)
      throw InputError("--poll: " + value + " is out of range, allowed 0.01..60 s");
  } else if (flag == "--timeout") {
    options.timeout_s = idm::tools::parse_number(value, flag);
    if (options.timeout_s < 0.1 || options.timeout_s > 600)
      throw InputError("--timeout: " + value + " is out of range, allowed 0.1..600 s");
  } else if (flag == "--max-connections") {
    const double n = idm::tools::parse_number(value, flag);
    if (n != std::floor(n) || n < 1 || n > 1000)
      throw InputError("--max-connections: " + value + " is out of range, allowed 1..1000");
    o.max_connections = static_cast<long>(n);
  } else {  // --region-freq, --region-duty
    const auto list = idm::tools::parse_list(value, flag);
    if (list.empty() || list.size() > 100)
      throw InputError(flag + ": 1 to 100 values, got " + std::to_string(list.size()));
    (flag == "--region-freq" ? options.region_freqs_hz : options.region_duties) = list;
  }
}

// The command line; InputError or AddressError for a bad one.
WebOptions parse_options(int argc, char** argv) {
  WebOptions o;
  bool have_idmd = false, have_unix = false;
  for (const double d : idm::tools::parse_list("0.05:0.95:0.05", "--region-duty"))
    if (std::abs(d - 0.5) > 1e-9) o.monitor.region_duties.push_back(d);
  for (int i = 1; i < argc; ++i) {
    const std::string flag = argv[i];
    if (flag == "--help" || flag == "--version") {
      (flag == "--help" ? o.help : o.version) = true;
      return o;
    }
    if (flag == "--control" || flag == "--allow-remote-control") {
      (flag == "--control" ? o.control : o.allow_remote_control) = true;
      continue;
    }
    if (flag == "--token")
      throw InputError(
          "--token: a token is never taken from the command line (ps shows it to every user): use "
          "--token-file FILE (mode 600) or IDM_WEB_TOKEN in the environment");
    const bool takes_value =
        std::find(std::begin(kValueFlags), std::end(kValueFlags), flag) != std::end(kValueFlags);
    if (!takes_value) throw InputError(flag + ": unknown flag (idm-web --help)");
    if (i + 1 >= argc) throw InputError(flag + ": missing value");
    take_value(o, flag, argv[i + 1], have_idmd, have_unix);
    ++i;
  }
  if (have_idmd && have_unix) throw InputError("--unix: give either --idmd or --unix");
  if (!have_idmd && !have_unix) o.monitor.address = idm::client::address_from_environment();
  return o;
}

// What the options allow, checked against where idm-web listens: control reachable from other
// machines needs --allow-remote-control and a token; InputError says what is missing.
std::string check_access(const WebOptions& o, bool loopback) {
  const char* env = std::getenv("IDM_WEB_TOKEN");
  const bool env_token = env != nullptr && *env != '\0';
  if (env_token && !o.token_file.empty())
    throw InputError("--token-file: IDM_WEB_TOKEN is set too: give the token one way");
  std::string token;
  if (!o.token_file.empty()) token = idm::web::token_from_file(o.token_file);
  if (env_token) token = idm::web::token_from_text(env, "IDM_WEB_TOKEN");
  if (o.allow_remote_control && !o.control)
    throw InputError("--allow-remote-control: only with --control");
  if (o.control && !loopback) {
    const std::string where =
        o.listen_host + " is not a loopback address: other machines could move the stage";
    if (!o.allow_remote_control)
      throw InputError("--control: " + where +
                       "; add --allow-remote-control and a token (--token-file FILE or "
                       "IDM_WEB_TOKEN), or listen on 127.0.0.1");
    if (token.empty())
      throw InputError("--allow-remote-control: " + where +
                       "; a token is needed (--token-file FILE or IDM_WEB_TOKEN)");
  }
  if (!o.gap_report.empty()) {
    struct stat st {};
    if (lstat(o.gap_report.c_str(), &st) == 0 && S_ISLNK(st.st_mode))
      throw InputError("--gap-report: " + o.gap_report +
                       " is a symbolic link: not followed (give the file itself)");
    if (lstat(o.gap_report.c_str(), &st) == 0 && !S_ISREG(st.st_mode))
      throw InputError("--gap-report: " + o.gap_report + " is not a regular file");
  }
  return token;
}

// The access rules' denial (access.h) as a reply: a control request's as JSON, others as text.
HttpResponse denial_reply(const idm::web::Denial& d) {
  HttpResponse res = d.control ? json_error(d.status, d.why) : text_reply(d.status, d.why + "\n");
  res.headers.insert(res.headers.end(), d.headers.begin(), d.headers.end());
  return res;
}

// Everything idm-web answers, after the access rules.
struct Routes {
  idm::web::Monitor& monitor;
  const WebOptions& options;
  const idm::web::HttpServer* server = nullptr;  // set before it serves
  bool token_required = false;

  HttpResponse get(const HttpRequest& req) const;
  HttpResponse gap() const;
  HttpResponse post(const HttpRequest& req) const;
};

HttpResponse Routes::get(const HttpRequest& req) const {
  HttpResponse res;
  if (req.path == "/") {
    res.content_type = "text/html; charset=utf-8";
    res.body = idm::web::page_html();
  } else if (req.path == "/app.js") {
    res.content_type = "text/javascript; charset=utf-8";
    res.body = idm::web::page_js();
  } else if (req.path == "/api/state") {
    return json_reply(200,
                      idm::web::state_json(monitor.snapshot(), options.control, token_required));
  } else if (req.path == "/api/history") {
    return json_reply(200, idm::web::history_json(monitor.snapshot()));
  } else if (req.path == "/api/regions") {
    const int axis = axis_param(req);
    if (axis <= 0) return json_error(400, "axis=N (1.." + std::to_string(kMaxAxes) + ") is needed");
    const idm::web::RegionMap m = monitor.regions(axis);
    return json_reply(m.error.empty() ? 200 : 502, idm::web::regions_json(m));
  } else if (req.path == "/api/gap") {
    return gap();
  } else if (req.path == "/metrics") {
    res.content_type = "text/plain; version=0.0.4; charset=utf-8";
    res.body =
        idm::web::metrics_text(monitor.snapshot(), server->open_connections(), server->requests());
    res.headers.emplace_back("Cache-Control", "no-store");
  } else {
    return text_reply(404, "not found\n");
  }
  return res;
}

// The gap report, read at each request through a descriptor opened without following a symbolic
// link (a user who may write where the report lies must not make idm-web read another file for
// them).
HttpResponse Routes::gap() const {
  using idm::web::FileRead;
  if (options.gap_report.empty())
    return json_error(404, "no gap report (idm-web --gap-report FILE)");
  FileRead f = idm::web::read_file_nofollow(options.gap_report, kMaxGapReportBytes);
  switch (f.kind) {
    case FileRead::kOk:
      return json_reply(200, std::move(f.text));
    case FileRead::kMissing:
      return json_error(404, "no gap report at " + options.gap_report + " yet");
    case FileRead::kSymlink:
    case FileRead::kNotRegular:
      return json_error(403, "the gap report " + f.why);
    case FileRead::kTooLarge:
      return json_error(413, "the gap report " + f.why);
    case FileRead::kUnreadable:
      break;
  }
  return json_error(404, "cannot read the gap report " + f.why);
}

// A control line to idmd: {"ok":true}, or the daemon's refusal (its error) as `refused`.
HttpResponse control_reply(idm::web::Monitor& monitor, const std::string& line, int refused) {
  try {
    monitor.command(line);
    return json_reply(200, "{\"ok\":true}");
  } catch (const std::exception& e) {
    return json_error(refused, e.what());
  }
}

// A number parameter of a control request: finite, at most 64 characters; false when not.
bool number_param(const HttpRequest& req, const char* name, double& value) {
  const std::string text = req.param(name).value_or("");
  return text.size() <= 64 && idm::daemon::parse_number(text, name, value).ok();
}

// STOP, moves, jogs and the speed limit (POST); the access rules let them through only with
// --control.
HttpResponse Routes::post(const HttpRequest& req) const {
  const int axis = axis_param(req);
  if (req.path == "/api/stop") {
    if (axis < 0) return json_error(400, "axis: expected 1.." + std::to_string(kMaxAxes));
    return control_reply(
        monitor, axis == 0 ? std::string("STOP") : "AXIS" + std::to_string(axis) + ":STOP", 502);
  }
  if (axis <= 0) return json_error(400, "axis=N (1.." + std::to_string(kMaxAxes) + ") is needed");
  const std::string prefix = "AXIS" + std::to_string(axis) + ":";
  if (req.path == "/api/jog") {
    const std::string direction = req.param("direction").value_or("");
    if (direction != "positive" && direction != "negative")
      return json_error(400, "direction: positive or negative is needed");
    return control_reply(monitor, prefix + (direction == "positive" ? "JOG POS" : "JOG NEG"), 422);
  }
  if (req.path == "/api/velocity") {
    double speed = 0;
    if (!number_param(req, "speed", speed))
      return json_error(400, "speed: a finite number of m/s is needed (0: no limit)");
    return control_reply(monitor, prefix + "MOVE:VEL " + format_number(speed), 422);
  }
  double target = 0;
  if (!number_param(req, "target", target))
    return json_error(400, "target: a finite number of metres is needed");
  return control_reply(monitor, prefix + "MOVE:ABS " + format_number(target), 422);
}

// Serves until SIGINT or SIGTERM (blocked in every thread, read from a signalfd) or until the
// server fails; a thread waits for either the signal or the server's end (an eventfd).
bool serve_until_signal(idm::web::HttpServer& server, const sigset_t& signals) {
  const int signal_fd = signalfd(-1, &signals, SFD_CLOEXEC);
  const int done_fd = eventfd(0, EFD_CLOEXEC);
  if (signal_fd < 0 || done_fd < 0) {
    std::fprintf(stderr, "idm-web: signalfd/eventfd: %s\n", std::strerror(errno));
    if (signal_fd >= 0) close(signal_fd);
    if (done_fd >= 0) close(done_fd);
    return false;
  }
  std::thread signal_thread([&] {
    pollfd fds[2] = {{signal_fd, POLLIN, 0}, {done_fd, POLLIN, 0}};
    while (poll(fds, 2, -1) < 0 && errno == EINTR) {
    }
    if (fds[0].revents & POLLIN) server.stop();
  });
  const bool ok = server.run();
  // run ended (a signal, or an error): make sure the signal thread ends too.
  const std::uint64_t one = 1;
  if (write(done_fd, &one, sizeof one) != sizeof one) std::perror("idm-web: eventfd");
  signal_thread.join();
  close(signal_fd);
  close(done_fd);
  return ok;
}

// Loud lines on stderr when the page is reachable from other machines.
void warn_if_remote(const WebOptions& o, const idm::web::AccessRules& rules, bool loopback,
                    int port) {
  if (loopback) return;
  std::string names;
  for (const std::string& n : rules.hosts.listed()) names += " " + n;
  std::fprintf(stderr,
               "idm-web: listening on %s, which other machines may reach; Host names accepted: "
               "localhost, 127.x, [::1]%s\n",
               o.listen_host.c_str(), names.c_str());
  if (o.control)
    std::fprintf(stderr,
                 "idm-web: WARNING: CONTROL IS REACHABLE FROM OTHER MACHINES: anyone who reaches "
                 "%s:%d with the token can STOP and MOVE the stage\n",
                 o.listen_host.c_str(), port);
}

int run(const WebOptions& o, const idm::web::AccessRules& rules, bool loopback) {
  // SIGINT/SIGTERM end the server; they are blocked here, before any thread starts, and read
  // from a signalfd (serve_until_signal).
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  signal(SIGPIPE, SIG_IGN);

  idm::web::Monitor monitor(o.monitor);
  Routes routes{monitor, o, nullptr, !rules.token.empty()};
  idm::web::HttpLimits limits;
  limits.max_connections = static_cast<std::size_t>(o.max_connections);
  idm::web::HttpServer server(
      limits,
      [&routes, &rules](const HttpRequest& req) {
        if (const auto denial = idm::web::deny(rules, req)) return denial_reply(*denial);
        return req.method == "POST" ? routes.post(req) : routes.get(req);
      },
      [](const HttpRequest& req) { return idm::web::is_control(req); },
      {{"X-Content-Type-Options", "nosniff"},
       {"X-Frame-Options", "DENY"},
       {"Referrer-Policy", "no-referrer"},
       {"Content-Security-Policy",
        "default-src 'self'; style-src 'self' 'unsafe-inline'; frame-ancestors 'none'"}});
  routes.server = &server;
  try {
    server.bind(o.listen_host, o.listen_port);
  } catch (const idm::web::BindError& e) {
    std::fprintf(stderr, "idm-web: %s\n", e.what());
    return 4;
  }
  warn_if_remote(o, rules, loopback && server.loopback(), server.port());
  monitor.start();
  const std::string shown_host =
      o.listen_host.find(':') != std::string::npos ? "[" + o.listen_host + "]" : o.listen_host;
  std::printf("idm-web: listening on http://%s:%d/ (idmd at %s, control %s)\n", shown_host.c_str(),
              server.port(), o.monitor.address.text().c_str(),
              !o.control            ? "off"
              : rules.token.empty() ? "on"
                                    : "on, with a token");
  std::fflush(stdout);
  const bool ok = serve_until_signal(server, signals);
  monitor.stop();
  return ok ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) {
  WebOptions o;
  idm::web::AccessRules rules;
  bool loopback = false;
  try {
    o = parse_options(argc, argv);
    if (o.help || o.version) {
      if (o.help) std::fputs(kUsage, stdout);
      if (o.version) std::printf("idm-web %s\n", IDM_VERSION);
      return 0;
    }
    try {
      loopback = idm::web::listens_on_loopback(o.listen_host);
    } catch (const idm::web::BindError& e) {
      std::fprintf(stderr, "idm-web: %s\n", e.what());
      return 4;
    }
    rules.token = check_access(o, loopback);
  } catch (const InputError& e) {
    std::fprintf(stderr, "idm-web: %s\n", e.what());
    return 2;
  } catch (const idm::client::AddressError& e) {
    std::fprintf(stderr, "idm-web: %s\n", e.what());
    return 2;
  }
  rules.control = o.control;
  for (const std::string& name : o.allow_hosts) rules.hosts.allow(name);
  rules.hosts.allow(o.listen_host);  // the literal listen address
  return run(o, rules, loopback);
}
