// The latest value from a non-RT writer to an RT reader, wait-free on both sides (a triple
// buffer, like cactus-rt's RealtimeReadableValue in spirit): the writer fills a spare slot and
// swaps it in; the reader swaps the newest slot out when there is one. Neither side ever
// waits for the other, and the reader never sees a half-written value.
//
//   writer (command intake):  value.write(cmd);
//   reader (RT thread):       if (const T* v = value.read_new()) { use(*v); }  // or latest()
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <type_traits>

namespace pmsm::hal {

template <typename T>
class RealtimeValue {
  static_assert(std::is_trivially_copyable_v<T>, "values are copied between threads");

 public:
  RealtimeValue() = default;
  explicit RealtimeValue(const T& initial) { slots_.fill(initial); }
  RealtimeValue(const RealtimeValue&) = delete;
  RealtimeValue& operator=(const RealtimeValue&) = delete;

  // Writer thread only.
  void write(const T& value) noexcept {
    slots_[back_] = value;
    // Publish: the back slot becomes the middle one, flagged new.
    const std::uint8_t old = middle_.exchange(static_cast<std::uint8_t>(back_ | kNew), std::memory_order_acq_rel);
    back_ = static_cast<std::uint8_t>(old & kIndex);
  }

  // Reader thread only. The newest value if one arrived since the last call, else null.
  [[nodiscard]] const T* read_new() noexcept {
    if ((middle_.load(std::memory_order_relaxed) & kNew) == 0U) {
      return nullptr;
    }
    const std::uint8_t old = middle_.exchange(front_, std::memory_order_acq_rel);
    front_ = static_cast<std::uint8_t>(old & kIndex);
    return &slots_[front_];
  }
  // Reader thread only. The newest value (the initial one before any write).
  [[nodiscard]] const T& latest() noexcept {
    (void)read_new();
    return slots_[front_];
  }

 private:
  static constexpr std::uint8_t kIndex = 0x03;
  static constexpr std::uint8_t kNew = 0x04;
  std::array<T, 3> slots_{};
  std::uint8_t back_ = 0;                 // writer's slot
  std::atomic<std::uint8_t> middle_{1};   // the exchanged slot, with the kNew flag
  std::uint8_t front_ = 2;                // reader's slot
  static_assert(std::atomic<std::uint8_t>::is_always_lock_free);
};

}  // namespace pmsm::hal
