// Helpers of bench/daemon_bench.sh (the daemon's side-by-side comparisons):
//   daemon_bench loop SECONDS PERIOD_S CONFIG   the daemon's real-time loop on the simulated stage
//                                               (moving back and forth): wake-up latency
//                                               p50/p99/max
//   daemon_bench echo                           a minimal line echo server (TCP, epoll), prints its
//   port daemon_bench rtt IDMD_PORT ECHO_PORT CLIENTS QUERIES ROUNDS
//                                               POS? round trips from CLIENTS threads to each
//                                               server, same client code, interleaved rounds:
//                                               p50/p99/max
//   daemon_bench rss MOVES CONFIG               RSS before/after MOVES moves on the simulated stage
//   daemon_bench loop-stalled SECONDS PERIOD_S CONFIG PID
//                                               the loop on a Modbus device whose server (PID,
//                                               idm-simdev) is stopped (SIGSTOP) the whole time
#include <arpa/inet.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <signal.h>
#include <sys/epoll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include "daemon/config.h"
#include "daemon/daemon.h"

using namespace idm::daemon;

namespace {

double now_s() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

double percentile_from_bins(const LoopStats& s, double q) {
  std::uint64_t total = 0;
  for (auto b : s.bins) total += b;
  std::uint64_t acc = 0;
  for (int i = 0; i < 32; ++i) {
    acc += s.bins[i];
    if (acc >= q * static_cast<double>(total)) return (i + 1) * s.bin_width_s;
  }
  return 32 * s.bin_width_s;
}

DaemonConfig bench_config(const std::string& path, double period_s) {
  DaemonConfig c = load_daemon_config(path);
  c.realtime.period_s = period_s;
  // 32 bins of 4 us: 0..124 us, the last one holds the rest (a p99 there is reported as a bound).
  c.realtime.histogram_bin_s = 4e-6;
  c.axes[0].control.calibration_file.clear();
  return c;
}

int loop_bench(double seconds, double period_s, const std::string& config, int stall_pid = 0) {
  Daemon d(bench_config(config, period_s));
  const std::string warning = d.start();
  if (!warning.empty()) std::fprintf(stderr, "%s\n", warning.c_str());
  // A stalled server: every request to it hangs until the driver's timeout, the device is lost,
  // reconnects hang too. The loop must not notice.
  if (stall_pid > 0) kill(stall_pid, SIGSTOP);
  const LoopStats before = d.loop_stats();
  const double end = now_s() + seconds;
  int sign = 1;
  while (now_s() < end) {
    if (d.motion_done()) {
      d.move_relative(0, sign * 50e-6);
      sign = -sign;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  LoopStats s = d.loop_stats();
  if (stall_pid > 0) {
    // Only the stalled stretch: the histogram since the stop.
    for (int i = 0; i < 32; ++i) s.bins[i] -= before.bins[i];
    s.wakeups -= before.wakeups;
    s.deadline_misses -= before.deadline_misses;
    const idm::drivers::LinkHealth h = d.link_of(0).health();
    std::printf("device while stalled: %s, %u losses, last error: %s\n",
                idm::drivers::link_state_name(h.state), h.losses, h.message);
    kill(stall_pid, SIGCONT);
  }
  d.shutdown();
  const double p99 = percentile_from_bins(s, 0.99);
  if (p99 >= 32 * s.bin_width_s)
    std::fprintf(stderr, "idmd_loop: p99 is past the histogram (>= %.0f us): a bound\n", p99 * 1e6);
  std::printf(
      "%s wakeups=%llu misses=%llu bin_us=%.0f min_us=%.1f avg_us=%.1f p50_us=%.0f p99_us=%.0f "
      "max_us=%.1f\n",
      stall_pid > 0 ? "idmd_loop_stalled_modbus" : "idmd_loop",
      static_cast<unsigned long long>(s.wakeups),
      static_cast<unsigned long long>(s.deadline_misses), s.bin_width_s * 1e6,
      s.latency_min_s * 1e6, s.latency_avg_s * 1e6, percentile_from_bins(s, 0.5) * 1e6, p99 * 1e6,
      s.latency_max_s * 1e6);
  return 0;
}

int echo_server() {
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  int one = 1;
  setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
  if (bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 || listen(fd, 64) != 0) return 1;
  socklen_t len = sizeof a;
  getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
  std::printf("echo listening on 127.0.0.1:%d\n", ntohs(a.sin_port));
  std::fflush(stdout);
  const int ep = epoll_create1(0);
  epoll_event ev{EPOLLIN, {}};
  ev.data.fd = fd;
  epoll_ctl(ep, EPOLL_CTL_ADD, fd, &ev);
  epoll_event events[64];
  char buf[4096];
  for (;;) {
    const int n = epoll_wait(ep, events, 64, -1);
    for (int i = 0; i < n; ++i) {
      const int f = events[i].data.fd;
      if (f == fd) {
        const int c = accept(fd, nullptr, nullptr);
        setsockopt(c, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
        epoll_event ce{EPOLLIN, {}};
        ce.data.fd = c;
        epoll_ctl(ep, EPOLL_CTL_ADD, c, &ce);
      } else {
        const ssize_t r = read(f, buf, sizeof buf);
        if (r <= 0) {
          close(f);
          continue;
        }
        // A fixed reply line per request line, as long as a POS? reply.
        for (ssize_t k = 0; k < r; ++k)
          if (buf[k] == '\n') (void)!write(f, "1.23456789012e-06\n", 18);
      }
    }
  }
}

int connect_client(int port) {
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  int one = 1;
  setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(static_cast<std::uint16_t>(port));
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) {
    close(fd);
    return -1;
  }
  return fd;
}

// One round: every client thread sends `queries` POS? one at a time and waits for each reply.
void rtt_round(const std::vector<int>& fds, int queries, std::vector<double>& out) {
  std::vector<std::vector<double>> lat(fds.size());
  std::vector<std::thread> threads;
  for (std::size_t c = 0; c < fds.size(); ++c) {
    threads.emplace_back([&, c] {
      lat[c].reserve(static_cast<std::size_t>(queries));
      char buf[256];
      for (int q = 0; q < queries; ++q) {
        const double t0 = now_s();
        if (write(fds[c], "POS?\n", 5) != 5) return;
        for (;;) {
          const ssize_t r = read(fds[c], buf, sizeof buf);
          if (r <= 0) return;
          if (std::memchr(buf, '\n', static_cast<std::size_t>(r))) break;
        }
        lat[c].push_back(now_s() - t0);
      }
    });
  }
  for (auto& t : threads) t.join();
  for (auto& v : lat) out.insert(out.end(), v.begin(), v.end());
}

void print_rtt(const char* name, std::vector<double>& all, int expected) {
  std::sort(all.begin(), all.end());
  if (all.empty()) {
    std::printf("%s rtt n=0 (no reply)\n", name);
    return;
  }
  std::printf("%s rtt n=%zu%s p50_us=%.1f p99_us=%.1f max_us=%.1f\n", name, all.size(),
              static_cast<int>(all.size()) == expected ? "" : " (INCOMPLETE)",
              all[all.size() / 2] * 1e6,
              all[static_cast<std::size_t>(0.99 * static_cast<double>(all.size() - 1))] * 1e6,
              all.back() * 1e6);
}

// The same client code against two servers in one run, interleaved: ROUNDS rounds, each one
// QUERIES/ROUNDS per client against A then B (B first in odd rounds), so that a burst of load
// from elsewhere on the machine falls on both alike. Connections stay open across rounds.
int rtt_bench(int port_a, int port_b, int clients, int queries, int rounds) {
  std::vector<int> fa, fb;
  for (int c = 0; c < clients; ++c) {
    fa.push_back(connect_client(port_a));
    fb.push_back(connect_client(port_b));
    if (fa.back() < 0 || fb.back() < 0) {
      std::fprintf(stderr, "rtt: cannot connect\n");
      return 1;
    }
  }
  const int per_round = std::max(1, queries / rounds);
  std::vector<double> la, lb;
  for (int r = 0; r < rounds; ++r) {
    if (r % 2 == 0) {
      rtt_round(fa, per_round, la);
      rtt_round(fb, per_round, lb);
    } else {
      rtt_round(fb, per_round, lb);
      rtt_round(fa, per_round, la);
    }
  }
  for (int fd : fa) close(fd);
  for (int fd : fb) close(fd);
  const int expected = per_round * rounds * clients;
  print_rtt("idmd", la, expected);
  print_rtt("echo", lb, expected);
  if (la.empty() || lb.empty()) return 1;
  return 0;
}

double rss_mb() {
  std::ifstream f("/proc/self/statm");
  long pages = 0, resident = 0;
  f >> pages >> resident;
  return static_cast<double>(resident) * static_cast<double>(sysconf(_SC_PAGESIZE)) / 1048576.0;
}

int rss_bench(int moves, const std::string& config) {
  Daemon d(bench_config(config, 1e-4));
  d.start();
  while (!d.status(0).position_valid) std::this_thread::sleep_for(std::chrono::milliseconds(5));
  double after_warmup = 0;
  int failed = 0;
  for (int i = 0; i < moves; ++i) {
    if (!d.move_relative(0, i % 2 ? -1e-6 : 1e-6).ok()) ++failed;
    while (!d.motion_done()) std::this_thread::sleep_for(std::chrono::microseconds(200));
    if (d.status(0).state == "FAULT") {
      ++failed;
      d.reset();
    }
    if (i == std::min(99, moves - 1)) after_warmup = rss_mb();
  }
  const double end = rss_mb();
  d.shutdown();
  std::printf("rss moves=%d failed=%d after_100_moves_mb=%.1f end_mb=%.1f growth_mb=%.2f\n", moves,
              failed, after_warmup, end, end - after_warmup);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  const std::string mode = argc > 1 ? argv[1] : "";
  if (mode == "loop" && argc == 5)
    return loop_bench(std::atof(argv[2]), std::atof(argv[3]), argv[4]);
  if (mode == "loop-stalled" && argc == 6)
    return loop_bench(std::atof(argv[2]), std::atof(argv[3]), argv[4], std::atoi(argv[5]));
  if (mode == "echo") return echo_server();
  if (mode == "rtt" && argc == 7)
    return rtt_bench(std::atoi(argv[2]), std::atoi(argv[3]), std::atoi(argv[4]), std::atoi(argv[5]),
                     std::atoi(argv[6]));
  if (mode == "rss" && argc == 4) return rss_bench(std::atoi(argv[2]), argv[3]);
  std::fprintf(stderr,
               "usage: daemon_bench loop S PERIOD CONFIG | echo | rtt IDMD_PORT ECHO_PORT CLIENTS "
               "N ROUNDS | "
               "rss MOVES CONFIG\n");
  return 2;
}
