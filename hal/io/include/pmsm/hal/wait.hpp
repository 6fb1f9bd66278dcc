// Waiting on several descriptors with a deadline: one loop that wakes for the CAN socket, a
// timer, or a stop request (candump's epoll over several sockets, reduced to what a control
// loop needs). One ppoll() per wait; the clock is not read here.
//
//   DescriptorWait wait;
//   const auto bus = wait.add(bus_fd);
//   const auto stop = wait.add(signals.fd());
//   const WaitResult r = wait.wait_for(std::chrono::microseconds{500});
//   if (r.ready(stop)) ...; if (r.ready(bus)) ...; if (r.timed_out) ...
//
// No allocation after add(): the descriptor list has a fixed capacity.
#pragma once

#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>

#include "pmsm/hal/status.hpp"

namespace pmsm::hal {

struct WaitResult {
  bool timed_out = false;     // the deadline passed with nothing ready
  bool interrupted = false;   // a signal arrived (EINTR); the caller checks its stop flag
  int error = 0;              // errno of a failed wait (0: none)
  std::uint32_t ready_mask = 0;  // bit i: slot i is readable, or reports an error / hang-up

  [[nodiscard]] bool ready(std::size_t slot) const noexcept { return (ready_mask & (1U << slot)) != 0U; }
};

class DescriptorWait {
 public:
  static constexpr std::size_t kCapacity = 8;

  // Adds a descriptor (watched for input); returns its slot. -1 reserves a slot that is
  // ignored until set() gives it a descriptor (e.g. a socket reopened later).
  std::size_t add(int fd) noexcept;
  // Replaces the descriptor of a slot (after a reopen); -1 ignores the slot.
  void set(std::size_t slot, int fd) noexcept;

  // Waits up to `timeout` (0: only looks) for any slot to become ready.
  [[nodiscard]] WaitResult wait_for(std::chrono::nanoseconds timeout) noexcept;

 private:
  std::array<int, kCapacity> fds_{};
  std::size_t count_ = 0;
};

}  // namespace pmsm::hal
