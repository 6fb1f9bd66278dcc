#include "fault_watch.hpp"

#include <algorithm>
#include <thread>

#include "pmsm/hal/wait.hpp"

namespace pmsm::daemon {

void watch_fault_input(hal::FaultInput& input, const std::atomic<bool>& stop, int stop_fd,
                       const std::function<void(bool fault, bool read_ok)>& report, FaultWatchStats& stats,
                       std::chrono::milliseconds recheck) {
  hal::DescriptorWait wait;
  const int event_fd = input.event_fd();
  stats.edge_driven = event_fd >= 0;
  (void)wait.add(event_fd);
  (void)wait.add(stop_fd);
  // Without edge events: a poll every millisecond; no fault line at all (the null backend,
  // always quiet): only the re-check.
  const bool polled = !stats.edge_driven && input.backend_name() != "null";
  const std::chrono::nanoseconds timeout = polled ? std::chrono::nanoseconds{std::chrono::milliseconds{1}}
                                                  : std::chrono::nanoseconds{recheck};
  while (!stop.load(std::memory_order_relaxed)) {
    const std::optional<bool> level = input.fault_active();
    ++stats.wakes;
    if (!level) {
      ++stats.read_failures;
    }
    report(level.value_or(true), level.has_value());
    if (!level) {
      // The descriptor may stay readable after a failed read: retry at a bounded pace.
      std::this_thread::sleep_for(std::chrono::milliseconds{10});
      continue;
    }
    // While the line reports a fault, read it again every millisecond: its end shows no edge
    // of its own kind to wake on (the backend reports any edge as a fault), and a stop command
    // must find the fault's cause gone soon after the line went quiet.
    (void)wait.wait_for(*level ? std::min(timeout, std::chrono::nanoseconds{std::chrono::milliseconds{1}}) : timeout);
  }
}

}  // namespace pmsm::daemon
