// Real-time setup helpers and the absolute-deadline timer (see rt.hpp).
#include "pmsm/hal/rt.hpp"

#include <alloca.h>
#include <malloc.h>
#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>
#include <sys/resource.h>
#include <time.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <limits>
#include <string>

namespace pmsm::hal {

namespace {

std::string limit_text(int resource) {
  rlimit limit{};
  if (::getrlimit(resource, &limit) != 0) {
    return "unknown";
  }
  if (limit.rlim_cur == RLIM_INFINITY) {
    return "unlimited";
  }
  return std::to_string(limit.rlim_cur);
}

constexpr std::int64_t kNsPerS = 1'000'000'000;

timespec to_timespec(std::int64_t ns) {
  timespec ts{};
  ts.tv_sec = ns / kNsPerS;
  ts.tv_nsec = ns % kNsPerS;
  return ts;
}

}  // namespace

Status lock_memory() {
  if (::mlockall(MCL_CURRENT | MCL_FUTURE) != 0) {
    const int e = errno;
    return Status::error(e, "mlockall(MCL_CURRENT | MCL_FUTURE) failed: " + errno_text(e) +
                                " (RLIMIT_MEMLOCK is " + limit_text(RLIMIT_MEMLOCK) +
                                " bytes; set LimitMEMLOCK=infinity or grant CAP_IPC_LOCK); "
                                "page faults may delay the control loop");
  }
  return {};
}

Status prepare_memory_for_realtime() {
  ::mallopt(M_TRIM_THRESHOLD, -1);
  ::mallopt(M_MMAP_MAX, 0);
  return lock_memory();
}

Status set_realtime_priority(int priority) {
  const int lowest = ::sched_get_priority_min(SCHED_FIFO);
  const int highest = ::sched_get_priority_max(SCHED_FIFO);
  if (priority < lowest || priority > highest) {
    return Status::error(EINVAL, "SCHED_FIFO priority " + std::to_string(priority) + " is out of range " +
                                     std::to_string(lowest) + ".." + std::to_string(highest));
  }
  sched_param param{};
  param.sched_priority = priority;
  // pthread_setschedparam returns the error number instead of setting errno.
  const int e = ::pthread_setschedparam(::pthread_self(), SCHED_FIFO, &param);
  if (e != 0) {
    return Status::error(e, "cannot set SCHED_FIFO priority " + std::to_string(priority) +
                                " for the control thread: " + errno_text(e) + " (RLIMIT_RTPRIO is " +
                                limit_text(RLIMIT_RTPRIO) +
                                "; set LimitRTPRIO= in the unit, grant CAP_SYS_NICE, and do not use "
                                "RestrictRealtime=yes); running with normal scheduling");
  }
  return {};
}

Status set_cpu_affinity(std::span<const int> cpus) {
  if (cpus.empty()) {
    return Status::error(EINVAL, "CPU affinity: no CPU given");
  }
  const long online = ::sysconf(_SC_NPROCESSORS_CONF);
  cpu_set_t set;
  CPU_ZERO(&set);
  std::string list;
  for (const int cpu : cpus) {
    if (cpu < 0 || cpu >= CPU_SETSIZE || (online > 0 && cpu >= online)) {
      return Status::error(EINVAL, "CPU affinity: CPU " + std::to_string(cpu) + " does not exist (this machine has " +
                                       std::to_string(online) + " CPUs, numbered from 0)");
    }
    CPU_SET(static_cast<std::size_t>(cpu), &set);
    if (!list.empty()) {
      list += ',';
    }
    list += std::to_string(cpu);
  }
  const int e = ::pthread_setaffinity_np(::pthread_self(), sizeof set, &set);
  if (e != 0) {
    return Status::error(e, "cannot pin the control thread to CPU(s) " + list + ": " + errno_text(e) +
                                " (restricted by a cpuset or CPUAffinity=?)");
  }
  return {};
}

void prefault_stack(std::size_t bytes) noexcept {
  // alloca, not a variable-length array (a GNU extension in C++): the block lives until
  // this function returns, and every page of it is written through a volatile pointer so
  // that the stores are kept.
  auto* stack = static_cast<volatile unsigned char*>(alloca(bytes));
  const auto page = static_cast<std::size_t>(::sysconf(_SC_PAGESIZE));
  for (std::size_t i = 0; i < bytes; i += page) {
    stack[i] = 0;
  }
}

std::int64_t monotonic_ns() noexcept {
  timespec ts{};
  ::clock_gettime(CLOCK_MONOTONIC, &ts);
  return std::int64_t{ts.tv_sec} * kNsPerS + std::int64_t{ts.tv_nsec};
}

std::int64_t realtime_minus_monotonic_ns() noexcept {
  // The thread may be preempted between the readings: the offset is then wrong by up to half
  // the gap (on a loaded machine, hundreds of microseconds, more than a frame's wait in the
  // socket). Of a few tries the one with the narrowest bracket stands.
  constexpr int kTries = 4;
  std::int64_t best_gap = std::numeric_limits<std::int64_t>::max();
  std::int64_t best = 0;
  for (int k = 0; k < kTries; ++k) {
    const std::int64_t before = monotonic_ns();
    timespec ts{};
    ::clock_gettime(CLOCK_REALTIME, &ts);
    const std::int64_t after = monotonic_ns();
    if (after - before < best_gap) {
      best_gap = after - before;
      best = std::int64_t{ts.tv_sec} * kNsPerS + std::int64_t{ts.tv_nsec} - (before + (after - before) / 2);
    }
  }
  return best;
}

PeriodicTimer::PeriodicTimer(std::chrono::nanoseconds period) : period_(period) {
  if (period_.count() <= 0) {
    throw HalError(EINVAL, "periodic timer: the period must be positive, got " +
                               std::to_string(period_.count()) + " ns");
  }
}

void PeriodicTimer::start() noexcept { start_at(monotonic_ns() + period_.count()); }

void PeriodicTimer::start_at(std::int64_t first_deadline_ns) noexcept {
  next_deadline_ns_ = first_deadline_ns;
  stats_ = Stats{};
}

PeriodicTimer::Tick PeriodicTimer::wait_next() noexcept {
  Tick tick;
  const std::int64_t period_ns = period_.count();
  std::int64_t now_ns = monotonic_ns();
  if (now_ns > next_deadline_ns_) {
    // Overrun: the body ran past the deadline it was to wait for. Skip to the next
    // deadline still ahead rather than firing a burst of late periods.
    const auto missed = static_cast<std::uint64_t>((now_ns - next_deadline_ns_) / period_ns) + 1U;
    tick.missed_periods = missed;
    ++stats_.deadline_misses;
    stats_.missed_periods += missed;
    next_deadline_ns_ += static_cast<std::int64_t>(missed) * period_ns;
  }
  const timespec deadline = to_timespec(next_deadline_ns_);
  while (::clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &deadline, nullptr) == EINTR) {
  }
  now_ns = monotonic_ns();
  tick.deadline_ns = next_deadline_ns_;
  tick.lateness_ns = now_ns > next_deadline_ns_ ? now_ns - next_deadline_ns_ : 0;
  if (tick.lateness_ns > stats_.max_lateness_ns) {
    stats_.max_lateness_ns = tick.lateness_ns;
  }
  ++stats_.periods;
  next_deadline_ns_ += period_ns;
  return tick;
}

}  // namespace pmsm::hal
