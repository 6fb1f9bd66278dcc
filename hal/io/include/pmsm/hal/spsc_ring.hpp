// Lock-free single-producer / single-consumer ring of fixed-size records: how the RT thread
// hands telemetry and log records to a normal thread without locks or allocation (DESIGN
// §3, §10: spdlog's async logger locks a mutex, so it is not for the RT thread).
//
// One thread calls try_push, one (other) thread calls try_pop. try_push never blocks: when
// the ring is full the record is dropped and counted. Capacity N is a power of two; all N
// slots are usable (indices run freely and are masked).
#pragma once

#include <array>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <new>
#include <type_traits>

namespace pmsm::hal {

template <typename T, std::size_t N>
class SpscRing {
  static_assert(std::is_trivially_copyable_v<T>, "records are copied bytewise between threads");
  static_assert(N >= 2 && (N & (N - 1)) == 0, "capacity must be a power of two");

 public:
  SpscRing() = default;
  SpscRing(const SpscRing&) = delete;
  SpscRing& operator=(const SpscRing&) = delete;

  // Producer side. False (and counted) if full.
  bool try_push(const T& record) noexcept {
    const std::size_t head = head_.load(std::memory_order_relaxed);
    if (head - cached_tail_ == N) {
      cached_tail_ = tail_.load(std::memory_order_acquire);
      if (head - cached_tail_ == N) {
        dropped_.store(dropped_.load(std::memory_order_relaxed) + 1, std::memory_order_relaxed);
        return false;
      }
    }
    slots_[head & kMask] = record;
    head_.store(head + 1, std::memory_order_release);
    return true;
  }

  // Consumer side. False if empty.
  bool try_pop(T& record) noexcept {
    const std::size_t tail = tail_.load(std::memory_order_relaxed);
    if (tail == cached_head_) {
      cached_head_ = head_.load(std::memory_order_acquire);
      if (tail == cached_head_) {
        return false;
      }
    }
    record = slots_[tail & kMask];
    tail_.store(tail + 1, std::memory_order_release);
    return true;
  }

  // Records dropped by try_push because the ring was full (any thread, approximate).
  [[nodiscard]] std::uint64_t dropped() const noexcept {
    return dropped_.load(std::memory_order_relaxed);
  }
  // Records waiting (any thread; exact only when both sides are idle).
  [[nodiscard]] std::size_t size_approx() const noexcept {
    return head_.load(std::memory_order_acquire) - tail_.load(std::memory_order_acquire);
  }
  [[nodiscard]] bool empty_approx() const noexcept { return size_approx() == 0; }
  [[nodiscard]] static constexpr std::size_t capacity() noexcept { return N; }

 private:
  static constexpr std::size_t kMask = N - 1;
  // Keeps the producer's and the consumer's indices on separate cache lines.
  static constexpr std::size_t kLine = 64;

  alignas(kLine) std::atomic<std::size_t> head_{0};  // written by the producer
  std::size_t cached_tail_ = 0;                      // producer's copy of tail_
  std::atomic<std::uint64_t> dropped_{0};            // written by the producer
  alignas(kLine) std::atomic<std::size_t> tail_{0};  // written by the consumer
  std::size_t cached_head_ = 0;                      // consumer's copy of head_
  alignas(kLine) std::array<T, N> slots_{};
};

}  // namespace pmsm::hal
