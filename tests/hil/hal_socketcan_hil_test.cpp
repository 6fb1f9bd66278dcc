// SocketCanBus on a real virtual CAN interface (PMSM_CAN_IFACE, default vcan0), run through
// scripts/vcan-env. Under User-Mode Linux the bus is private to this run; natively it may be
// shared with other tests, so every data frame here uses extended identifiers tagged with
// this process's id and every receiver filters on them. Tests that change an interface or
// inject error frames do it on a vcan of their own (skipped without CAP_NET_ADMIN).
#include <gtest/gtest.h>
#include <sys/utsname.h>
#include <unistd.h>

#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include "pmsm/hal/rt.hpp"       // monotonic_ns
#include "pmsm/hal/sim_bus.hpp"  // make_error_frame
#include "pmsm/hal/socketcan.hpp"

namespace pmsm::hal {
namespace {

using namespace std::chrono_literals;

std::string iface() {
  const char* name = std::getenv("PMSM_CAN_IFACE");
  return name != nullptr && *name != '\0' ? name : "vcan0";
}

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

// Extended identifiers private to this process: 0x0PPPPnnn.
std::uint32_t tagged(std::uint32_t n) {
  return (static_cast<std::uint32_t>(::getpid()) & 0xFFFFU) << 12U | (n & 0xFFFU);
}
CanFilter tag_filter() { return CanFilter{tagged(0), 0x1FFF'F000, CanIdKind::kExtended}; }

CanFrame frame(std::uint32_t n, std::uint8_t length, bool fd = false) {
  CanFrame f;
  f.id = tagged(n);
  f.extended = true;
  f.fd = fd;
  f.bitrate_switch = fd;
  f.length = length;
  for (std::uint8_t i = 0; i < length; ++i) {
    f.data[i] = static_cast<std::uint8_t>(n * 7U + i);
  }
  return f;
}

std::unique_ptr<SocketCanBus> open_bus(bool fd, std::vector<CanFilter> filters, const std::string& name = iface()) {
  return std::make_unique<SocketCanBus>(SocketCanConfig{.interface = name, .fd = fd, .filters = std::move(filters)});
}

std::vector<ReceivedFrame> receive_all(CanBus& bus, std::chrono::nanoseconds quiet = 100ms) {
  std::vector<ReceivedFrame> frames;
  ReceivedFrame r;
  while (bus.receive(r, quiet) == ReceiveStatus::kFrame) {
    frames.push_back(r);
  }
  return frames;
}

// CAP_NET_ADMIN in this process's effective set (/proc/self/status CapEff, bit 12): what
// SO_RCVBUFFORCE needs, which a root process in a container may lack.
bool has_cap_net_admin() {
  std::ifstream status("/proc/self/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.rfind("CapEff:", 0) == 0) {
      const unsigned long long caps = std::stoull(line.substr(7), nullptr, 16);
      return ((caps >> 12U) & 1U) != 0U;
    }
  }
  return false;
}

bool run(const std::string& command) { return std::system((command + " 2>/dev/null").c_str()) == 0; }

// A vcan interface of our own (needs CAP_NET_ADMIN: root in the UML guest), removed after.
class ScratchVcan {
 public:
  explicit ScratchVcan(int mtu) : name_("pmsm" + std::to_string(::getpid() % 100000) + "m" + std::to_string(mtu)) {
    created_ = run("ip link add dev " + name_ + " type vcan") &&
               run("ip link set dev " + name_ + " mtu " + std::to_string(mtu)) &&
               run("ip link set dev " + name_ + " up");
  }
  ~ScratchVcan() { (void)run("ip link del dev " + name_); }
  ScratchVcan(const ScratchVcan&) = delete;
  ScratchVcan& operator=(const ScratchVcan&) = delete;
  [[nodiscard]] bool created() const { return created_; }
  [[nodiscard]] const std::string& name() const { return name_; }

 private:
  std::string name_;
  bool created_ = false;
};

// Linux 5.17 or later (a send's success without a completion), io_uring not disabled by sysctl.
bool kernel_should_have_io_uring() {
  utsname u{};
  int major = 0;
  int minor = 0;
  if (::uname(&u) != 0 || std::sscanf(u.release, "%d.%d", &major, &minor) != 2) {
    return false;
  }
  std::ifstream disabled("/proc/sys/kernel/io_uring_disabled");
  int value = 0;
  if (disabled >> value && value != 0) {
    return false;
  }
  return major > 5 || (major == 5 && minor >= 17);
}

TEST(SocketCanHil, ClassicFrameTravelsBetweenTwoSocketsWithTimestamp) {
  auto tx = open_bus(false, {tag_filter()});
  auto rx = open_bus(false, {tag_filter()});
  EXPECT_TRUE(tx->interface_up());
  EXPECT_FALSE(tx->fd_enabled());
  EXPECT_GT(tx->interface_index(), 0);

  const CanFrame sent = frame(1, 8);
  ASSERT_EQ(tx->send(sent), SendResult::kOk);
  ReceivedFrame r;
  ASSERT_EQ(rx->receive(r, 2s), ReceiveStatus::kFrame);
  EXPECT_EQ(r.frame.id, sent.id);
  EXPECT_TRUE(r.frame.extended);
  EXPECT_FALSE(r.frame.fd);
  EXPECT_FALSE(r.frame.error);
  EXPECT_EQ(r.frame.length, 8U);
  EXPECT_EQ(r.frame.data, sent.data);

  // The kernel's software receive timestamp, on the real-time clock.
  const auto now_ns = std::chrono::duration_cast<std::chrono::nanoseconds>(
                          std::chrono::system_clock::now().time_since_epoch())
                          .count();
  EXPECT_GT(r.timestamp_ns, 0);
  EXPECT_LT(std::llabs(now_ns - r.timestamp_ns), 60'000'000'000LL);
  EXPECT_FALSE(r.hardware_timestamp);

  // The sender does not hear its own frame.
  EXPECT_EQ(tx->receive(r, 50ms), ReceiveStatus::kTimeout);

  const CanBusCounters tc = tx->counters();
  const CanBusCounters rc = rx->counters();
  EXPECT_EQ(tc.tx_frames, 1U);
  EXPECT_EQ(rc.rx_frames, 1U);
  EXPECT_EQ(rc.bad_size_reads, 0U);
  EXPECT_EQ(rc.rx_errors, 0U);
  EXPECT_EQ(rc.rx_overflow, 0U);
}

// receive() reads first after a frame that was already queued and waits first after one it
// waited for; receive_backstop() is one blocking read. Every order gives every frame, in order,
// and a timeout that is not early.
TEST(SocketCanHil, EveryWaitOrderAndTheBackstopReadDeliverEveryFrameInOrder) {
  auto tx = open_bus(false, {tag_filter()});
  auto rx = open_bus(false, {tag_filter()});
  ReceivedFrame r;
  std::uint32_t next = 0;
  const auto expect_next = [&](ReceiveStatus status) {
    ASSERT_EQ(status, ReceiveStatus::kFrame);
    EXPECT_EQ(r.frame.data[0], static_cast<std::uint8_t>(next * 7U)) << "frame " << next;
    ++next;
  };
  // A burst already queued, read with a timeout (read first) and with the backstop.
  for (std::uint32_t k = 0; k < 4; ++k) {
    ASSERT_EQ(tx->send(frame(k, 8)), SendResult::kOk);
  }
  expect_next(rx->receive(r, 1s));
  EXPECT_EQ(r.waited_ns, 0) << "a frame already queued is read without a wait";
  expect_next(rx->receive(r, 1s));
  expect_next(rx->receive_backstop(r, 1s));
  EXPECT_EQ(r.waited_ns, -1) << "the backstop's wait is not told";
  expect_next(rx->receive(r, 1s));
  // Empty: each form times out, and not before its timeout.
  for (const bool backstop : {false, true}) {
    const auto t0 = std::chrono::steady_clock::now();
    EXPECT_EQ(backstop ? rx->receive_backstop(r, 30ms) : rx->receive(r, 30ms), ReceiveStatus::kTimeout);
    EXPECT_GE(std::chrono::steady_clock::now() - t0, 30ms) << (backstop ? "backstop" : "receive");
  }
  // A frame that arrives during the wait (the lockstep case), for both forms. receive() tells
  // how long it waited, by the kernel's account (ppoll's time left, on a 64-bit target): more
  // than nothing, and within the call as the clock saw it from outside.
  for (const bool backstop : {false, true, false}) {
    const std::uint32_t k = next;
    std::thread sender([&tx, k] {
      std::this_thread::sleep_for(20ms);
      (void)tx->send(frame(k, 8));
    });
    const std::int64_t before = monotonic_ns();
    expect_next(backstop ? rx->receive_backstop(r, 2s) : rx->receive(r, 2s));
    const std::int64_t after = monotonic_ns();
    sender.join();
    if (backstop || sizeof(long) != 8) {
      EXPECT_EQ(r.waited_ns, -1);
    } else {
      EXPECT_GT(r.waited_ns, 0) << "the frame came 20 ms into the wait";
      EXPECT_LE(r.waited_ns, after - before);
    }
  }
  // After a wait, a queued frame is still read at once.
  ASSERT_EQ(tx->send(frame(next, 8)), SendResult::kOk);
  expect_next(rx->receive(r, 1s));
  EXPECT_EQ(rx->receive(r, 0ms), ReceiveStatus::kTimeout);
  EXPECT_EQ(rx->counters().rx_frames, next);
  EXPECT_EQ(rx->counters().rx_errors, 0U);
}

// send_and_receive(): a lockstep period's answer and wait for the next frame, one io_uring_enter
// where the kernel has io_uring (User-Mode Linux's 6.1 has), else a send and a receive; the
// same behaviour either way. Every frame arrives once and in order, also when it comes as a wait
// times out (the read is then cancelled: a frame it took meanwhile is delivered, not lost).
TEST(SocketCanHil, SendAndReceiveSendsWaitsTimesOutAndLosesNoFrame) {
  auto a = std::make_unique<SocketCanBus>(
      SocketCanConfig{.interface = iface(), .fd = true, .filters = std::vector<CanFilter>{tag_filter()}, .io_uring = true});
  auto b = open_bus(true, {tag_filter()});
  const bool one_call = a->exchanges_in_one_call();
  std::printf("send_and_receive in one call (io_uring): %s\n", one_call ? "yes" : "no");
  // User-Mode Linux's kernel (6.1) has io_uring with what the call needs; so has any kernel from
  // 5.17 that does not disable it.
  EXPECT_TRUE(one_call || !kernel_should_have_io_uring()) << "io_uring refused on a kernel that has it";
  ReceivedFrame r;

  // Lockstep: b answers every frame from a with its number + 100.
  constexpr std::uint32_t kPeriods = 200;
  std::thread peer([&b] {
    ReceivedFrame in;
    for (std::uint32_t k = 0; k < kPeriods; ++k) {
      if (b->receive(in, 5s) != ReceiveStatus::kFrame) {
        return;
      }
      (void)b->send(frame(in.frame.data[0] / 7U + 100U, 12, true));
    }
  });
  // The first period sends only (nothing to wait for yet but the answer).
  for (std::uint32_t k = 0; k < kPeriods; ++k) {
    const CanFrame out = frame(k % 30U, 24, true);
    const std::int64_t before = monotonic_ns();
    const std::int64_t before_rt = std::chrono::duration_cast<std::chrono::nanoseconds>(
                                       std::chrono::system_clock::now().time_since_epoch()).count();
    const ExchangeResult x = a->send_and_receive(&out, before + 1'000'000'000, r, before, before + 2'000'000'000);
    ASSERT_EQ(x.sent, SendResult::kOk) << "period " << k;
    ASSERT_EQ(x.received, ReceiveStatus::kFrame) << "period " << k;
    EXPECT_EQ(r.frame.data[0], static_cast<std::uint8_t>((k % 30U + 100U) * 7U)) << "period " << k;
    EXPECT_EQ(r.frame.length, 12U);
    EXPECT_TRUE(r.frame.fd);
    // The receive timestamp is there (the frame's moment where the wait is not told), after the
    // call began.
    EXPECT_GE(r.software_timestamp_ns, before_rt - 1'000'000) << "period " << k;
    if (one_call) {
      EXPECT_EQ(r.waited_ns, -1) << "one call does not tell its wait";
    }
  }
  peer.join();
  EXPECT_EQ(a->counters().tx_frames, kPeriods);
  EXPECT_EQ(a->counters().rx_frames, kPeriods);

  // Nothing comes: a timeout, not early; no send.
  {
    const std::int64_t t0 = monotonic_ns();
    const ExchangeResult x = a->send_and_receive(nullptr, 0, r, t0, t0 + 30'000'000);
    EXPECT_EQ(x.sent, SendResult::kOk);
    EXPECT_EQ(x.received, ReceiveStatus::kTimeout);
    EXPECT_GE(monotonic_ns() - t0, 30'000'000);
  }
  // A frame queued before the call is read at once; an unsendable frame is refused and counted
  // and the wait still happens.
  ASSERT_EQ(b->send(frame(7, 8, true)), SendResult::kOk);
  std::this_thread::sleep_for(10ms);
  {
    CanFrame bad = frame(1, 8, true);
    bad.id = 0x2000'0000U;  // beyond 29 bits
    const std::int64_t t0 = monotonic_ns();
    const ExchangeResult x = a->send_and_receive(&bad, t0 + 1'000'000, r, t0, t0 + 1'000'000'000);
    EXPECT_EQ(x.sent, SendResult::kInvalidFrame);
    ASSERT_EQ(x.received, ReceiveStatus::kFrame);
    EXPECT_EQ(r.frame.data[0], static_cast<std::uint8_t>(7U * 7U));
    EXPECT_LT(monotonic_ns() - t0, 500'000'000) << "a queued frame is no wait";
  }
  EXPECT_EQ(a->counters().tx_errors, 1U);

  // Frames at random moments against waits of 1 ms: many waits end as a frame comes. Every
  // frame is delivered once, in order.
  constexpr std::uint32_t kFrames = 300;
  std::thread sender([&b] {
    std::uint32_t seed = 12345;
    for (std::uint32_t k = 0; k < kFrames; ++k) {
      seed = seed * 1103515245U + 12345U;
      std::this_thread::sleep_for(std::chrono::microseconds(200 + (seed >> 16U) % 1800U));
      (void)b->send(frame(k % 36U, 8, true));
    }
  });
  std::uint32_t got = 0;
  std::uint32_t timeouts = 0;
  const std::int64_t end = monotonic_ns() + 20'000'000'000;
  while (got < kFrames && monotonic_ns() < end) {
    const std::int64_t t0 = monotonic_ns();
    const ExchangeResult x = a->send_and_receive(nullptr, 0, r, t0, t0 + 1'000'000);
    if (x.received == ReceiveStatus::kTimeout) {
      ++timeouts;
      continue;
    }
    ASSERT_EQ(x.received, ReceiveStatus::kFrame);
    ASSERT_EQ(r.frame.data[0], static_cast<std::uint8_t>((got % 36U) * 7U)) << "frame " << got;
    ++got;
  }
  sender.join();
  EXPECT_EQ(got, kFrames);
  EXPECT_GT(timeouts, 0U);
  EXPECT_EQ(a->send_and_receive(nullptr, 0, r, monotonic_ns(), monotonic_ns() + 20'000'000).received,
            ReceiveStatus::kTimeout);
  EXPECT_EQ(a->counters().rx_errors, 0U);
  // Plain receive() after the exchanges: nothing left in flight takes its frame.
  ASSERT_EQ(b->send(frame(3, 8, true)), SendResult::kOk);
  ASSERT_EQ(a->receive(r, 1s), ReceiveStatus::kFrame);
  EXPECT_EQ(r.frame.data[0], static_cast<std::uint8_t>(3U * 7U));
}

// A send the kernel refuses inside the one call (its interface down): told and counted once, the
// wait still bounded by its deadline, and the exchanges go on once the interface is back.
TEST(SocketCanHil, SendAndReceiveReportsASendTheKernelRefuses) {
  ScratchVcan scratch(72);
  if (!scratch.created()) {
    GTEST_SKIP() << "cannot create a vcan (needs CAP_NET_ADMIN)";
  }
  auto a = std::make_unique<SocketCanBus>(SocketCanConfig{
      .interface = scratch.name(), .fd = true, .filters = std::vector<CanFilter>{tag_filter()}, .io_uring = true});
  auto b = open_bus(true, {tag_filter()}, scratch.name());
  ASSERT_TRUE(run("ip link set dev " + scratch.name() + " down"));
  ReceivedFrame r;
  const CanFrame out = frame(5, 8, true);
  std::int64_t t0 = monotonic_ns();
  ExchangeResult x = a->send_and_receive(&out, t0 + 1'000'000, r, t0, t0 + 30'000'000);
  const std::int64_t took = monotonic_ns() - t0;
  EXPECT_EQ(x.sent, SendResult::kInterfaceDown);
  EXPECT_NE(x.received, ReceiveStatus::kFrame);
  EXPECT_LT(took, 1'000'000'000) << "the wait ends by its deadline";
  CanBusCounters c = a->counters();
  EXPECT_EQ(c.tx_frames, 0U);
  EXPECT_EQ(c.tx_errors, 1U);
  EXPECT_GE(c.interface_down_events, 1U);

  ASSERT_TRUE(run("ip link set dev " + scratch.name() + " up"));
  ASSERT_EQ(a->reopen().ok(), true);
  ASSERT_EQ(b->reopen().ok(), true);
  std::thread peer([&b] {
    ReceivedFrame in;
    if (b->receive(in, 5s) == ReceiveStatus::kFrame) {
      (void)b->send(frame(6, 8, true));
    }
  });
  t0 = monotonic_ns();
  x = a->send_and_receive(&out, t0 + 1'000'000'000, r, t0, t0 + 5'000'000'000);
  peer.join();
  EXPECT_EQ(x.sent, SendResult::kOk);
  ASSERT_EQ(x.received, ReceiveStatus::kFrame);
  EXPECT_EQ(r.frame.data[0], static_cast<std::uint8_t>(6U * 7U));
  EXPECT_EQ(a->counters().tx_frames, 1U);
}

TEST(SocketCanHil, FdFramesReachFdSocketsOnlyAndReadsHaveExactSizes) {
  auto fd_tx = open_bus(true, {tag_filter()});
  auto fd_rx = open_bus(true, {tag_filter()});
  auto classic_rx = open_bus(false, {tag_filter()});
  ASSERT_TRUE(fd_tx->fd_enabled());

  // Every FD length, then classic frames from the FD socket.
  const std::vector<std::uint8_t> lengths{0, 1, 8, 12, 16, 20, 24, 32, 48, 64};
  std::uint32_t n = 0x100;
  for (const std::uint8_t length : lengths) {
    ASSERT_EQ(fd_tx->send(frame(n++, length, true)), SendResult::kOk);
  }
  for (std::uint8_t length = 0; length <= 8; ++length) {
    ASSERT_EQ(fd_tx->send(frame(n++, length, false)), SendResult::kOk);
  }
  const std::vector<ReceivedFrame> at_fd = receive_all(*fd_rx);
  ASSERT_EQ(at_fd.size(), lengths.size() + 9);
  for (std::size_t i = 0; i < at_fd.size(); ++i) {
    const CanFrame& f = at_fd[i].frame;
    const bool fd = i < lengths.size();
    const std::uint8_t length = fd ? lengths[i] : static_cast<std::uint8_t>(i - lengths.size());
    const CanFrame expected = frame(0x100U + static_cast<std::uint32_t>(i), length, fd);
    EXPECT_EQ(f.id, expected.id);
    EXPECT_EQ(f.fd, fd) << i;
    EXPECT_EQ(f.bitrate_switch, fd) << i;
    EXPECT_EQ(f.length, length) << i;
    EXPECT_EQ(f.data, expected.data) << i;
  }
  // The classic socket sees only the classic frames: the kernel drops FD frames for it.
  const std::vector<ReceivedFrame> at_classic = receive_all(*classic_rx);
  ASSERT_EQ(at_classic.size(), 9U);
  for (const ReceivedFrame& r : at_classic) {
    EXPECT_FALSE(r.frame.fd);
  }
  EXPECT_EQ(fd_rx->counters().bad_size_reads, 0U);
  EXPECT_EQ(classic_rx->counters().bad_size_reads, 0U);
  EXPECT_EQ(fd_tx->counters().tx_frames, lengths.size() + 9);

  // A classic socket refuses to send FD frames.
  EXPECT_EQ(classic_rx->send(frame(0x200, 12, true)), SendResult::kInvalidFrame);
  EXPECT_EQ(classic_rx->counters().tx_errors, 1U);
}

TEST(SocketCanHil, KernelFiltersDropUnselectedFrames) {
  auto tx = open_bus(false, {tag_filter()});
  // Exactly tagged(0x10), and the range tagged(0x20..0x2F).
  auto rx = open_bus(false, {CanFilter::exact(tagged(0x10), true),
                             CanFilter{tagged(0x20), 0x1FFF'FFF0, CanIdKind::kExtended}});
  ASSERT_EQ(tx->send(frame(0x10, 1)), SendResult::kOk);  // pass
  ASSERT_EQ(tx->send(frame(0x11, 1)), SendResult::kOk);  // no
  ASSERT_EQ(tx->send(frame(0x2A, 1)), SendResult::kOk);  // pass
  ASSERT_EQ(tx->send(frame(0x30, 1)), SendResult::kOk);  // no
  CanFrame standard = frame(0x10, 1);                     // same number, standard kind: no
  standard.extended = false;
  standard.id &= kMaxStandardId;
  ASSERT_EQ(tx->send(standard), SendResult::kOk);

  const std::vector<ReceivedFrame> got = receive_all(*rx);
  ASSERT_EQ(got.size(), 2U);
  EXPECT_EQ(got[0].frame.id, tagged(0x10));
  EXPECT_EQ(got[1].frame.id, tagged(0x2A));
  EXPECT_EQ(rx->counters().rx_frames, 2U);

  // An empty list passes nothing.
  ASSERT_TRUE(rx->set_filters({}).ok());
  ASSERT_EQ(tx->send(frame(0x10, 1)), SendResult::kOk);
  EXPECT_TRUE(receive_all(*rx, 50ms).empty());
}

TEST(SocketCanHil, ErrorFramesFollowTheErrorMask) {
  // Error frames carry no identifier to filter on: every socket with a matching error mask
  // gets them. So this test injects them on an interface of its own, never on a bus that
  // other tests (or a daemon) may share.
  ScratchVcan private_if{16};
  if (!private_if.created()) {
    GTEST_SKIP() << "cannot create a private vcan interface here (needs CAP_NET_ADMIN)";
  }
  // Error frames written to vcan are looped back like data frames (can-utils canerrsim).
  auto injector = open_bus(false, {tag_filter()}, private_if.name());
  auto watcher = open_bus(false, {tag_filter()}, private_if.name());
  auto deaf = open_bus(false, {tag_filter()}, private_if.name());
  ASSERT_TRUE(watcher->set_error_mask(kCanErrBusOff | kCanErrController | kCanErrRestarted).ok());

  ASSERT_EQ(injector->send(make_error_frame(CanBusState::kErrorPassive)), SendResult::kOk);
  ReceivedFrame r;
  ASSERT_EQ(watcher->receive(r, 2s), ReceiveStatus::kFrame);
  EXPECT_TRUE(r.frame.error);
  EXPECT_EQ(r.frame.id, kCanErrController);
  EXPECT_EQ(watcher->state(), CanBusState::kErrorPassive);

  ASSERT_EQ(injector->send(make_error_frame(CanBusState::kBusOff)), SendResult::kOk);
  ASSERT_EQ(watcher->receive(r, 2s), ReceiveStatus::kFrame);
  EXPECT_EQ(watcher->state(), CanBusState::kBusOff);

  CanFrame restarted;
  restarted.error = true;
  restarted.id = kCanErrRestarted;
  restarted.length = 8;
  ASSERT_EQ(injector->send(restarted), SendResult::kOk);
  ASSERT_EQ(watcher->receive(r, 2s), ReceiveStatus::kFrame);
  EXPECT_EQ(watcher->state(), CanBusState::kErrorActive);

  // A class outside the mask does not arrive.
  CanFrame protocol;
  protocol.error = true;
  protocol.id = kCanErrProtocol;
  protocol.length = 8;
  ASSERT_EQ(injector->send(protocol), SendResult::kOk);
  EXPECT_EQ(watcher->receive(r, 100ms), ReceiveStatus::kTimeout);

  const CanBusCounters c = watcher->counters();
  EXPECT_EQ(c.error_frames, 3U);
  EXPECT_EQ(c.bus_off_events, 1U);
  EXPECT_EQ(c.rx_frames, 0U);
  // Without an error mask no error frame arrives at all.
  EXPECT_EQ(deaf->receive(r, 100ms), ReceiveStatus::kTimeout);
  EXPECT_EQ(deaf->counters().error_frames, 0U);
  EXPECT_EQ(deaf->state(), CanBusState::kErrorActive);
}

TEST(SocketCanHil, KernelReceiveDropsAreCountedWithSoRxqOvfl) {
  auto tx = open_bus(false, {tag_filter()});
  auto rx = std::make_unique<SocketCanBus>(SocketCanConfig{
      .interface = iface(), .fd = false, .filters = std::vector{tag_filter()}, .receive_buffer_bytes = 4096});
  constexpr std::uint32_t kBurst = 400;
  for (std::uint32_t i = 0; i < kBurst; ++i) {
    ASSERT_EQ(tx->send(frame(i, 8), 100ms), SendResult::kOk);
  }
  // The drop count travels with the next queued frame: drain, then send one more.
  std::vector<ReceivedFrame> got = receive_all(*rx);
  ASSERT_EQ(tx->send(frame(kBurst, 8)), SendResult::kOk);
  const std::vector<ReceivedFrame> last = receive_all(*rx);
  ASSERT_EQ(last.size(), 1U);
  const CanBusCounters c = rx->counters();
  EXPECT_GT(c.rx_overflow, 0U) << "a " << kBurst << "-frame burst into a 4 KiB socket buffer should overflow";
  EXPECT_EQ(c.rx_frames + c.rx_overflow, kBurst + 1);
  EXPECT_EQ(c.rx_frames, got.size() + 1);
}

// A receive buffer larger than net.core.rmem_max (the monitor asks 16 MiB): granted with
// CAP_NET_ADMIN through SO_RCVBUFFORCE, as candump -r does, and then a burst hundreds of times
// what the default queue holds (about 500 frames) arrives whole. Without the capability the
// kernel's cap is what is granted, and the accessor says so.
TEST(SocketCanHil, ALargeReceiveBufferIsGrantedBeyondRmemMaxWithCapNetAdmin) {
  constexpr int kAsked = 16 * 1024 * 1024;
  auto tx = open_bus(false, {tag_filter()});
  auto rx = std::make_unique<SocketCanBus>(SocketCanConfig{
      .interface = iface(), .fd = false, .filters = std::vector{tag_filter()}, .receive_buffer_bytes = kAsked});
  if (!has_cap_net_admin()) {
    EXPECT_GT(rx->receive_buffer_granted_bytes(), 0);
    EXPECT_LE(rx->receive_buffer_granted_bytes(), kAsked);
    GTEST_SKIP() << "SO_RCVBUFFORCE needs CAP_NET_ADMIN; granted " << rx->receive_buffer_granted_bytes() << " bytes";
  }
  EXPECT_EQ(rx->receive_buffer_granted_bytes(), kAsked);
  constexpr std::uint32_t kBurst = 10000;
  for (std::uint32_t i = 0; i < kBurst; ++i) {
    ASSERT_EQ(tx->send(frame(i, 8), 100ms), SendResult::kOk) << "frame " << i;
  }
  const std::vector<ReceivedFrame> got = receive_all(*rx);
  EXPECT_EQ(got.size(), kBurst);
  EXPECT_EQ(rx->counters().rx_overflow, 0U);
}

TEST(SocketCanHil, MissingOrNonCanInterfacesAreClearErrors) {
  try {
    (void)open_bus(false, {}, "pmsmnosuch0");
    FAIL() << "expected HalError";
  } catch (const HalError& e) {
    EXPECT_TRUE(contains(e.what(), "no such CAN interface 'pmsmnosuch0'")) << e.what();
  }
  try {
    (void)open_bus(false, {}, "lo");
    FAIL() << "expected HalError";
  } catch (const HalError& e) {
    EXPECT_TRUE(contains(e.what(), "'lo' is not a CAN interface")) << e.what();
  }
}

TEST(SocketCanHil, FdOnAClassicMtuInterfaceIsAClearError) {
  ScratchVcan classic_only{16};
  if (!classic_only.created()) {
    GTEST_SKIP() << "cannot create a vcan interface here (needs CAP_NET_ADMIN)";
  }
  try {
    (void)open_bus(true, {}, classic_only.name());
    FAIL() << "expected HalError";
  } catch (const HalError& e) {
    EXPECT_TRUE(contains(e.what(), "CAN FD requested on '" + classic_only.name() + "' but its MTU is 16")) << e.what();
  }
  EXPECT_NO_THROW((void)open_bus(false, {}, classic_only.name()));
}

TEST(SocketCanHil, InterfaceDownIsReportedAndReopenReconnects) {
  ScratchVcan bus_if{72};
  if (!bus_if.created()) {
    GTEST_SKIP() << "cannot create a vcan interface here (needs CAP_NET_ADMIN)";
  }
  const std::string& name = bus_if.name();
  auto a = open_bus(true, {tag_filter()}, name);
  auto b = open_bus(true, {tag_filter()}, name);
  ASSERT_EQ(a->send(frame(1, 8)), SendResult::kOk);
  ReceivedFrame r;
  ASSERT_EQ(b->receive(r, 2s), ReceiveStatus::kFrame);

  // Down: sends fail with ENETDOWN, the reader is told once.
  ASSERT_TRUE(run("ip link set dev " + name + " down"));
  EXPECT_FALSE(a->interface_up());
  EXPECT_EQ(a->send(frame(2, 8)), SendResult::kInterfaceDown);
  EXPECT_EQ(a->last_error_number(), ENETDOWN);
  EXPECT_EQ(b->receive(r, 500ms), ReceiveStatus::kInterfaceDown);
  // Up again: the binding survived, no reopen needed.
  ASSERT_TRUE(run("ip link set dev " + name + " up"));
  EXPECT_TRUE(a->interface_up());
  ASSERT_EQ(a->send(frame(3, 8)), SendResult::kOk);
  ASSERT_EQ(b->receive(r, 2s), ReceiveStatus::kFrame);
  EXPECT_EQ(r.frame.id, tagged(3));

  // Deleted and created again (a new interface index): the sockets lost their binding
  // and reopen() reconnects them.
  ASSERT_TRUE(run("ip link del dev " + name));
  EXPECT_EQ(a->send(frame(4, 8)), SendResult::kInterfaceDown);
  EXPECT_EQ(b->receive(r, 500ms), ReceiveStatus::kInterfaceDown);
  ASSERT_TRUE(run("ip link add dev " + name + " type vcan") && run("ip link set dev " + name + " mtu 72") &&
              run("ip link set dev " + name + " up"));
  EXPECT_NE(a->send(frame(5, 8)), SendResult::kOk);
  const Status ra = a->reopen();
  ASSERT_TRUE(ra.ok()) << ra.message();
  const Status rb = b->reopen();
  ASSERT_TRUE(rb.ok()) << rb.message();
  ASSERT_EQ(a->send(frame(6, 64, true)), SendResult::kOk);
  ASSERT_EQ(b->receive(r, 2s), ReceiveStatus::kFrame);
  EXPECT_EQ(r.frame.id, tagged(6));
  EXPECT_EQ(r.frame.length, 64U);
  EXPECT_GE(a->counters().interface_down_events, 2U);
  EXPECT_GE(b->counters().interface_down_events, 2U);
}

}  // namespace
}  // namespace pmsm::hal
