#include "pmsm/hal/sim_bus.hpp"

#include <gtest/gtest.h>

#include <array>
#include <chrono>
#include <cstdint>
#include <string>
#include <thread>
#include <vector>

#include "pmsm/hal/rt.hpp"  // monotonic_ns

namespace pmsm::hal {
namespace {

using namespace std::chrono_literals;

CanFrame classic(std::uint32_t id, std::uint8_t length, bool extended = false) {
  CanFrame f;
  f.id = id;
  f.extended = extended;
  f.length = length;
  for (std::uint8_t i = 0; i < length; ++i) {
    f.data[i] = static_cast<std::uint8_t>(id + i);
  }
  return f;
}

CanFrame fd_frame(std::uint32_t id, std::uint8_t length) {
  CanFrame f = classic(id, 0);
  f.fd = true;
  f.bitrate_switch = true;
  f.length = length;
  for (std::uint8_t i = 0; i < length; ++i) {
    f.data[i] = static_cast<std::uint8_t>(0xA0U + i);
  }
  return f;
}

// Everything `bus` holds now (zero timeout), as identifiers.
std::vector<std::uint32_t> drain_ids(CanBus& bus) {
  std::vector<std::uint32_t> ids;
  ReceivedFrame r;
  while (bus.receive(r, 0ns) == ReceiveStatus::kFrame) {
    ids.push_back(r.frame.id);
  }
  return ids;
}

TEST(SimBus, DeliversToEveryOtherEndpointButNotTheSender) {
  SimBus bus;
  auto a = bus.connect();
  auto b = bus.connect();
  auto c = bus.connect();
  const CanFrame sent = classic(0x123, 8);
  ASSERT_EQ(a->send(sent), SendResult::kOk);

  for (CanBus* rx : {b.get(), c.get()}) {
    ReceivedFrame r;
    ASSERT_EQ(rx->receive(r, 100ms), ReceiveStatus::kFrame);
    EXPECT_EQ(r.frame.id, 0x123U);
    EXPECT_EQ(r.frame.length, 8U);
    EXPECT_EQ(r.frame.data, sent.data);
    EXPECT_FALSE(r.frame.fd);
    EXPECT_GT(r.timestamp_ns, 0);
  }
  ReceivedFrame r;
  EXPECT_EQ(a->receive(r, 0ns), ReceiveStatus::kTimeout);
  EXPECT_EQ(a->counters().tx_frames, 1U);
  EXPECT_EQ(b->counters().rx_frames, 1U);
  EXPECT_EQ(bus.frames_sent(), 1U);
}

TEST(SimBus, ReceiveTimesOutWhenNothingArrives) {
  SimBus bus;
  auto a = bus.connect();
  ReceivedFrame r;
  const auto t0 = std::chrono::steady_clock::now();
  EXPECT_EQ(a->receive(r, 20ms), ReceiveStatus::kTimeout);
  EXPECT_GE(std::chrono::steady_clock::now() - t0, 19ms);
}

// send_and_receive() where the backend has no one-call form: a send, then a receive until the
// deadline; a refused send is told and the wait still happens; no frame to send, only the wait.
TEST(SimBus, SendAndReceiveIsASendThenAReceiveUntilTheDeadline) {
  SimBus bus;
  auto a = bus.connect();
  auto b = bus.connect();
  EXPECT_FALSE(a->exchanges_in_one_call());
  ReceivedFrame r;
  ASSERT_EQ(b->send(classic(0x222, 2)), SendResult::kOk);  // already queued for a
  std::int64_t now = monotonic_ns();
  ExchangeResult x = a->send_and_receive(nullptr, 0, r, now, now + 1'000'000'000);
  EXPECT_EQ(x.sent, SendResult::kOk);
  ASSERT_EQ(x.received, ReceiveStatus::kFrame);
  EXPECT_EQ(r.frame.id, 0x222U);

  const CanFrame out = classic(0x111, 8);
  now = monotonic_ns();
  x = a->send_and_receive(&out, now + 100'000, r, now, now + 20'000'000);
  EXPECT_EQ(x.sent, SendResult::kOk);
  EXPECT_EQ(x.received, ReceiveStatus::kTimeout);
  EXPECT_GE(monotonic_ns() - now, 19'000'000);
  ASSERT_EQ(b->receive(r, 0ns), ReceiveStatus::kFrame);
  EXPECT_EQ(r.frame.id, 0x111U);

  CanFrame bad = classic(0x111, 8);
  bad.id = 0x800;  // beyond 11 bits
  ASSERT_EQ(b->send(classic(0x333, 1)), SendResult::kOk);
  now = monotonic_ns();
  x = a->send_and_receive(&bad, now + 100'000, r, now, now + 1'000'000'000);
  EXPECT_EQ(x.sent, SendResult::kInvalidFrame);
  ASSERT_EQ(x.received, ReceiveStatus::kFrame);
  EXPECT_EQ(r.frame.id, 0x333U);
  EXPECT_EQ(a->counters().tx_frames, 1U);
  EXPECT_EQ(a->counters().tx_errors, 1U);
}

TEST(SimBus, FiltersSelectByIdMaskAndKind) {
  SimBus bus;
  auto tx = bus.connect();
  auto rx = bus.connect();
  const std::array filters{
      CanFilter::exact(0x100, false),                      // standard 0x100 only
      CanFilter{0x1234'0010, 0x1FFF'FFF0, CanIdKind::kExtended},  // extended 0x12340010..1F
  };
  ASSERT_TRUE(rx->set_filters(filters).ok());

  ASSERT_EQ(tx->send(classic(0x100, 1)), SendResult::kOk);              // pass
  ASSERT_EQ(tx->send(classic(0x101, 1)), SendResult::kOk);              // wrong id
  ASSERT_EQ(tx->send(classic(0x100, 1, true)), SendResult::kOk);        // extended 0x100: wrong kind
  ASSERT_EQ(tx->send(classic(0x1234'0015, 1, true)), SendResult::kOk);  // pass
  ASSERT_EQ(tx->send(classic(0x1234'0025, 1, true)), SendResult::kOk);  // outside the mask
  EXPECT_EQ(drain_ids(*rx), (std::vector<std::uint32_t>{0x100, 0x1234'0015}));

  // kAny matches both kinds on the numeric identifier.
  const CanFilter any{0x7F, 0x7FF, CanIdKind::kAny};
  ASSERT_TRUE(rx->set_filters(std::span{&any, 1}).ok());
  ASSERT_EQ(tx->send(classic(0x7F, 0)), SendResult::kOk);
  ASSERT_EQ(tx->send(classic(0x7F, 0, true)), SendResult::kOk);
  ASSERT_EQ(tx->send(classic(0x7E, 0)), SendResult::kOk);
  EXPECT_EQ(drain_ids(*rx).size(), 2U);

  // An empty list passes nothing; accept_all passes everything.
  ASSERT_TRUE(rx->set_filters({}).ok());
  ASSERT_EQ(tx->send(classic(0x100, 1)), SendResult::kOk);
  EXPECT_TRUE(drain_ids(*rx).empty());
  const CanFilter all = CanFilter::accept_all();
  ASSERT_TRUE(rx->set_filters(std::span{&all, 1}).ok());
  ASSERT_EQ(tx->send(classic(0x555, 1)), SendResult::kOk);
  ASSERT_EQ(tx->send(classic(0x1555'5555, 1, true)), SendResult::kOk);
  EXPECT_EQ(drain_ids(*rx).size(), 2U);
}

TEST(SimBus, FdFramesOnlyBetweenFdEndpoints) {
  SimBus bus;
  auto fd_tx = bus.connect({.fd = true});
  auto fd_rx = bus.connect({.fd = true});
  auto classic_rx = bus.connect({.fd = false});

  ASSERT_EQ(fd_tx->send(fd_frame(0x200, 64)), SendResult::kOk);
  ASSERT_EQ(fd_tx->send(classic(0x201, 8)), SendResult::kOk);  // an FD endpoint may send classic frames

  ReceivedFrame r;
  ASSERT_EQ(fd_rx->receive(r, 100ms), ReceiveStatus::kFrame);
  EXPECT_TRUE(r.frame.fd);
  EXPECT_TRUE(r.frame.bitrate_switch);
  EXPECT_EQ(r.frame.length, 64U);
  EXPECT_EQ(r.frame.data[63], 0xA0U + 63U);
  ASSERT_EQ(fd_rx->receive(r, 100ms), ReceiveStatus::kFrame);
  EXPECT_FALSE(r.frame.fd);

  EXPECT_EQ(drain_ids(*classic_rx), (std::vector<std::uint32_t>{0x201}));

  // A classic endpoint cannot send FD frames; nobody can send malformed ones.
  EXPECT_EQ(classic_rx->send(fd_frame(0x202, 12)), SendResult::kInvalidFrame);
  EXPECT_EQ(fd_tx->send(fd_frame(0x203, 9)), SendResult::kInvalidFrame);   // 9 is not an FD length
  EXPECT_EQ(fd_tx->send(classic(0x204, 9)), SendResult::kInvalidFrame);    // classic max is 8
  EXPECT_EQ(fd_tx->send(classic(0x800, 1)), SendResult::kInvalidFrame);    // 12-bit standard id
  EXPECT_EQ(fd_tx->send(classic(0x2000'0000, 1, true)), SendResult::kInvalidFrame);
  EXPECT_EQ(classic_rx->counters().tx_errors, 1U);
  EXPECT_EQ(fd_tx->counters().tx_errors, 4U);
}

TEST(SimBus, ClassicOnlyBusRefusesFdEndpointsClearly) {
  SimBus bus{{.fd_capable = false}};
  try {
    (void)bus.connect({.fd = true});
    FAIL() << "expected HalError";
  } catch (const HalError& e) {
    EXPECT_NE(std::string{e.what()}.find("CAN FD"), std::string::npos) << e.what();
  }
  EXPECT_NO_THROW((void)bus.connect({.fd = false}));
  EXPECT_THROW((void)bus.connect({.fd = false, .queue_capacity = 0}), HalError);
}

TEST(SimBus, FullQueueDropsAndCountsOverflow) {
  SimBus bus;
  auto tx = bus.connect();
  auto rx = bus.connect({.fd = false, .queue_capacity = 4});
  for (std::uint32_t i = 0; i < 10; ++i) {
    ASSERT_EQ(tx->send(classic(0x300 + i, 1)), SendResult::kOk);
  }
  // The first four stay queued (oldest first), the other six are lost and counted.
  EXPECT_EQ(drain_ids(*rx), (std::vector<std::uint32_t>{0x300, 0x301, 0x302, 0x303}));
  const CanBusCounters c = rx->counters();
  EXPECT_EQ(c.rx_overflow, 6U);
  EXPECT_EQ(c.rx_frames, 4U);
  EXPECT_EQ(tx->counters().tx_frames, 10U);
}

TEST(SimBus, ErrorFramesFollowTheErrorMaskAndSetTheState) {
  SimBus bus;
  auto watcher = bus.connect();
  auto deaf = bus.connect();
  ASSERT_TRUE(watcher->set_error_mask(kCanErrBusOff | kCanErrController | kCanErrRestarted).ok());
  EXPECT_EQ(watcher->state(), CanBusState::kErrorActive);

  bus.inject_error_frame(make_error_frame(CanBusState::kErrorPassive));
  ReceivedFrame r;
  ASSERT_EQ(watcher->receive(r, 100ms), ReceiveStatus::kFrame);
  EXPECT_TRUE(r.frame.error);
  EXPECT_EQ(watcher->state(), CanBusState::kErrorPassive);

  bus.inject_error_frame(make_error_frame(CanBusState::kBusOff));
  ASSERT_EQ(watcher->receive(r, 100ms), ReceiveStatus::kFrame);
  EXPECT_EQ(watcher->state(), CanBusState::kBusOff);
  EXPECT_STREQ(to_string(watcher->state()), "bus-off");

  CanFrame restarted;
  restarted.error = true;
  restarted.id = kCanErrRestarted;
  restarted.length = 8;
  bus.inject_error_frame(restarted);
  ASSERT_EQ(watcher->receive(r, 100ms), ReceiveStatus::kFrame);
  EXPECT_EQ(watcher->state(), CanBusState::kErrorActive);

  const CanBusCounters c = watcher->counters();
  EXPECT_EQ(c.error_frames, 3U);
  EXPECT_EQ(c.bus_off_events, 1U);
  EXPECT_EQ(c.rx_frames, 0U);
  // No error mask, no error frames.
  EXPECT_EQ(deaf->receive(r, 0ns), ReceiveStatus::kTimeout);
  EXPECT_EQ(deaf->state(), CanBusState::kErrorActive);
}

TEST(SimBus, InterfaceDownFailsSendsAndWakesBlockedReaders) {
  SimBus bus;
  auto a = bus.connect();
  auto b = bus.connect();
  EXPECT_TRUE(a->interface_up());

  ReceiveStatus blocked_result = ReceiveStatus::kFrame;
  std::thread reader{[&] {
    ReceivedFrame r;
    blocked_result = b->receive(r, -1ns);  // waits forever unless the link drops
  }};
  std::this_thread::sleep_for(20ms);
  bus.set_interface_up(false);
  reader.join();
  EXPECT_EQ(blocked_result, ReceiveStatus::kInterfaceDown);
  EXPECT_FALSE(a->interface_up());
  EXPECT_EQ(a->send(classic(0x10, 1)), SendResult::kInterfaceDown);
  EXPECT_EQ(a->counters().interface_down_events, 1U);

  bus.set_interface_up(true);
  ASSERT_TRUE(a->reopen().ok());
  ASSERT_TRUE(b->reopen().ok());
  ASSERT_EQ(a->send(classic(0x10, 1)), SendResult::kOk);
  ReceivedFrame r;
  EXPECT_EQ(b->receive(r, 100ms), ReceiveStatus::kFrame);
}

// A plant thread and a controller thread in lockstep over the simulated bus.
TEST(SimBus, PlantAndControllerThreadsPingPong) {
  constexpr std::uint32_t kExchanges = 20'000;
  SimBus bus;
  auto plant = bus.connect({.fd = true});
  auto controller = bus.connect({.fd = true});
  const CanFilter sensor = CanFilter::exact(0x10, false);
  const CanFilter command = CanFilter::exact(0x20, false);
  ASSERT_TRUE(controller->set_filters(std::span{&sensor, 1}).ok());
  ASSERT_TRUE(plant->set_filters(std::span{&command, 1}).ok());

  std::uint32_t controller_errors = 0;
  std::thread controller_thread{[&] {
    for (std::uint32_t k = 0; k < kExchanges; ++k) {
      ReceivedFrame r;
      if (controller->receive(r, 2s) != ReceiveStatus::kFrame || r.frame.data[0] != static_cast<std::uint8_t>(k)) {
        ++controller_errors;
        return;
      }
      CanFrame reply = fd_frame(0x20, 16);
      reply.data[0] = r.frame.data[0];
      if (controller->send(reply) != SendResult::kOk) {
        ++controller_errors;
        return;
      }
    }
  }};
  std::uint32_t plant_errors = 0;
  for (std::uint32_t k = 0; k < kExchanges; ++k) {
    CanFrame sample = fd_frame(0x10, 32);
    sample.data[0] = static_cast<std::uint8_t>(k);
    ASSERT_EQ(plant->send(sample), SendResult::kOk);
    ReceivedFrame r;
    if (plant->receive(r, 2s) != ReceiveStatus::kFrame || r.frame.data[0] != static_cast<std::uint8_t>(k)) {
      ++plant_errors;
      break;
    }
  }
  controller_thread.join();
  EXPECT_EQ(plant_errors, 0U);
  EXPECT_EQ(controller_errors, 0U);
  EXPECT_EQ(plant->counters().rx_frames, kExchanges);
  EXPECT_EQ(controller->counters().rx_overflow, 0U);
}

TEST(SimBus, EndpointsMayOutliveTheBusObject) {
  std::unique_ptr<CanBus> a;
  std::unique_ptr<CanBus> b;
  {
    SimBus bus;
    a = bus.connect();
    b = bus.connect();
  }
  ASSERT_EQ(a->send(classic(0x1, 1)), SendResult::kOk);
  ReceivedFrame r;
  EXPECT_EQ(b->receive(r, 100ms), ReceiveStatus::kFrame);
}

}  // namespace
}  // namespace pmsm::hal
