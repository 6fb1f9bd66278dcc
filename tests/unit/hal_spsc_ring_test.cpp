#include "pmsm/hal/spsc_ring.hpp"

#include <gtest/gtest.h>

#include <cstdint>
#include <memory>
#include <thread>

namespace pmsm::hal {
namespace {

struct Record {
  std::uint64_t sequence = 0;
  std::uint64_t check = 0;  // derived from sequence: detects torn or stale copies
  double value = 0.0;
};

constexpr std::uint64_t check_of(std::uint64_t sequence) { return sequence * 0x9E37'79B9'7F4A'7C15ULL + 1U; }

TEST(SpscRing, PopsInPushOrderAndReportsEmpty) {
  SpscRing<Record, 8> ring;
  Record r;
  EXPECT_FALSE(ring.try_pop(r));
  for (std::uint64_t i = 0; i < 5; ++i) {
    ASSERT_TRUE(ring.try_push(Record{i, check_of(i), 0.5}));
  }
  EXPECT_EQ(ring.size_approx(), 5U);
  for (std::uint64_t i = 0; i < 5; ++i) {
    ASSERT_TRUE(ring.try_pop(r));
    EXPECT_EQ(r.sequence, i);
  }
  EXPECT_FALSE(ring.try_pop(r));
  EXPECT_TRUE(ring.empty_approx());
  EXPECT_EQ(ring.dropped(), 0U);
}

TEST(SpscRing, AllSlotsUsableThenDropsAndCountsWhenFull) {
  SpscRing<Record, 4> ring;
  static_assert(SpscRing<Record, 4>::capacity() == 4);
  for (std::uint64_t i = 0; i < 4; ++i) {
    EXPECT_TRUE(ring.try_push(Record{i, check_of(i), 0.0}));
  }
  EXPECT_FALSE(ring.try_push(Record{99, 0, 0.0}));
  EXPECT_FALSE(ring.try_push(Record{100, 0, 0.0}));
  EXPECT_EQ(ring.dropped(), 2U);
  Record r;
  ASSERT_TRUE(ring.try_pop(r));
  EXPECT_EQ(r.sequence, 0U);  // the oldest survives; the dropped ones were the new ones
  EXPECT_TRUE(ring.try_push(Record{4, check_of(4), 0.0}));
  for (std::uint64_t expected = 1; expected <= 4; ++expected) {
    ASSERT_TRUE(ring.try_pop(r));
    EXPECT_EQ(r.sequence, expected);
  }
}

TEST(SpscRing, WrapsAroundManyTimes) {
  SpscRing<std::uint32_t, 8> ring;
  std::uint32_t next_out = 0;
  for (std::uint32_t i = 0; i < 10'000; ++i) {
    ASSERT_TRUE(ring.try_push(i));
    if (i % 3 != 0) {
      std::uint32_t v = 0;
      ASSERT_TRUE(ring.try_pop(v));
      ASSERT_EQ(v, next_out++);
    }
    while (ring.size_approx() > 6) {
      std::uint32_t v = 0;
      ASSERT_TRUE(ring.try_pop(v));
      ASSERT_EQ(v, next_out++);
    }
  }
  EXPECT_EQ(ring.dropped(), 0U);
}

// Two threads: a producer that retries when the ring is full (so nothing may be lost) and
// a consumer that checks every record arrives once, in order, intact.
TEST(SpscRing, TwoThreadsLoseNothingWhenProducerWaitsForRoom) {
  constexpr std::uint64_t kRecords = 2'000'000;
  auto ring = std::make_unique<SpscRing<Record, 1024>>();
  std::uint64_t full_retries = 0;
  std::thread producer{[&] {
    for (std::uint64_t i = 0; i < kRecords; ++i) {
      const Record r{i, check_of(i), static_cast<double>(i)};
      while (!ring->try_push(r)) {
        ++full_retries;
        std::this_thread::yield();
      }
    }
  }};
  std::uint64_t expected = 0;
  std::uint64_t bad = 0;
  while (expected < kRecords) {
    Record r;
    if (!ring->try_pop(r)) {
      std::this_thread::yield();
      continue;
    }
    if (r.sequence != expected || r.check != check_of(expected) || r.value != static_cast<double>(expected)) {
      ++bad;
    }
    ++expected;
  }
  producer.join();
  EXPECT_EQ(bad, 0U);
  // Every failed try_push is counted as a drop, and the producer retried exactly those.
  EXPECT_EQ(ring->dropped(), full_retries);
  Record r;
  EXPECT_FALSE(ring->try_pop(r));
}

// A producer that never waits (as the RT thread): what arrives is in order and intact, and
// arrivals plus drops account for every record.
TEST(SpscRing, TwoThreadsDropCountAccountsForEveryRecord) {
  constexpr std::uint64_t kRecords = 1'000'000;
  auto ring = std::make_unique<SpscRing<Record, 64>>();
  std::atomic<bool> done{false};
  std::thread producer{[&] {
    for (std::uint64_t i = 0; i < kRecords; ++i) {
      (void)ring->try_push(Record{i, check_of(i), 0.0});
    }
    done.store(true);
  }};
  std::uint64_t received = 0;
  std::uint64_t last = 0;
  bool ordered = true;
  bool intact = true;
  for (;;) {
    Record r;
    if (ring->try_pop(r)) {
      ordered = ordered && (received == 0 || r.sequence > last);
      intact = intact && r.check == check_of(r.sequence);
      last = r.sequence;
      ++received;
    } else if (done.load()) {
      if (!ring->try_pop(r)) {
        break;
      }
      ordered = ordered && (received == 0 || r.sequence > last);
      intact = intact && r.check == check_of(r.sequence);
      last = r.sequence;
      ++received;
    }
  }
  producer.join();
  EXPECT_TRUE(ordered);
  EXPECT_TRUE(intact);
  EXPECT_EQ(received + ring->dropped(), kRecords);
}

}  // namespace
}  // namespace pmsm::hal
