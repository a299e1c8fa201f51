// The only ways data crosses between idmd's threads and the real-time loop: a fixed-capacity
// single-producer single-consumer ring (commands in, trial samples out) and a seqlock latest-value
// buffer (status out). Neither allocates after construction, locks, or makes a system call.
#pragma once

#include <array>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <type_traits>

namespace idm::drivers {

// Lamport ring for one producer thread and one consumer thread. Capacity is a power of two;
// one slot is never wasted (head and tail count without wrapping).
template <typename T, std::size_t Capacity>
class SpscRing {
  static_assert(Capacity >= 2 && (Capacity & (Capacity - 1)) == 0, "capacity: a power of two");
  static_assert(std::is_trivially_copyable_v<T>, "ring elements are copied as plain data");

 public:
  // Producer: false when full (nothing written).
  bool push(const T& value) {
    const std::size_t head = head_.load(std::memory_order_relaxed);
    if (head - tail_cache_ >= Capacity) {
      tail_cache_ = tail_.load(std::memory_order_acquire);
      if (head - tail_cache_ >= Capacity) return false;
    }
    slots_[head & (Capacity - 1)] = value;
    head_.store(head + 1, std::memory_order_release);
    return true;
  }
  // Consumer: false when empty.
  bool pop(T& out) {
    const std::size_t tail = tail_.load(std::memory_order_relaxed);
    if (tail == head_cache_) {
      head_cache_ = head_.load(std::memory_order_acquire);
      if (tail == head_cache_) return false;
    }
    out = slots_[tail & (Capacity - 1)];
    tail_.store(tail + 1, std::memory_order_release);
    return true;
  }
  // Either side: an estimate (exact when the other side is quiet).
  std::size_t size() const {
    return head_.load(std::memory_order_acquire) - tail_.load(std::memory_order_acquire);
  }
  bool empty() const { return size() == 0; }
  static constexpr std::size_t capacity() { return Capacity; }

 private:
  alignas(64) std::atomic<std::size_t> head_{0};
  std::size_t tail_cache_ = 0;  // producer's copy of tail_
  alignas(64) std::atomic<std::size_t> tail_{0};
  std::size_t head_cache_ = 0;  // consumer's copy of head_
  alignas(64) std::array<T, Capacity> slots_{};
};

// Latest-value buffer for one writer and any number of readers (seqlock). The writer never waits;
// a reader retries while a write is in progress. T is copied bytewise through atomic words so that
// the concurrent read is not a data race. The words are stored with release and loaded with
// acquire instead of fences around relaxed ones: the same order (a reader that sees a word of a
// new write also sees that write's odd sequence number), plain moves on x86, and an order that
// ThreadSanitizer can check (it does not model standalone fences).
template <typename T>
class Seqlock {
  static_assert(std::is_trivially_copyable_v<T>, "a seqlock value is copied as plain data");
  static constexpr std::size_t kWords =
      (sizeof(T) + sizeof(std::uint64_t) - 1) / sizeof(std::uint64_t);

 public:
  Seqlock() { store(T{}); }

  void store(const T& value) {
    std::uint64_t words[kWords] = {};
    std::memcpy(words, &value, sizeof(T));
    const std::uint64_t seq = seq_.load(std::memory_order_relaxed);
    seq_.store(seq + 1, std::memory_order_relaxed);
    for (std::size_t i = 0; i < kWords; ++i) data_[i].store(words[i], std::memory_order_release);
    seq_.store(seq + 2, std::memory_order_release);
  }

  T load() const {
    std::uint64_t words[kWords];
    for (;;) {
      const std::uint64_t before = seq_.load(std::memory_order_acquire);
      if (before & 1u) continue;
      for (std::size_t i = 0; i < kWords; ++i) words[i] = data_[i].load(std::memory_order_acquire);
      if (seq_.load(std::memory_order_relaxed) == before) break;
    }
    T out;
    std::memcpy(&out, words, sizeof(T));
    return out;
  }

  // Number of stores so far.
  std::uint64_t version() const { return seq_.load(std::memory_order_acquire) / 2; }

 private:
  std::atomic<std::uint64_t> seq_{0};
  std::array<std::atomic<std::uint64_t>, kWords> data_{};
};

}  // namespace idm::drivers
