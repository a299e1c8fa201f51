// A small parallel loop over indices with std::thread: the diagnosis spreads the cells of a sweep
// (or the runs of validate) over the machine's cores. Exceptions from a worker are rethrown.
#pragma once

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <exception>
#include <mutex>
#include <thread>
#include <vector>

namespace idm::analysis {

// The number of worker threads to use when the caller asks for 0 ("all cores").
inline int default_threads() {
  return std::max(1u, std::thread::hardware_concurrency());
}

// Calls fn(i) for i in [0, n) on up to `threads` threads (0: all cores), in no particular order.
template <class Fn>
void parallel_for(std::size_t n, int threads, Fn&& fn) {
  const std::size_t workers =
      std::min<std::size_t>(n, static_cast<std::size_t>(threads > 0 ? threads : default_threads()));
  if (workers <= 1) {
    for (std::size_t i = 0; i < n; ++i) fn(i);
    return;
  }
  std::atomic<std::size_t> next{0};
  std::exception_ptr error;
  std::mutex error_mutex;
  auto work = [&] {
    for (;;) {
      const std::size_t i = next.fetch_add(1);
      if (i >= n) return;
      try {
        fn(i);
      } catch (...) {
        std::lock_guard<std::mutex> lock(error_mutex);
        if (!error) error = std::current_exception();
        next.store(n);
        return;
      }
    }
  };
  std::vector<std::thread> pool;
  for (std::size_t w = 1; w < workers; ++w) pool.emplace_back(work);
  work();
  for (std::thread& t : pool) t.join();
  if (error) std::rethrow_exception(error);
}

}  // namespace idm::analysis
