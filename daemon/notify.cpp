#include "daemon/notify.h"

#include <systemd/sd-daemon.h>

#include <chrono>
#include <cstdlib>

namespace idm::daemon {

bool Notifier::under_systemd() {
  const char* s = std::getenv("NOTIFY_SOCKET");
  return s != nullptr && *s != '\0';
}

void Notifier::send(const std::string& text) {
  if (under_systemd()) sd_notify(0, text.c_str());
}

void Notifier::ready(const std::string& status) {
  send("READY=1\nSTATUS=" + status);
}
void Notifier::status(const std::string& status) {
  send("STATUS=" + status);
}
void Notifier::stopping(const std::string& status) {
  send("STOPPING=1\nSTATUS=" + status);
}

double Notifier::start_watchdog(std::function<std::uint64_t()> ticks) {
  std::uint64_t usec = 0;
  if (!under_systemd() || sd_watchdog_enabled(0, &usec) <= 0 || usec == 0) return 0.0;
  const auto interval = std::chrono::microseconds(usec / 4 > 1000 ? usec / 4 : 1000);
  {
    std::lock_guard<std::mutex> lock(mutex_);
    quit_ = false;
  }
  thread_ =
      StackThread("idmd-notify", kSmallStackBytes, [this, interval, ticks = std::move(ticks)] {
        std::uint64_t last = ticks();
        bool stalled = false;
        std::unique_lock<std::mutex> lock(mutex_);
        for (;;) {
          if (cv_.wait_for(lock, interval, [this] { return quit_; })) return;
          const std::uint64_t now = ticks();
          if (now != last) {
            sd_notify(0, stalled ? "WATCHDOG=1\nSTATUS=Running: the real-time loop advances again"
                                 : "WATCHDOG=1");
            pings_.fetch_add(1);
            stalled = false;
          } else if (!stalled) {
            sd_notify(0, "STATUS=The real-time loop has stalled: no watchdog ping");
            stalled = true;
          }
          last = now;
        }
      });
  return static_cast<double>(usec) * 1e-6;
}

void Notifier::stop_watchdog() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    quit_ = true;
  }
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

}  // namespace idm::daemon
