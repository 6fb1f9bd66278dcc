// The pieces a daemon's loops are built from (hal/io): the wait on several descriptors, the
// stop signals, single-writer counters, the non-RT -> RT value handoff and the record drain.
#include <gtest/gtest.h>

#include <fcntl.h>
#include <signal.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <thread>
#include <vector>

#include "pmsm/hal/counters.hpp"
#include "pmsm/hal/realtime_value.hpp"
#include "pmsm/hal/record_drain.hpp"
#include "pmsm/hal/rt.hpp"
#include "pmsm/hal/signals.hpp"
#include "pmsm/hal/wait.hpp"

namespace pmsm::hal {
namespace {

using namespace std::chrono_literals;

struct Pipe {
  int fd[2] = {-1, -1};
  Pipe() { EXPECT_EQ(::pipe2(fd, O_NONBLOCK | O_CLOEXEC), 0); }
  ~Pipe() {
    ::close(fd[0]);
    ::close(fd[1]);
  }
  void put() const { ASSERT_EQ(::write(fd[1], "x", 1), 1); }
};

TEST(DescriptorWait, TimesOutWhenNothingIsReadyAndNamesTheReadySlot) {
  Pipe a;
  Pipe b;
  DescriptorWait wait;
  const std::size_t sa = wait.add(a.fd[0]);
  const std::size_t sb = wait.add(b.fd[0]);
  const WaitResult none = wait.wait_for(1ms);
  EXPECT_TRUE(none.timed_out);
  EXPECT_EQ(none.ready_mask, 0U);
  b.put();
  const WaitResult r = wait.wait_for(1s);
  EXPECT_FALSE(r.timed_out);
  EXPECT_FALSE(r.ready(sa));
  EXPECT_TRUE(r.ready(sb));
}

TEST(DescriptorWait, AnIgnoredSlotNeverWakesAndCanBeSetLater) {
  Pipe a;
  DescriptorWait wait;
  const std::size_t slot = wait.add(-1);
  a.put();
  EXPECT_TRUE(wait.wait_for(1ms).timed_out);
  wait.set(slot, a.fd[0]);
  EXPECT_TRUE(wait.wait_for(1s).ready(slot));
}

TEST(StopSignals, SigtermSetsTheFlagAndWakesAWait) {
  ASSERT_TRUE(install_stop_signals().ok());
  ASSERT_GE(stop_signal_fd(), 0);
  stop_requested().store(false);
  DescriptorWait wait;
  const std::size_t slot = wait.add(stop_signal_fd());
  ASSERT_EQ(::raise(SIGTERM), 0);
  EXPECT_TRUE(stop_requested().load());
  EXPECT_TRUE(wait.wait_for(1s).ready(slot));
  stop_requested().store(false);
}

TEST(SingleWriterCounter, CountsAndRaises) {
  SingleWriterCounter c;
  c.bump();
  c.bump(4);
  EXPECT_EQ(c.get(), 5U);
  c.raise_to(3);
  EXPECT_EQ(c.get(), 5U);
  c.raise_to(9);
  EXPECT_EQ(c.get(), 9U);
}

struct Command {
  std::uint64_t sequence;
  std::uint64_t check;  // sequence * 7: a torn read would break it
};

TEST(RealtimeValue, TheReaderSeesTheInitialValueThenOnlyNewOnes) {
  RealtimeValue<Command> v(Command{0, 0});
  EXPECT_EQ(v.read_new(), nullptr);
  EXPECT_EQ(v.latest().sequence, 0U);
  v.write({1, 7});
  v.write({2, 14});
  const Command* c = v.read_new();
  ASSERT_NE(c, nullptr);
  EXPECT_EQ(c->sequence, 2U) << "the newest, never an older one";
  EXPECT_EQ(v.read_new(), nullptr);
  EXPECT_EQ(v.latest().sequence, 2U);
}

TEST(RealtimeValue, ConcurrentWriterAndReaderNeverTearAndNeverGoBack) {
  RealtimeValue<Command> v(Command{0, 0});
  constexpr std::uint64_t kWrites = 200000;
  std::thread writer([&] {
    for (std::uint64_t k = 1; k <= kWrites; ++k) {
      v.write({k, 7 * k});
    }
  });
  std::uint64_t last = 0;
  std::uint64_t reads = 0;
  while (last < kWrites) {
    const Command& c = v.latest();
    ASSERT_EQ(c.check, 7 * c.sequence) << "torn value";
    ASSERT_GE(c.sequence, last) << "went back in time";
    last = c.sequence;
    ++reads;
  }
  writer.join();
  EXPECT_GT(reads, 0U);
}

TEST(RecordDrain, HandsEveryRecordToTheHandlerOnItsOwnThreadAndDrainsOnStop) {
  SpscRing<Command, 64> ring;
  std::vector<std::uint64_t> seen;
  std::thread::id handler_thread;
  {
    RecordDrain<Command, 64> drain(
        ring,
        [&](const Command& c) {
          handler_thread = std::this_thread::get_id();
          seen.push_back(c.sequence);
        },
        1ms);
    for (std::uint64_t k = 0; k < 1000; ++k) {
      while (!ring.try_push({k, 7 * k})) {
        std::this_thread::yield();
      }
    }
    drain.stop();
    EXPECT_EQ(drain.drained(), 1000U);
  }
  ASSERT_EQ(seen.size(), 1000U);
  for (std::uint64_t k = 0; k < seen.size(); ++k) {
    EXPECT_EQ(seen[k], k);
  }
  EXPECT_NE(handler_thread, std::this_thread::get_id());
}

TEST(RealtimeMemory, PrepareSaysWhatWasRefusedOrSucceeds) {
  const Status s = prepare_memory_for_realtime();
  if (!s.ok()) {
    EXPECT_NE(s.message().find("mlockall"), std::string::npos) << s.message();
  }
}

}  // namespace
}  // namespace pmsm::hal
