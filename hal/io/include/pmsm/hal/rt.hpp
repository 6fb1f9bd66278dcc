// Real-time setup for the control thread and the periodic timer it runs on.
//
// Each setup call returns a Status whose message says what was refused and how to allow it
// (limits, capabilities, systemd settings), so that the daemon can warn and continue when
// it runs without privileges (a development machine, a CI container).
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <span>

#include "pmsm/hal/status.hpp"

namespace pmsm::hal {

// mlockall(MCL_CURRENT | MCL_FUTURE): no page faults from swapped-out or not-yet-touched
// memory on the hot path. Needs RLIMIT_MEMLOCK (LimitMEMLOCK=infinity) or CAP_IPC_LOCK.
[[nodiscard]] Status lock_memory();

// Memory for a real-time process, as cactus-rt sets it up: lock_memory(), then glibc's heap
// is told never to give memory back (M_TRIM_THRESHOLD = -1) and never to serve a request
// with a fresh mmap (M_MMAP_MAX = 0), so that a free() or a large allocation on another
// thread cannot make the RT thread fault pages in. Returns lock_memory()'s status (the
// mallopt calls cannot be refused).
[[nodiscard]] Status prepare_memory_for_realtime();

// SCHED_FIFO at `priority` (1..99) for the calling thread only. Needs RLIMIT_RTPRIO
// (LimitRTPRIO=) or CAP_SYS_NICE, and no RestrictRealtime=yes.
[[nodiscard]] Status set_realtime_priority(int priority);

// Pins the calling thread to the given CPUs (at least one).
[[nodiscard]] Status set_cpu_affinity(std::span<const int> cpus);

// Touches `bytes` of stack below the caller so that later calls do not fault in new
// stack pages (useful after lock_memory()).
void prefault_stack(std::size_t bytes = 256U * 1024U) noexcept;

// CLOCK_MONOTONIC in nanoseconds.
[[nodiscard]] std::int64_t monotonic_ns() noexcept;

// CLOCK_REALTIME less CLOCK_MONOTONIC, in nanoseconds: what turns a monotonic reading into the
// clock of the kernel's software receive timestamps (ReceivedFrame::timestamp_ns). Read between
// two monotonic readings, whose midpoint it is taken against; of four tries the narrowest
// bracket stands (a preemption between the readings skews it). It moves when the wall clock is
// set or slewed: read it again now and then, not once for a process's life.
[[nodiscard]] std::int64_t realtime_minus_monotonic_ns() noexcept;

// A periodic wake-up on absolute deadlines (clock_nanosleep(CLOCK_MONOTONIC,
// TIMER_ABSTIME)), so that the period does not drift with the loop's own run time.
//
//   PeriodicTimer timer{100us};
//   timer.start();
//   for (;;) { auto tick = timer.wait_next(); step(); }
//
// When the loop body overran one or more deadlines, wait_next() returns at once, reports
// how many periods were missed, and re-aligns the schedule to the next deadline still in
// the future (missed periods are skipped, not made up for with a burst).
class PeriodicTimer {
 public:
  struct Tick {
    std::int64_t deadline_ns = 0;   // the deadline this wake-up is for (monotonic)
    std::int64_t lateness_ns = 0;   // wake-up time minus deadline (>= 0)
    std::uint64_t missed_periods = 0; // deadlines skipped before this one (0 normally)
  };

  struct Stats {
    std::uint64_t periods = 0;          // wake-ups delivered
    std::uint64_t deadline_misses = 0;  // wake-ups that found the next deadline already passed
    std::uint64_t missed_periods = 0;   // deadlines skipped in total
    std::int64_t max_lateness_ns = 0;   // worst wake-up latency
  };

  explicit PeriodicTimer(std::chrono::nanoseconds period);

  // The first deadline is one period from now.
  void start() noexcept;
  // ... or from a given monotonic time (e.g. shared by several loops).
  void start_at(std::int64_t first_deadline_ns) noexcept;
  // Sleeps until the next deadline (returns at once after an overrun).
  Tick wait_next() noexcept;

  [[nodiscard]] std::chrono::nanoseconds period() const noexcept { return period_; }
  [[nodiscard]] Stats stats() const noexcept { return stats_; }

 private:
  std::chrono::nanoseconds period_;
  std::int64_t next_deadline_ns_ = 0;
  Stats stats_;
};

}  // namespace pmsm::hal
