// Counts the heap allocations made on chosen threads, for the tests showing that a loop allocates
// nothing. Include in exactly one .cpp of a test binary (a second one fails to link).
//
// It replaces every replaceable global operator new and delete (plain, array, nothrow, sized,
// aligned) with malloc / aligned_alloc and free. All of them: the C++ library calls forms a test
// never writes itself (std::stable_sort takes its buffer with the nothrow new and gives it back
// with the plain delete), and a partial replacement pairs the runtime's new with this free, which
// AddressSanitizer rightly reports as alloc-dealloc-mismatch.
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdlib>
#include <new>

// The replacement pairs malloc with free on purpose; GCC cannot see that across inlining.
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wmismatched-new-delete"
#endif

namespace idm::test_alloc {

// Allocations and frees are counted on a thread while its flag is set.
inline thread_local bool t_counting = false;
inline std::atomic<long> allocations{0};
inline std::atomic<long> frees{0};

inline void* allocate(std::size_t n, std::size_t alignment) noexcept {
  if (t_counting) allocations.fetch_add(1, std::memory_order_relaxed);
  if (n == 0) n = 1;
  if (alignment <= alignof(std::max_align_t)) return std::malloc(n);
  return std::aligned_alloc(alignment, (n + alignment - 1) / alignment * alignment);
}

inline void release(void* p) noexcept {
  if (p && t_counting) frees.fetch_add(1, std::memory_order_relaxed);
  std::free(p);
}

inline void* allocate_or_throw(std::size_t n, std::size_t alignment) {
  if (void* p = allocate(n, alignment)) return p;
  throw std::bad_alloc();
}

}  // namespace idm::test_alloc

// The replacements (not inline: [replacement.functions]).
void* operator new(std::size_t n) {
  return idm::test_alloc::allocate_or_throw(n, 0);
}
void* operator new[](std::size_t n) {
  return idm::test_alloc::allocate_or_throw(n, 0);
}
void* operator new(std::size_t n, const std::nothrow_t&) noexcept {
  return idm::test_alloc::allocate(n, 0);
}
void* operator new[](std::size_t n, const std::nothrow_t&) noexcept {
  return idm::test_alloc::allocate(n, 0);
}
void* operator new(std::size_t n, std::align_val_t a) {
  return idm::test_alloc::allocate_or_throw(n, static_cast<std::size_t>(a));
}
void* operator new[](std::size_t n, std::align_val_t a) {
  return idm::test_alloc::allocate_or_throw(n, static_cast<std::size_t>(a));
}
void* operator new(std::size_t n, std::align_val_t a, const std::nothrow_t&) noexcept {
  return idm::test_alloc::allocate(n, static_cast<std::size_t>(a));
}
void* operator new[](std::size_t n, std::align_val_t a, const std::nothrow_t&) noexcept {
  return idm::test_alloc::allocate(n, static_cast<std::size_t>(a));
}
void operator delete(void* p) noexcept {
  idm::test_alloc::release(p);
}
void operator delete[](void* p) noexcept {
  idm::test_alloc::release(p);
}
void operator delete(void* p, std::size_t) noexcept {
  idm::test_alloc::release(p);
}
void operator delete[](void* p, std::size_t) noexcept {
  idm::test_alloc::release(p);
}
void operator delete(void* p, const std::nothrow_t&) noexcept {
  idm::test_alloc::release(p);
}
void operator delete[](void* p, const std::nothrow_t&) noexcept {
  idm::test_alloc::release(p);
}
void operator delete(void* p, std::align_val_t) noexcept {
  idm::test_alloc::release(p);
}
void operator delete[](void* p, std::align_val_t) noexcept {
  idm::test_alloc::release(p);
}
void operator delete(void* p, std::size_t, std::align_val_t) noexcept {
  idm::test_alloc::release(p);
}
void operator delete[](void* p, std::size_t, std::align_val_t) noexcept {
  idm::test_alloc::release(p);
}
void operator delete(void* p, std::align_val_t, const std::nothrow_t&) noexcept {
  idm::test_alloc::release(p);
}
void operator delete[](void* p, std::align_val_t, const std::nothrow_t&) noexcept {
  idm::test_alloc::release(p);
}
