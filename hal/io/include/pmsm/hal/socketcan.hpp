// SocketCAN backend: one CAN_RAW socket bound to one interface (can0, vcan0, ...), set up
// in the order can-utils uses (candump.c / cansend.c / lib.c):
//   socket(PF_CAN, SOCK_RAW, CAN_RAW) -> interface index by name -> SIOCGIFMTU check
//   before CAN_RAW_FD_FRAMES -> CAN_RAW_FILTER / CAN_RAW_ERR_FILTER -> SO_RXQ_OVFL ->
//   SO_TIMESTAMPING -> bind.
// Raw CAN sockets need no capability; creating or configuring the interface does, and is
// not this class's job (systemd-networkd .netdev, or scripts/vcan-env for tests).
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "pmsm/hal/can_bus.hpp"
#include "pmsm/hal/unique_fd.hpp"

struct msghdr;

namespace pmsm::hal {

struct SocketCanConfig {
  std::string interface = "vcan0";
  bool fd = false;  // enable CAN FD frames; the interface must have MTU 72 (CANFD_MTU)
  // Receive filters (empty optional: every data frame; empty list: none).
  std::optional<std::vector<CanFilter>> filters{};
  std::uint32_t error_mask = 0;  // CanErrorClass bits of error frames to receive
  // Socket receive buffer in bytes (SO_RCVBUFFORCE with CAP_NET_ADMIN, else SO_RCVBUF, which
  // the kernel caps at net.core.rmem_max); 0 keeps the kernel default.
  int receive_buffer_bytes = 0;
  // Set up an io_uring for send_and_receive() (a lockstep period's send and wait in one system
  // call) where the kernel allows it (exchanges_in_one_call() says whether it did); off, that
  // call makes a send and a receive.
  bool io_uring = false;
};

class SocketCanBus final : public CanBus {
 public:
  // Opens the socket. Throws HalError with a message naming the interface and the errno
  // text, e.g.
  //   "this kernel has no CAN support (socket(PF_CAN) failed: Address family not supported
  //    by protocol); run under scripts/vcan-env"
  //   "no such CAN interface 'can0'"
  //   "CAN FD requested on 'vcan0' but its MTU is 16 (classic CAN only); set it with
  //    'ip link set vcan0 mtu 72'"
  explicit SocketCanBus(SocketCanConfig config);
  // Non-throwing form: the bus, or nullptr and `error` filled in.
  [[nodiscard]] static std::unique_ptr<SocketCanBus> open(SocketCanConfig config, Status& error);

  ~SocketCanBus() override;
  SocketCanBus(SocketCanBus&&) = delete;  // the counters are shared with reader threads
  SocketCanBus& operator=(SocketCanBus&&) = delete;

  Status set_filters(std::span<const CanFilter> filters) override;
  // Back to "every data frame" (the kernel default).
  Status accept_all_frames();
  Status set_error_mask(std::uint32_t error_classes) override;
  Status reopen() override;

  [[nodiscard]] CanBusCounters counters() const noexcept override;
  [[nodiscard]] CanBusState state() const noexcept override;
  [[nodiscard]] bool interface_up() const noexcept override;
  [[nodiscard]] bool fd_enabled() const noexcept override { return config_.fd; }
  // Whether send_and_receive() is one io_uring_enter: the kernel has io_uring with the
  // features it needs (5.17: a send's success without a completion; 5.11: a wait with a
  // timeout), and neither seccomp nor kernel.io_uring_disabled refused the ring.
  [[nodiscard]] bool exchanges_in_one_call() const noexcept override { return ring_ != nullptr && !ring_failed_; }

  [[nodiscard]] const std::string& interface_name() const noexcept { return config_.interface; }
  [[nodiscard]] int interface_index() const noexcept { return ifindex_; }
  // The socket's receive buffer as granted, comparable with receive_buffer_bytes (the kernel's
  // figure halved); 0 when it could not be read.
  [[nodiscard]] int receive_buffer_granted_bytes() const noexcept { return receive_buffer_granted_bytes_; }
  // errno of the last failed send/receive (0 if none yet). Read it on the I/O thread.
  [[nodiscard]] int last_error_number() const noexcept { return last_errno_; }
  // The socket, e.g. to wait on it together with other descriptors. Do not close it.
  [[nodiscard]] int native_handle() const noexcept { return fd_.get(); }

 protected:
  SendResult do_send(const CanFrame& frame, std::chrono::nanoseconds max_wait) noexcept override;
  SendResult do_send_before(const CanFrame& frame, std::int64_t deadline_ns) noexcept override;
  // Sends, waiting for room until `deadline_ns` on the monotonic clock, or (deadline 0) for
  // max_wait from the first refusal on; neither: no wait.
  SendResult send_until(const CanFrame& frame, std::chrono::nanoseconds max_wait, std::int64_t deadline_ns) noexcept;
  ReceiveStatus do_receive(ReceivedFrame& out, std::chrono::nanoseconds timeout) noexcept override;
  ReceiveStatus do_receive_backstop(ReceivedFrame& out, std::chrono::nanoseconds timeout) noexcept override;
  ExchangeResult do_send_and_receive(const CanFrame* frame, std::int64_t send_deadline_ns, ReceivedFrame& out,
                                     std::int64_t now_ns, std::int64_t receive_deadline_ns) noexcept override;

 private:
  struct Ring;  // the io_uring and the buffers its operations use (socketcan.cpp)
  struct AtomicCounters {
    std::atomic<std::uint64_t> tx_frames{0};
    std::atomic<std::uint64_t> rx_frames{0};
    std::atomic<std::uint64_t> tx_dropped_enobufs{0};
    std::atomic<std::uint64_t> tx_would_block{0};
    std::atomic<std::uint64_t> tx_errors{0};
    std::atomic<std::uint64_t> rx_overflow{0};
    std::atomic<std::uint64_t> rx_errors{0};
    std::atomic<std::uint64_t> error_frames{0};
    std::atomic<std::uint64_t> bad_size_reads{0};
    std::atomic<std::uint64_t> bus_off_events{0};
    std::atomic<std::uint64_t> interface_down_events{0};
  };

  Status open_socket();
  Status apply_filters();
  Status apply_error_mask();
  ReceiveStatus read_one(ReceivedFrame& out, bool block = false) noexcept;
  // A read's outcome: `n` bytes into `buffer` with `msg`'s control messages, or (n < 0) the
  // error `error_number`.
  ReceiveStatus finish_read(long n, int error_number, ::msghdr& msg, const std::uint8_t* buffer,
                            ReceivedFrame& out) noexcept;

  SocketCanConfig config_;
  UniqueFd fd_;
  int ifindex_ = 0;
  int receive_buffer_granted_bytes_ = 0;
  int last_errno_ = 0;
  std::uint32_t last_drop_count_ = 0;  // SO_RXQ_OVFL's running count on this socket
  bool last_receive_waited_ = false;   // the previous receive() found no frame queued
  std::int64_t receive_timeout_ns_ = 0; // SO_RCVTIMEO as last set (0: none, reads block)
  std::atomic<CanBusState> state_{CanBusState::kErrorActive};
  AtomicCounters counters_;
  std::unique_ptr<Ring> ring_;  // null: no io_uring here, send_and_receive() makes two calls
  bool ring_failed_ = false;    // the ring failed a call: parked (a read may be in flight), not used
};

// Why `name` cannot name a network interface, or "" when it can: the kernel's rule
// (dev_valid_name: 1 to 15 characters, not "." or "..", no '/', ':' or white space) and no
// control character (common/can_interface_name.hpp). For configuration checks, so that a bad
// name is refused with the key that gave it before any socket is opened.
[[nodiscard]] std::string can_interface_name_problem(std::string_view name);

// Converts between CanFrame and the kernel's frame layout; exposed for unit tests.
namespace socketcan_detail {
inline constexpr std::size_t kClassicMtu = 16;  // sizeof(struct can_frame)
inline constexpr std::size_t kFdMtu = 72;       // sizeof(struct canfd_frame)
// Fills `bytes` (at least kFdMtu long) with the kernel image of `frame`; returns its size
// (kClassicMtu or kFdMtu).
[[nodiscard]] std::size_t encode(const CanFrame& frame, std::span<std::uint8_t, kFdMtu> bytes) noexcept;
// Decodes a read of `size` bytes; false if the size is neither CAN_MTU nor CANFD_MTU or
// the length field is out of range.
[[nodiscard]] bool decode(std::span<const std::uint8_t> bytes, CanFrame& frame) noexcept;
}  // namespace socketcan_detail

}  // namespace pmsm::hal
