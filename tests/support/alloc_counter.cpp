#include "alloc_counter.hpp"

#include <atomic>
#include <cerrno>
#include <cstddef>

#include "sanitizers.hpp"

#define PMSM_ALLOC_COUNTER (!PMSM_TEST_ASAN)

namespace {
thread_local long t_allocations = 0;  // trivial: no allocation to set it up
std::atomic<long> g_allocations{0};
}  // namespace

namespace pmsm::test {
long thread_allocations() noexcept { return t_allocations; }
long total_allocations() noexcept { return g_allocations.load(std::memory_order_relaxed); }
bool allocation_counter_active() noexcept { return PMSM_ALLOC_COUNTER != 0; }
}  // namespace pmsm::test

#if PMSM_ALLOC_COUNTER
// glibc's allocator under its own names: the replacements count, then hand over.
extern "C" {
void* __libc_malloc(std::size_t size);
void* __libc_calloc(std::size_t count, std::size_t size);
void* __libc_realloc(void* p, std::size_t size);
void* __libc_memalign(std::size_t alignment, std::size_t size);
void* __libc_valloc(std::size_t size);
void* __libc_pvalloc(std::size_t size);
void __libc_free(void* p);
}

namespace {
void note() noexcept {
  ++t_allocations;
  g_allocations.fetch_add(1, std::memory_order_relaxed);
}
}  // namespace

extern "C" {
void* malloc(std::size_t size) {
  note();
  return __libc_malloc(size);
}
void* calloc(std::size_t count, std::size_t size) {
  note();
  return __libc_calloc(count, size);
}
void* realloc(void* p, std::size_t size) {
  note();
  return __libc_realloc(p, size);
}
void* aligned_alloc(std::size_t alignment, std::size_t size) {
  note();
  return __libc_memalign(alignment, size);
}
void* memalign(std::size_t alignment, std::size_t size) {
  note();
  return __libc_memalign(alignment, size);
}
void* valloc(std::size_t size) {
  note();
  return __libc_valloc(size);
}
void* pvalloc(std::size_t size) {
  note();
  return __libc_pvalloc(size);
}
int posix_memalign(void** out, std::size_t alignment, std::size_t size) {
  note();
  void* p = __libc_memalign(alignment, size);
  if (p == nullptr) {
    return ENOMEM;
  }
  *out = p;
  return 0;
}
void free(void* p) { __libc_free(p); }
}
#endif
