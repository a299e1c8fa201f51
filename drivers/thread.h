// A joinable thread with a chosen stack size. idmd's threads use it instead of std::thread because
// std::thread takes the default stack (8 MiB, RLIMIT_STACK), and once the real-time loop has
// called mlockall(MCL_CURRENT | MCL_FUTURE) every thread stack is locked and resident in full:
// 8 MiB each for threads that use a few tens of KiB. Header-only: the device links' I/O threads,
// the protocol library (server) and the daemon core use it.
#pragma once

#include <pthread.h>

#include <cstddef>
#include <functional>
#include <memory>
#include <string>
#include <system_error>
#include <utility>

namespace idm::drivers {

// Stack sizes of idmd's threads: each is far above what the thread uses (no recursion, no large
// locals beyond the buffers noted), and small enough that locking them costs little.
inline constexpr std::size_t kLoopStackBytes = std::size_t{512} * 1024;  // loop + 64 KiB prefault
inline constexpr std::size_t kServerStackBytes =
    std::size_t{512} * 1024;  // 16 KiB read buffer, logging
inline constexpr std::size_t kRecorderStackBytes =
    std::size_t{1024} * 1024;  // dataset writing (I/O, formatting)
inline constexpr std::size_t kSmallStackBytes = std::size_t{256} * 1024;  // watchdog, housekeeping
inline constexpr std::size_t kIoStackBytes =
    std::size_t{1024} * 1024;  // a device's I/O thread (libmodbus,
                               // libusb, error messages)

class StackThread {
 public:
  static constexpr std::size_t kMaxNameChars = 15;  // TASK_COMM_LEN - 1
  StackThread() = default;
  // Starts fn on a new thread named `name` (what top -H, ps -L and gdb show; cut to the kernel's
  // 15 characters) with a stack of stack_bytes (at least PTHREAD_STACK_MIN). Throws
  // std::system_error when the thread cannot be created (as std::thread does).
  StackThread(const std::string& name, std::size_t stack_bytes, std::function<void()> fn) {
    auto owned = std::make_unique<std::function<void()>>(std::move(fn));
    pthread_attr_t attr;
    pthread_attr_init(&attr);
    pthread_attr_setstacksize(&attr, stack_bytes);
    const int e = pthread_create(&id_, &attr, &StackThread::entry, owned.get());
    pthread_attr_destroy(&attr);
    if (e != 0) throw std::system_error(e, std::generic_category(), "pthread_create");
    pthread_setname_np(id_, name.substr(0, kMaxNameChars).c_str());
    static_cast<void>(owned.release());  // the thread owns it now
    joinable_ = true;
  }
  StackThread(StackThread&& other) noexcept
      : id_(other.id_), joinable_(std::exchange(other.joinable_, false)) {}
  StackThread& operator=(StackThread&& other) noexcept {
    if (this != &other) {
      if (joinable_) join();
      id_ = other.id_;
      joinable_ = std::exchange(other.joinable_, false);
    }
    return *this;
  }
  StackThread(const StackThread&) = delete;
  StackThread& operator=(const StackThread&) = delete;
  // Unlike std::thread, a joinable thread is joined rather than terminating the program.
  ~StackThread() {
    if (joinable_) join();
  }

  bool joinable() const { return joinable_; }
  void join() {
    if (!joinable_) return;
    pthread_join(id_, nullptr);
    joinable_ = false;
  }

 private:
  static void* entry(void* arg) {
    std::unique_ptr<std::function<void()>> fn(static_cast<std::function<void()>*>(arg));
    (*fn)();
    return nullptr;
  }

  pthread_t id_{};
  bool joinable_ = false;
};

}  // namespace idm::drivers
