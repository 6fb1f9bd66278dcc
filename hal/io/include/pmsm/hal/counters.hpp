// A counter written by one thread (the RT thread) and read by any: a relaxed load and store,
// no read-modify-write, so the hot path pays no locked instruction. Readers see each value
// atomically; a set of counters is not one snapshot, which is fine for logs and summaries.
#pragma once

#include <atomic>
#include <cstdint>

namespace pmsm::hal {

class SingleWriterCounter {
 public:
  // Writer thread only.
  void bump(std::uint64_t n = 1) noexcept {
    value_.store(value_.load(std::memory_order_relaxed) + n, std::memory_order_relaxed);
  }
  void set(std::uint64_t v) noexcept { value_.store(v, std::memory_order_relaxed); }
  void raise_to(std::uint64_t v) noexcept {
    if (v > value_.load(std::memory_order_relaxed)) {
      value_.store(v, std::memory_order_relaxed);
    }
  }
  // Any thread.
  [[nodiscard]] std::uint64_t get() const noexcept { return value_.load(std::memory_order_relaxed); }

 private:
  std::atomic<std::uint64_t> value_{0};
  static_assert(std::atomic<std::uint64_t>::is_always_lock_free);
};

}  // namespace pmsm::hal
