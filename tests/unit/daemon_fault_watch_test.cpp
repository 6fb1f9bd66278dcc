// The fault-input watcher: driven by the line's edge events, not by polling; a failed read is
// reported as a fault.
#include <gtest/gtest.h>

#include <sys/eventfd.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdint>
#include <mutex>
#include <thread>
#include <vector>

#include "fault_watch.hpp"

namespace pmsm::daemon {
namespace {

struct Reports {
  std::mutex mutex;
  std::vector<std::pair<bool, bool>> seen;  // (fault, read_ok)

  void add(bool fault, bool ok) {
    const std::lock_guard lock(mutex);
    seen.emplace_back(fault, ok);
  }
  std::size_t size() {
    const std::lock_guard lock(mutex);
    return seen.size();
  }
  std::pair<bool, bool> last() {
    const std::lock_guard lock(mutex);
    return seen.back();
  }
  // Waits (bounded) for the n-th report; the bound only guards a hang, it is not the check.
  bool wait_for_count(std::size_t n) {
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds{10};
    while (size() < n && std::chrono::steady_clock::now() < until) {
      std::this_thread::sleep_for(std::chrono::milliseconds{1});
    }
    return size() >= n;
  }
  // Waits (bounded) until the last report is `expected`.
  bool wait_for_last(std::pair<bool, bool> expected) {
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds{10};
    while ((size() == 0 || last() != expected) && std::chrono::steady_clock::now() < until) {
      std::this_thread::sleep_for(std::chrono::milliseconds{1});
    }
    return size() > 0 && last() == expected;
  }
};

TEST(FaultWatch, WakesOnEdgesOnlyAndAFailedReadIsAFault) {
  hal::SimFaultInput input;
  std::atomic<bool> stop{false};
  const int stop_fd = ::eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
  ASSERT_GE(stop_fd, 0);
  Reports reports;
  FaultWatchStats stats;
  // A re-check period far beyond the test: every wake below is an edge.
  std::thread watcher([&] {
    watch_fault_input(input, stop, stop_fd, [&](bool fault, bool ok) { reports.add(fault, ok); }, stats,
                      std::chrono::hours{1});
  });
  ASSERT_TRUE(reports.wait_for_count(1));  // the level at start
  EXPECT_EQ(reports.last(), std::make_pair(false, true));
  input.set_fault(true);
  ASSERT_TRUE(reports.wait_for_count(2));
  EXPECT_EQ(reports.last(), std::make_pair(true, true));
  input.set_fault(true);  // no change, no edge
  // While a fault is reported the watcher reads the line again every millisecond (the end of
  // a pulse shows no edge of its own kind): the quiet line is reported soon after it goes quiet.
  input.set_fault(false);
  ASSERT_TRUE(reports.wait_for_last(std::make_pair(false, true)));
  // Quiet line, no reads: a 1 ms poller would have read it ~50 times by now (a loaded
  // machine can only make a poller read less, never an edge-driven watcher read more).
  const std::size_t quiet = reports.size();
  std::this_thread::sleep_for(std::chrono::milliseconds{50});
  EXPECT_EQ(reports.size(), quiet) << "the watcher reads without an edge: it polls";
  input.fail_with(EIO);
  ASSERT_TRUE(reports.wait_for_count(quiet + 1));
  EXPECT_EQ(reports.last(), std::make_pair(true, false)) << "a failed read must read as a fault";
  input.fail_with(0);
  const std::size_t failed = reports.size();
  input.set_fault(true);  // wakes it again (the retry after a failure reads too)
  ASSERT_TRUE(reports.wait_for_count(failed + 1));
  stop = true;
  const std::uint64_t one = 1;
  ASSERT_EQ(::write(stop_fd, &one, sizeof one), static_cast<ssize_t>(sizeof one));
  watcher.join();
  ::close(stop_fd);
  EXPECT_TRUE(stats.edge_driven);
  EXPECT_GE(stats.read_failures, 1U);
}

}  // namespace
}  // namespace pmsm::daemon
