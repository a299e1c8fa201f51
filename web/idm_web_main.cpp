// idm-web: a status page and Prometheus metrics for idmd, as a separate process and a client of
// the daemon's socket (README.md here).
//
//   idm-web [--idmd HOST:PORT | --unix PATH] [--listen HOST:PORT] [--control] [--gap-report FILE]
//           [--poll S] [--timeout S] [--region-freq LIST] [--region-duty LIST]
#include <httplib.h>
#include <poll.h>
#include <signal.h>
#include <sys/eventfd.h>
#include <sys/signalfd.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>
#include <thread>

#include "client/connection.h"
#include "daemon/protocol.h"
#include "model/stage.h"
#include "tools/cli.h"
#include "web/monitor.h"
#include "web/page.h"

using idm::model::InputError;

namespace {

const char* kUsage =
    "usage: idm-web [--idmd HOST:PORT | --unix PATH] [--listen HOST:PORT] [--control]\n"
    "               [--gap-report FILE] [--poll S] [--timeout S] [--region-freq LIST]\n"
    "               [--region-duty LIST]\n"
    "A status page (/), JSON (/api/state, /api/history, /api/regions?axis=N, /api/gap) and\n"
    "Prometheus metrics (/metrics) for idmd, as a client of its socket.\n"
    "  --idmd HOST:PORT   idmd's TCP address (default: IDMD_SOCKET or IDMD_ADDRESS from the\n"
    "                     environment, else 127.0.0.1:5025)\n"
    "  --unix PATH        idmd's Unix socket instead\n"
    "  --listen HOST:PORT where to serve (default 127.0.0.1:8080; port 0: a free port)\n"
    "  --control          allow STOP and moves from the page (POST); without it only GET\n"
    "  --gap-report FILE  the JSON of idm-gap diagnose --json to show (read at each request)\n"
    "  --poll S           how often idmd is polled (default 0.1 s)\n"
    "  --timeout S        longest wait for one of idmd's replies (default 5 s)\n"
    "  --region-freq LIST, --region-duty LIST  the region map's grid (default: rows over\n"
    "                     the axis's frequency range from idmd; duty 0.05:0.95:0.05 but 0.5)\n";

constexpr std::size_t kMaxGapReportBytes = std::size_t{16} * 1024 * 1024;
constexpr int kMaxAxes = 64;

// Counts the HTTP connections being served: every connection is one task of the pool.
class CountingQueue : public httplib::TaskQueue {
 public:
  CountingQueue(std::size_t threads, std::atomic<std::uint64_t>& open)
      : pool_(threads), open_(open) {}
  void enqueue(std::function<void()> fn) override {
    pool_.enqueue([this, fn = std::move(fn)] {
      ++open_;
      fn();
      --open_;
    });
  }
  void shutdown() override { pool_.shutdown(); }

 private:
  httplib::ThreadPool pool_;
  std::atomic<std::uint64_t>& open_;
};

bool is_loopback(const std::string& host) {
  return host == "127.0.0.1" || host == "localhost" || host == "::1" || host.rfind("127.", 0) == 0;
}

// An axis number from a request: digits only, 1..kMaxAxes; 0 when absent or bad.
int axis_param(const httplib::Request& req) {
  if (!req.has_param("axis")) return 0;
  const std::string v = req.get_param_value("axis");
  if (v.empty() || v.size() > 2 || v.find_first_not_of("0123456789") != std::string::npos)
    return -1;
  const int n = std::stoi(v);
  return n >= 1 && n <= kMaxAxes ? n : -1;
}

void json_reply(httplib::Response& res, int status, const std::string& body) {
  res.status = status;
  res.set_header("Cache-Control", "no-store");
  res.set_content(body, "application/json");
}

void json_error(httplib::Response& res, int status, const std::string& text) {
  json_reply(res, status, "{\"ok\":false,\"error\":" + idm::web::json_string(text) + "}");
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
  bool control = false;
  std::string gap_report;
  bool help = false;  // --help: print the usage and do nothing else
};

// The command line; InputError or AddressError for a bad one.
WebOptions parse_options(int argc, char** argv) {
  WebOptions o;
  idm::web::MonitorOptions& options = o.monitor;
  bool have_idmd = false, have_unix = false;
  for (const double d : idm::tools::parse_list("0.05:0.95:0.05", "--region-duty"))
    if (std::abs(d - 0.5) > 1e-9) options.region_duties.push_back(d);
  for (int i = 1; i < argc; ++i) {
    const std::string flag = argv[i];
    if (flag == "--help") {
      o.help = true;
      return o;
    }
    if (flag == "--control") {
      o.control = true;
      continue;
    }
    if (flag != "--idmd" && flag != "--unix" && flag != "--listen" && flag != "--gap-report" &&
        flag != "--poll" && flag != "--timeout" && flag != "--region-freq" &&
        flag != "--region-duty")
      throw InputError(flag + ": unknown flag (idm-web --help)");
    if (i + 1 >= argc) throw InputError(flag + ": missing value");
    const std::string value = argv[++i];
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
    } else {
      const auto list = idm::tools::parse_list(value, flag);
      if (list.empty() || list.size() > 100)
        throw InputError(flag + ": 1 to 100 values, got " + std::to_string(list.size()));
      (flag == "--region-freq" ? options.region_freqs_hz : options.region_duties) = list;
    }
  }
  if (have_idmd && have_unix) throw InputError("--unix: give either --idmd or --unix");
  if (!have_idmd && !have_unix) options.address = idm::client::address_from_environment();
  return o;
}

// Security headers, the Host and method checks in front of every route, and the error replies.
// bound_port is read at each request (it is known once the server is bound).
void guard_requests(httplib::Server& server, const WebOptions& o, const int& bound_port,
                    std::atomic<std::uint64_t>& requests) {
  server.set_default_headers({{"X-Content-Type-Options", "nosniff"},
                              {"X-Frame-Options", "DENY"},
                              {"Referrer-Policy", "no-referrer"},
                              {"Content-Security-Policy",
                               "default-src 'self'; style-src 'self' 'unsafe-inline'; "
                               "frame-ancestors 'none'"}});

  const bool loopback = is_loopback(o.listen_host);
  const bool control = o.control;
  const std::string listen_host = o.listen_host;
  server.set_pre_routing_handler([&bound_port, &requests, loopback, control, listen_host](
                                     const httplib::Request& req, httplib::Response& res) {
    ++requests;
    // Bound to loopback, a page from elsewhere may still reach us through a DNS name that points
    // to 127.0.0.1: only requests naming this host are served.
    if (loopback && req.has_header("Host")) {
      std::string host = req.get_header_value("Host");
      const std::string port_suffix = ":" + std::to_string(bound_port);
      if (host.size() > port_suffix.size() &&
          host.compare(host.size() - port_suffix.size(), port_suffix.size(), port_suffix) == 0)
        host.resize(host.size() - port_suffix.size());
      if (host != "127.0.0.1" && host != "localhost" && host != "[::1]" && host != listen_host) {
        res.status = 403;
        res.set_content("forbidden: Host " + host.substr(0, 100) + " is not this server\n",
                        "text/plain");
        return httplib::Server::HandlerResponse::Handled;
      }
    }
    const bool read = req.method == "GET" || req.method == "HEAD";
    const bool control_post =
        control && req.method == "POST" && (req.path == "/api/stop" || req.path == "/api/move");
    if (!read && !control_post) {
      res.status = 405;
      res.set_header("Allow", control ? "GET, HEAD, POST" : "GET, HEAD");
      res.set_content(control
                          ? "method not allowed\n"
                          : "method not allowed: idm-web is read-only (start it with --control)\n",
                      "text/plain");
      return httplib::Server::HandlerResponse::Handled;
    }
    // A form on another site cannot set this header; a script there cannot without a CORS
    // preflight, which is never granted.
    if (control_post && req.get_header_value("X-Idm-Control") != "1") {
      json_error(res, 403, "control requests need the header X-Idm-Control: 1");
      return httplib::Server::HandlerResponse::Handled;
    }
    return httplib::Server::HandlerResponse::Unhandled;
  });
  server.set_exception_handler(
      [](const httplib::Request&, httplib::Response& res, const std::exception_ptr& ep) {
        std::string what = "internal error";
        try {
          if (ep) std::rethrow_exception(ep);
        } catch (const std::exception& e) {
          what = e.what();
        } catch (...) {
        }
        json_error(res, 500, what);
      });
  server.set_error_handler([](const httplib::Request&, httplib::Response& res) {
    if (res.body.empty())
      res.set_content("HTTP " + std::to_string(res.status) + "\n", "text/plain");
  });
}

// The page, its script and the read-only JSON and metrics.
void add_read_routes(httplib::Server& server, idm::web::Monitor& monitor, const WebOptions& o,
                     const std::atomic<std::uint64_t>& open_connections,
                     const std::atomic<std::uint64_t>& requests) {
  server.Get("/", [](const httplib::Request&, httplib::Response& res) {
    res.set_content(idm::web::page_html(), "text/html; charset=utf-8");
  });
  server.Get("/app.js", [](const httplib::Request&, httplib::Response& res) {
    res.set_content(idm::web::page_js(), "text/javascript; charset=utf-8");
  });
  server.Get("/api/state",
             [&monitor, control = o.control](const httplib::Request&, httplib::Response& res) {
               json_reply(res, 200, idm::web::state_json(monitor.snapshot(), control));
             });
  server.Get("/api/history", [&](const httplib::Request&, httplib::Response& res) {
    json_reply(res, 200, idm::web::history_json(monitor.snapshot()));
  });
  server.Get("/api/regions", [&](const httplib::Request& req, httplib::Response& res) {
    const int axis = axis_param(req);
    if (axis <= 0)
      return json_error(res, 400, "axis=N (1.." + std::to_string(kMaxAxes) + ") is needed");
    const idm::web::RegionMap m = monitor.regions(axis);
    json_reply(res, m.error.empty() ? 200 : 502, idm::web::regions_json(m));
  });
  server.Get("/api/gap",
             [gap_report = o.gap_report](const httplib::Request&, httplib::Response& res) {
               if (gap_report.empty())
                 return json_error(res, 404, "no gap report (idm-web --gap-report FILE)");
               std::error_code ec;
               if (!std::filesystem::is_regular_file(gap_report, ec))
                 return json_error(res, 404, "no gap report at " + gap_report + " yet");
               std::ifstream in(gap_report, std::ios::binary);
               if (!in) return json_error(res, 404, "cannot read the gap report " + gap_report);
               std::string body;
               body.resize(kMaxGapReportBytes + 1);
               in.read(body.data(), static_cast<std::streamsize>(body.size()));
               body.resize(static_cast<std::size_t>(in.gcount()));
               if (body.size() > kMaxGapReportBytes)
                 return json_error(res, 413, "the gap report is too large");
               json_reply(res, 200, body);
             });
  server.Get("/metrics", [&](const httplib::Request&, httplib::Response& res) {
    res.set_header("Cache-Control", "no-store");
    res.set_content(idm::web::metrics_text(monitor.snapshot(), open_connections, requests),
                    "text/plain; version=0.0.4; charset=utf-8");
  });
}

// STOP and moves (POST); guard_requests lets them through only with --control.
void add_control_routes(httplib::Server& server, idm::web::Monitor& monitor) {
  server.Post("/api/stop", [&](const httplib::Request& req, httplib::Response& res) {
    const int axis = axis_param(req);
    if (axis < 0) return json_error(res, 400, "axis: expected 1.." + std::to_string(kMaxAxes));
    try {
      monitor.command(axis == 0 ? std::string("STOP") : "AXIS" + std::to_string(axis) + ":STOP");
      json_reply(res, 200, "{\"ok\":true}");
    } catch (const std::exception& e) {
      json_error(res, 502, e.what());
    }
  });
  server.Post("/api/move", [&](const httplib::Request& req, httplib::Response& res) {
    const int axis = axis_param(req);
    if (axis <= 0)
      return json_error(res, 400, "axis=N (1.." + std::to_string(kMaxAxes) + ") is needed");
    double target = 0;
    const std::string text = req.get_param_value("target");
    if (text.size() > 64 || !idm::daemon::parse_number(text, "target", target).ok())
      return json_error(res, 400, "target: a finite number of metres is needed");
    try {
      monitor.command("AXIS" + std::to_string(axis) + ":MOVE:ABS " + format_number(target));
      json_reply(res, 200, "{\"ok\":true}");
    } catch (const std::exception& e) {
      json_error(res, 422, e.what());
    }
  });
}

// Serves until SIGINT or SIGTERM (blocked in every thread, read from a signalfd) or until the
// server fails; a thread waits for either the signal or the server's end (an eventfd).
bool serve_until_signal(httplib::Server& server, const sigset_t& signals) {
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
  const bool ok = server.listen_after_bind();
  // listen ended (a signal, or an error): make sure the signal thread ends too.
  const std::uint64_t one = 1;
  if (write(done_fd, &one, sizeof one) != sizeof one) std::perror("idm-web: eventfd");
  signal_thread.join();
  close(signal_fd);
  close(done_fd);
  return ok;
}

}  // namespace

int main(int argc, char** argv) {
  WebOptions o;
  try {
    o = parse_options(argc, argv);
  } catch (const InputError& e) {
    std::fprintf(stderr, "idm-web: %s\n", e.what());
    return 2;
  } catch (const idm::client::AddressError& e) {
    std::fprintf(stderr, "idm-web: %s\n", e.what());
    return 2;
  }
  if (o.help) {
    std::fputs(kUsage, stdout);
    return 0;
  }

  // SIGINT/SIGTERM end the server; they are blocked here, before any thread starts, and read
  // from a signalfd (serve_until_signal).
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  signal(SIGPIPE, SIG_IGN);

  idm::web::Monitor monitor(o.monitor);
  monitor.start();

  httplib::Server server;
  std::atomic<std::uint64_t> open_connections{0}, requests{0};
  server.new_task_queue = [&] { return new CountingQueue(16, open_connections); };
  server.set_payload_max_length(std::size_t{64} * 1024);
  server.set_read_timeout(5, 0);
  server.set_write_timeout(5, 0);
  server.set_keep_alive_timeout(2);
  server.set_keep_alive_max_count(1000);
  int bound_port = 0;
  guard_requests(server, o, bound_port, requests);
  add_read_routes(server, monitor, o, open_connections, requests);
  add_control_routes(server, monitor);

  if (o.listen_port == 0) {
    bound_port = server.bind_to_any_port(o.listen_host);
  } else {
    bound_port = server.bind_to_port(o.listen_host, o.listen_port) ? o.listen_port : -1;
  }
  if (bound_port <= 0) {
    std::fprintf(stderr, "idm-web: cannot listen on %s:%d\n", o.listen_host.c_str(), o.listen_port);
    monitor.stop();
    return 4;
  }
  const std::string shown_host =
      o.listen_host.find(':') != std::string::npos ? "[" + o.listen_host + "]" : o.listen_host;
  std::printf("idm-web: listening on http://%s:%d/ (idmd at %s, control %s)\n", shown_host.c_str(),
              bound_port, o.monitor.address.text().c_str(), o.control ? "on" : "off");
  std::fflush(stdout);

  const bool ok = serve_until_signal(server, signals);
  monitor.stop();
  return ok ? 0 : 1;
}
