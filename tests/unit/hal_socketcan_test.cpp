// SocketCanBus on whatever kernel runs the unit tests: this machine's has no CAN at all,
// others have it. Either way, opening must fail with a clear message, never crash.
#include "pmsm/hal/socketcan.hpp"

#include <gtest/gtest.h>

#include <cerrno>
#include <string>

namespace pmsm::hal {
namespace {

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

void expect_clear_open_error(const std::string& message, int error_number, const std::string& interface) {
  if (error_number == EAFNOSUPPORT) {
    // A kernel without CAN: say so and point at the way out.
    EXPECT_TRUE(contains(message, "no CAN support")) << message;
    EXPECT_TRUE(contains(message, "scripts/vcan-env")) << message;
    EXPECT_TRUE(contains(message, "cannot open CAN interface '" + interface + "'")) << message;
  } else {
    // A kernel with CAN: the interface does not exist.
    EXPECT_EQ(error_number, ENODEV) << message;
    EXPECT_TRUE(contains(message, "no such CAN interface '" + interface + "'")) << message;
  }
}

// The kernel's rule for interface names, told before any socket is opened (the daemon's and
// the plant's configuration checks use it).
TEST(SocketCan, InterfaceNamesFollowTheKernelsRule) {
  for (const char* good : {"vcan0", "can0", "c", "can-axis_1.2", "abcdefghijklmno"}) {
    EXPECT_EQ(can_interface_name_problem(good), "") << good;
  }
  EXPECT_TRUE(contains(can_interface_name_problem(""), "got an empty one"));
  EXPECT_TRUE(contains(can_interface_name_problem("abcdefghijklmnop"), "got 16 in 'abcdefghijklmnop'"));
  EXPECT_TRUE(contains(can_interface_name_problem(std::string_view("vcan0\0x", 7)), "no control characters (a NUL would end it early), got 'vcan0\\x00x'"));
  EXPECT_TRUE(contains(can_interface_name_problem(".."), "is not an interface name"));
  for (const char* bad : {"can/0", "can:0", "can 0", "can\t0"}) {
    EXPECT_TRUE(contains(can_interface_name_problem(bad), "no '/', ':' or white space")) << bad;
  }
  // The name is quoted with its control characters escaped (a terminal escape in a configured
  // name went raw into the message), whichever rule refused it.
  EXPECT_TRUE(contains(can_interface_name_problem("a/\x1b[2J"), "got 'a/\\x1b[2J'"));
  EXPECT_TRUE(contains(can_interface_name_problem("abcdefghijklmno\x1b"), "got 16 in 'abcdefghijklmno\\x1b'"));
}

TEST(SocketCan, OpeningAMissingInterfaceIsAClearError) {
  const std::string name = "pmsmnosuch7";
  try {
    SocketCanBus bus{SocketCanConfig{.interface = name, .fd = true}};
    FAIL() << "opening '" << name << "' should have failed";
  } catch (const HalError& e) {
    expect_clear_open_error(e.what(), e.error_number(), name);
  }
}

TEST(SocketCan, NonThrowingOpenReportsTheSameError) {
  const std::string name = "pmsmnosuch8";
  Status status;
  auto bus = SocketCanBus::open(SocketCanConfig{.interface = name}, status);
  EXPECT_EQ(bus, nullptr);
  ASSERT_FALSE(status.ok());
  expect_clear_open_error(status.message(), status.error_number(), name);
}

TEST(SocketCan, EncodeDecodeClassicFrame) {
  CanFrame f;
  f.id = 0x1ABC'DEF0;
  f.extended = true;
  f.length = 5;
  f.data = {1, 2, 3, 4, 5};
  std::array<std::uint8_t, socketcan_detail::kFdMtu> bytes{};
  ASSERT_EQ(socketcan_detail::encode(f, bytes), socketcan_detail::kClassicMtu);
  CanFrame back;
  ASSERT_TRUE(socketcan_detail::decode(std::span{bytes.data(), socketcan_detail::kClassicMtu}, back));
  EXPECT_EQ(back.id, f.id);
  EXPECT_TRUE(back.extended);
  EXPECT_FALSE(back.fd);
  EXPECT_EQ(back.length, 5U);
  EXPECT_EQ(back.data, f.data);
}

TEST(SocketCan, EncodeDecodeFdFrameWithBitrateSwitch) {
  CanFrame f;
  f.id = 0x7FF;
  f.fd = true;
  f.bitrate_switch = true;
  f.length = 48;
  for (std::size_t i = 0; i < 48; ++i) {
    f.data[i] = static_cast<std::uint8_t>(i * 3U);
  }
  std::array<std::uint8_t, socketcan_detail::kFdMtu> bytes{};
  ASSERT_EQ(socketcan_detail::encode(f, bytes), socketcan_detail::kFdMtu);
  CanFrame back;
  ASSERT_TRUE(socketcan_detail::decode(bytes, back));
  EXPECT_EQ(back.id, 0x7FFU);
  EXPECT_FALSE(back.extended);
  EXPECT_TRUE(back.fd);
  EXPECT_TRUE(back.bitrate_switch);
  EXPECT_EQ(back.length, 48U);
  EXPECT_EQ(back.data, f.data);
}

TEST(SocketCan, DecodeRejectsEverySizeButCanMtuAndCanFdMtu) {
  std::array<std::uint8_t, 80> bytes{};
  CanFrame f;
  for (std::size_t size = 0; size <= bytes.size(); ++size) {
    const bool ok = socketcan_detail::decode(std::span{bytes.data(), size}, f);
    EXPECT_EQ(ok, size == 16 || size == 72) << "size " << size;
  }
  // A length field beyond the frame type's limit is malformed too.
  bytes[4] = 9;
  EXPECT_FALSE(socketcan_detail::decode(std::span{bytes.data(), 16}, f));
  EXPECT_FALSE(socketcan_detail::decode(std::span{bytes.data(), 72}, f));  // 9 is no FD length
  bytes[4] = 12;
  EXPECT_TRUE(socketcan_detail::decode(std::span{bytes.data(), 72}, f));
}

TEST(SocketCan, ErrorFramesKeepTheirClassBits) {
  CanFrame f;
  f.error = true;
  f.id = kCanErrBusOff | kCanErrController;
  f.length = 8;
  f.data[1] = kCanCtrlTxPassive;
  std::array<std::uint8_t, socketcan_detail::kFdMtu> bytes{};
  ASSERT_EQ(socketcan_detail::encode(f, bytes), socketcan_detail::kClassicMtu);
  CanFrame back;
  ASSERT_TRUE(socketcan_detail::decode(std::span{bytes.data(), socketcan_detail::kClassicMtu}, back));
  EXPECT_TRUE(back.error);
  EXPECT_FALSE(back.extended);
  EXPECT_EQ(back.id, f.id);
  EXPECT_EQ(state_after_error_frame(back, CanBusState::kErrorActive), CanBusState::kBusOff);
}

TEST(SocketCan, StateFollowsControllerErrorFrames) {
  CanFrame f;
  f.error = true;
  f.id = kCanErrController;
  f.length = 8;
  f.data[1] = kCanCtrlRxWarning;
  EXPECT_EQ(state_after_error_frame(f, CanBusState::kErrorActive), CanBusState::kErrorWarning);
  f.data[1] = kCanCtrlRxPassive;
  EXPECT_EQ(state_after_error_frame(f, CanBusState::kErrorWarning), CanBusState::kErrorPassive);
  f.data[1] = kCanCtrlActive;
  EXPECT_EQ(state_after_error_frame(f, CanBusState::kErrorPassive), CanBusState::kErrorActive);
  f.data[1] = kCanCtrlRxOverflow;  // no state information
  EXPECT_EQ(state_after_error_frame(f, CanBusState::kErrorPassive), CanBusState::kErrorPassive);
  CanFrame data_frame;
  EXPECT_EQ(state_after_error_frame(data_frame, CanBusState::kBusOff), CanBusState::kBusOff);
}

TEST(SocketCan, SendableChecksLimits) {
  CanFrame f;
  f.length = 8;
  EXPECT_TRUE(is_sendable(f, false));
  f.bitrate_switch = true;
  EXPECT_FALSE(is_sendable(f, true));  // BRS only exists on FD frames
  f.fd = true;
  EXPECT_FALSE(is_sendable(f, false));
  EXPECT_TRUE(is_sendable(f, true));
  f.length = 64;
  EXPECT_TRUE(is_sendable(f, true));
  f.length = 65;
  EXPECT_FALSE(is_sendable(f, true));
  f.length = 20;
  EXPECT_TRUE(is_sendable(f, true));
  f.length = 21;
  EXPECT_FALSE(is_sendable(f, true));
}

}  // namespace
}  // namespace pmsm::hal
