// The power stage's fault input, watched on its own thread: woken by the line's edge events
// (the kernel's interrupt, through FaultInput::event_fd()) or, for a backend without events,
// polled every millisecond. Every wake reads the level and hands it to the control loop
// (DriveLoop::set_gpio_fault, an atomic the next period reads): an active line trips the
// drive within one control period of the wake. A failed read is a fault, never "no fault".
// The level is also re-read every `recheck` without an edge, so a lost edge cannot hide a
// fault for longer than that.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>

#include "pmsm/hal/gpio.hpp"

namespace pmsm::daemon {

struct FaultWatchStats {
  std::uint64_t wakes = 0;         // edge events or polls that read the line
  std::uint64_t read_failures = 0;
  bool edge_driven = false;        // the backend has edge events
};

// Runs until `stop` (seen within `recheck`, or at once when `stop_fd` becomes readable).
// `report(fault, read_ok)` is called on every read: fault is true for an active line and for a
// failed read. `stats` is written by this thread only; read it after the call returns.
void watch_fault_input(hal::FaultInput& input, const std::atomic<bool>& stop, int stop_fd,
                       const std::function<void(bool fault, bool read_ok)>& report, FaultWatchStats& stats,
                       std::chrono::milliseconds recheck = std::chrono::milliseconds{100});

}  // namespace pmsm::daemon
