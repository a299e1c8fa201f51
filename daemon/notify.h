// systemd's notification protocol (sd_notify, libsystemd): READY=1 once the hardware is configured,
// STATUS= in words, STOPPING=1 on the way out, and WATCHDOG=1 from a watchdog thread only while
// the real-time loop's tick counter advances. Without NOTIFY_SOCKET every call does nothing.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <mutex>
#include <string>
#include <thread>

#include "drivers/thread.h"

namespace idm::daemon {

using drivers::kLoopStackBytes;
using drivers::kRecorderStackBytes;
using drivers::kServerStackBytes;
using drivers::kSmallStackBytes;
using drivers::StackThread;

class Notifier {
 public:
  Notifier() = default;
  ~Notifier() { stop_watchdog(); }
  Notifier(const Notifier&) = delete;
  Notifier& operator=(const Notifier&) = delete;

  static bool under_systemd();  // NOTIFY_SOCKET is set

  void ready(const std::string& status);
  void status(const std::string& status);
  void stopping(const std::string& status);
  // RELOADING=1 (answer with ready() when done).
  void send_reloading() { send("RELOADING=1"); }

  // When the service manager asked for a watchdog (WATCHDOG_USEC), starts a thread that sends
  // WATCHDOG=1 every WATCHDOG_USEC / 4 if ticks() has advanced since the last check; when it has
  // not, it sends nothing (and STATUS= says the loop stalled), so systemd restarts the service.
  // Returns the watchdog interval in seconds, 0 when none was asked for.
  double start_watchdog(std::function<std::uint64_t()> ticks);
  void stop_watchdog();
  std::uint64_t watchdog_pings() const { return pings_.load(); }

 private:
  void send(const std::string& text);

  StackThread thread_;
  std::mutex mutex_;
  std::condition_variable cv_;
  bool quit_ = false;
  std::atomic<std::uint64_t> pings_{0};
};

}  // namespace idm::daemon
