#include "pmsm/hal/rt.hpp"

#include <gtest/gtest.h>
#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>

#include <array>
#include <chrono>
#include <string>
#include <thread>

namespace pmsm::hal {
namespace {

using namespace std::chrono_literals;

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

TEST(Rt, MonotonicClockAdvances) {
  const std::int64_t a = monotonic_ns();
  std::this_thread::sleep_for(2ms);
  const std::int64_t b = monotonic_ns();
  EXPECT_GE(b - a, 2'000'000);
  EXPECT_LT(b - a, 2'000'000'000);
}

TEST(Rt, PeriodicTimerKeepsAbsoluteDeadlines) {
  PeriodicTimer timer{1ms};
  const std::int64_t start_ns = monotonic_ns();
  timer.start_at(start_ns + 1'000'000);
  std::int64_t previous = 0;
  for (int i = 0; i < 20; ++i) {
    const PeriodicTimer::Tick tick = timer.wait_next();
    EXPECT_GE(monotonic_ns(), tick.deadline_ns);
    if (i > 0 && tick.missed_periods == 0) {
      EXPECT_EQ(tick.deadline_ns - previous, 1'000'000);  // no drift: deadlines are exact multiples
    }
    previous = tick.deadline_ns;
  }
  const PeriodicTimer::Stats stats = timer.stats();
  EXPECT_EQ(stats.periods, 20U);
  // On a loaded CI machine a wake-up may be late; the deadlines themselves never drift.
  EXPECT_EQ((previous - start_ns) % 1'000'000, 0);
}

TEST(Rt, PeriodicTimerCountsOverrunsAndSkipsMissedPeriods) {
  PeriodicTimer timer{2ms};
  timer.start();
  const PeriodicTimer::Tick first = timer.wait_next();
  std::this_thread::sleep_for(11ms);  // the loop body overruns about five periods
  const PeriodicTimer::Tick tick = timer.wait_next();
  EXPECT_GE(tick.missed_periods, 4U);
  EXPECT_LT(tick.lateness_ns, 2'000'000 + 50'000'000);  // returned at once, not a period late
  const PeriodicTimer::Stats stats = timer.stats();
  // The overrun is one deadline miss (the first wake-up may be one too on a loaded machine).
  EXPECT_EQ(stats.deadline_misses, 1U + (first.missed_periods > 0 ? 1U : 0U));
  EXPECT_EQ(stats.missed_periods, first.missed_periods + tick.missed_periods);
  // Back on the grid: the next deadline is a whole number of periods later, one more than it
  // skipped (normally exactly one period; a loaded machine may deschedule this test for
  // longer, which must then be counted, not drift the schedule).
  const PeriodicTimer::Tick next = timer.wait_next();
  EXPECT_EQ(next.deadline_ns - tick.deadline_ns, static_cast<std::int64_t>(2'000'000 * (1 + next.missed_periods)));
  EXPECT_EQ(timer.stats().missed_periods, first.missed_periods + tick.missed_periods + next.missed_periods);
}

TEST(Rt, PeriodMustBePositive) { EXPECT_THROW(PeriodicTimer{0ns}, HalError); }

TEST(Rt, LockMemoryWorksOrSaysHowToAllowIt) {
  const Status s = lock_memory();
  if (s.ok()) {
    ::munlockall();
  } else {
    EXPECT_TRUE(contains(s.message(), "mlockall")) << s.message();
    EXPECT_TRUE(contains(s.message(), "LimitMEMLOCK")) << s.message();
  }
}

TEST(Rt, RealtimePriorityWorksOrSaysHowToAllowIt) {
  // On a thread of its own, so that the test runner's thread keeps normal scheduling.
  Status s;
  int policy_after = -1;
  std::thread{[&] {
    s = set_realtime_priority(10);
    sched_param p{};
    (void)pthread_getschedparam(pthread_self(), &policy_after, &p);
  }}.join();
  if (s.ok()) {
    EXPECT_EQ(policy_after, SCHED_FIFO);
  } else {
    EXPECT_TRUE(contains(s.message(), "SCHED_FIFO priority 10")) << s.message();
    EXPECT_TRUE(contains(s.message(), "LimitRTPRIO")) << s.message();
  }
  const Status bad = set_realtime_priority(0);
  EXPECT_FALSE(bad.ok());
  EXPECT_TRUE(contains(bad.message(), "out of range")) << bad.message();
}

TEST(Rt, CpuAffinityRejectsMissingCpusClearly) {
  Status s;
  std::thread{[&] {
    const std::array cpu0{0};
    s = set_cpu_affinity(cpu0);
  }}.join();
  EXPECT_TRUE(s.ok()) << s.message();
  const std::array missing{4096};
  const Status bad = set_cpu_affinity(missing);
  EXPECT_FALSE(bad.ok());
  EXPECT_TRUE(contains(bad.message(), "CPU 4096 does not exist")) << bad.message();
  EXPECT_FALSE(set_cpu_affinity({}).ok());
}

TEST(Rt, PrefaultStackDoesNotCrash) {
  prefault_stack(64U * 1024U);
  prefault_stack();
}

}  // namespace
}  // namespace pmsm::hal
