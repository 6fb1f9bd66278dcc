// Counts every heap allocation of the process: malloc, calloc, realloc, aligned_alloc,
// memalign, posix_memalign, valloc and pvalloc are replaced (glibc allows it) and hand over to
// glibc's own allocator. Every operator new comes through them (libstdc++'s new calls malloc,
// aligned new aligned_alloc), and so do Eigen's dynamic matrices and libc's own allocations
// (strdup, fopen). Link tests/support/alloc_counter.cpp into the test binary.
//
// Under AddressSanitizer the replacement is left out (ASan owns malloc): active() is false and
// the tests that need the counter skip, visibly.
#pragma once

namespace pmsm::test {

// Allocations made on the calling thread since it started.
[[nodiscard]] long thread_allocations() noexcept;
// Allocations made by every thread.
[[nodiscard]] long total_allocations() noexcept;
[[nodiscard]] bool allocation_counter_active() noexcept;

}  // namespace pmsm::test
