// The CAN bus as the daemon and the plant see it: one endpoint on one bus.
//
// Backends: SocketCanBus (socketcan.hpp, a CAN_RAW socket on can0 / vcan0) and
// SimBusEndpoint (sim_bus.hpp, in-process, for fast tests). Both follow the SocketCAN
// semantics, so that a test on the simulated bus means the same on vcan:
//   - an endpoint does not receive its own frames; every other endpoint does (loopback on,
//     CAN_RAW_RECV_OWN_MSGS off);
//   - an endpoint opened without CAN FD neither sends nor receives FD frames;
//   - receive filters are {id, mask} pairs, a frame passes if any filter matches; an
//     empty list passes no data frame; the default (before set_filters) passes all;
//   - error frames reach an endpoint only if its error mask selects their class (default:
//     none), and they arrive through receive() with CanFrame::error set, after the endpoint
//     has updated its state() and counters from them.
//
// Threading: one thread does send/receive/set_*/reopen on an endpoint (the RT thread);
// counters(), state() and interface_up() may be read from any thread.
#pragma once

#include <algorithm>
#include <atomic>
#include <chrono>
#include <thread>
#include <cstdint>
#include <span>

#include "pmsm/hal/can_frame.hpp"
#include "pmsm/hal/status.hpp"

namespace pmsm::hal {

// Classes of error frames (the values are linux/can/error.h's CAN_ERR_* class bits, which
// are also the bits of CanFrame::id of an error frame).
enum CanErrorClass : std::uint32_t {
  kCanErrTxTimeout = 0x001,
  kCanErrLostArbitration = 0x002,
  kCanErrController = 0x004,   // data[1]: warning / passive / active, rx/tx overflow
  kCanErrProtocol = 0x008,
  kCanErrTransceiver = 0x010,
  kCanErrNoAck = 0x020,
  kCanErrBusOff = 0x040,
  kCanErrBusError = 0x080,     // may flood: select only when needed
  kCanErrRestarted = 0x100,    // the controller left bus-off
  kCanErrCounters = 0x200,
  kCanErrAll = 0x1FFF'FFFF,
};

// Bits of data[1] of a kCanErrController error frame (CAN_ERR_CRTL_*).
enum CanControllerError : std::uint8_t {
  kCanCtrlRxOverflow = 0x01,
  kCanCtrlTxOverflow = 0x02,
  kCanCtrlRxWarning = 0x04,
  kCanCtrlTxWarning = 0x08,
  kCanCtrlRxPassive = 0x10,
  kCanCtrlTxPassive = 0x20,
  kCanCtrlActive = 0x40,
};

// The controller's fault-confinement state, as learnt from error frames. vcan never
// leaves kErrorActive by itself (error frames can be injected, see can-utils canerrsim).
enum class CanBusState : std::uint8_t { kErrorActive, kErrorWarning, kErrorPassive, kBusOff };

[[nodiscard]] const char* to_string(CanBusState state) noexcept;

enum class SendResult : std::uint8_t {
  kOk,
  kWouldBlock,      // the socket's send buffer is full (EAGAIN); frame not sent
  kNoBufferSpace,   // the device queue is full (ENOBUFS); frame dropped and counted
  kInterfaceDown,   // ENETDOWN / ENODEV / ENXIO: reconnect (reopen()) once it is back
  kInvalidFrame,    // identifier or length out of range, or FD frame on a classic endpoint
  kError,           // anything else (see the backend's last_error_number())
};

[[nodiscard]] const char* to_string(SendResult result) noexcept;

enum class ReceiveStatus : std::uint8_t {
  kFrame,          // `out` holds a frame (a data frame, or an error frame if error is set)
  kTimeout,        // nothing arrived before the timeout
  kInterfaceDown,  // ENETDOWN / ENODEV: reconnect once it is back
  kError,          // a failed or malformed read (counted in rx_errors / bad_size_reads)
};

[[nodiscard]] const char* to_string(ReceiveStatus status) noexcept;

struct ReceivedFrame {
  CanFrame frame;
  // Reception time, nanoseconds since the epoch (CLOCK_REALTIME: the kernel's software
  // receive timestamp for SocketCAN, the hardware one when the driver provides it).
  // 0 when the backend delivered none.
  std::int64_t timestamp_ns = 0;
  bool hardware_timestamp = false;
  // The kernel's software receive timestamp (CLOCK_REALTIME) also where timestamp_ns is a
  // hardware one (on the controller's own clock): what the host's clocks can be compared with.
  // 0 when the backend delivered none.
  std::int64_t software_timestamp_ns = 0;
  // How long the receive() call waited for this frame, by the kernel's own account of the
  // wait (SocketCanBus: ppoll's time left; SimBus: its clock around the wait): 0 when the frame
  // was queued already, -1 when the backend cannot tell (a wait a signal interrupted, one that
  // ran out as the frame came, a wait without a timeout, the backstop read, a 32-bit target).
  // A caller that read its clock just before the call knows, without reading it again, when
  // the frame was in hand: its reading plus this. (Under User-Mode Linux, as on any target
  // without a vDSO, every clock reading is a system call.) Not counted: a stop of the process
  // in the wait (SIGSTOP, a debugger attaching), after which the kernel restarts the wait with
  // the time left; a moment read this way is then early by the stop.
  std::int64_t waited_ns = -1;
};

// What send_and_receive() did: the send's result (kOk when there was nothing to send) and the
// receive's.
struct ExchangeResult {
  SendResult sent = SendResult::kOk;
  ReceiveStatus received = ReceiveStatus::kTimeout;
};

// Monotonic counts since the endpoint was created (reopen() keeps them).
struct CanBusCounters {
  std::uint64_t tx_frames = 0;           // frames handed to the kernel / bus
  std::uint64_t rx_frames = 0;           // data frames received
  std::uint64_t tx_dropped_enobufs = 0;  // frames dropped because the device queue was full
  std::uint64_t tx_would_block = 0;      // sends refused with EAGAIN
  std::uint64_t tx_errors = 0;           // other failed sends (incl. invalid frames, down)
  std::uint64_t rx_overflow = 0;         // frames the kernel dropped for this socket (SO_RXQ_OVFL) or the simulated queue overflowed
  std::uint64_t rx_errors = 0;           // failed reads
  std::uint64_t error_frames = 0;        // error frames received
  std::uint64_t bad_size_reads = 0;      // reads that were neither CAN_MTU nor CANFD_MTU bytes
  std::uint64_t bus_off_events = 0;      // error frames that reported bus-off
  std::uint64_t interface_down_events = 0; // sends/reads that failed with the interface down
};

class CanBus {
 public:
  CanBus() = default;
  virtual ~CanBus() = default;
  CanBus(const CanBus&) = delete;
  CanBus& operator=(const CanBus&) = delete;

  // Sends one frame without blocking. If the device queue is full (ENOBUFS) or the send
  // buffer is (EAGAIN), waits up to `max_wait` for room and retries; 0 (the default)
  // means no wait. A frame that still cannot be sent is dropped and counted.
  SendResult send(const CanFrame& frame,
                  std::chrono::nanoseconds max_wait = std::chrono::nanoseconds{0}) noexcept {
    return do_send(frame, max_wait);
  }

  // As send(), waiting for room at most until `deadline_ns` on the monotonic clock (a period's
  // end): the caller needs no clock reading of its own. SocketCanBus reads the clock only when
  // the queue is full; the default reads it first and calls send() with what is left.
  SendResult send_before(const CanFrame& frame, std::int64_t deadline_ns) noexcept {
    return do_send_before(frame, deadline_ns);
  }

  // Waits up to `timeout` for one frame (a negative timeout waits forever, zero polls).
  ReceiveStatus receive(ReceivedFrame& out, std::chrono::nanoseconds timeout) noexcept {
    return do_receive(out, timeout);
  }

  // As receive(), for a wait whose length is only a backstop (a lockstep re-send after tens of
  // milliseconds, not a deadline): the backend may round `timeout` up to its clock tick, and a
  // signal may end the wait early as a timeout, in exchange for a cheaper wait (SocketCanBus:
  // one blocking read with SO_RCVTIMEO, where receive() polls and then reads). `timeout` > 0.
  ReceiveStatus receive_backstop(ReceivedFrame& out, std::chrono::nanoseconds timeout) noexcept {
    return do_receive_backstop(out, timeout);
  }

  // A lockstep period's input and output in one call: sends `*frame` (unless null) as
  // send_before(*frame, send_deadline_ns) does, then waits for one frame as receive() does, until
  // `receive_deadline_ns` on the monotonic clock. `now_ns` is a reading of that clock the caller
  // took since its last wait (the first wait lasts receive_deadline_ns - now_ns; a wait that a
  // signal or a refused send cut short goes on to the deadline from a fresh reading).
  //   SocketCanBus does both in one system call where the kernel has io_uring (one
  // io_uring_enter: the send, the read and the wait; receive() costs a poll and a read besides a
  // send, and under User-Mode Linux every system call costs as much as a frame's trip); it then
  // cannot tell the wait's length (out.waited_ns -1): the frame's receive timestamp dates it.
  // Elsewhere, and for a deadline already past, the two calls.
  ExchangeResult send_and_receive(const CanFrame* frame, std::int64_t send_deadline_ns, ReceivedFrame& out,
                                  std::int64_t now_ns, std::int64_t receive_deadline_ns) noexcept {
    return do_send_and_receive(frame, send_deadline_ns, out, now_ns, receive_deadline_ns);
  }
  // Whether send_and_receive() takes one system call (SocketCanBus with io_uring), for the log.
  [[nodiscard]] virtual bool exchanges_in_one_call() const noexcept { return false; }

  // Replaces the kernel receive filters (CAN_RAW_FILTER). Not for the hot path.
  virtual Status set_filters(std::span<const CanFilter> filters) = 0;
  // Selects which error-frame classes (CanErrorClass bits) reach receive() (CAN_RAW_ERR_FILTER).
  virtual Status set_error_mask(std::uint32_t error_classes) = 0;

  // Closes and reopens the endpoint with the same configuration, filters and error mask,
  // e.g. after the interface was deleted and created again. Counters are kept.
  virtual Status reopen() = 0;

  [[nodiscard]] virtual CanBusCounters counters() const noexcept = 0;
  [[nodiscard]] virtual CanBusState state() const noexcept = 0;
  // Whether the interface is administratively up and running (SocketCanBus asks the kernel:
  // one ioctl, not for the hot path).
  [[nodiscard]] virtual bool interface_up() const noexcept = 0;
  [[nodiscard]] virtual bool fd_enabled() const noexcept = 0;

 protected:
  virtual SendResult do_send(const CanFrame& frame, std::chrono::nanoseconds max_wait) noexcept = 0;
  virtual SendResult do_send_before(const CanFrame& frame, std::int64_t deadline_ns) noexcept;
  virtual ReceiveStatus do_receive(ReceivedFrame& out, std::chrono::nanoseconds timeout) noexcept = 0;
  virtual ReceiveStatus do_receive_backstop(ReceivedFrame& out, std::chrono::nanoseconds timeout) noexcept {
    return do_receive(out, timeout);
  }
  // The two calls: the send, then a receive until the deadline (from a fresh reading of the clock
  // after a send, which may have waited for room).
  virtual ExchangeResult do_send_and_receive(const CanFrame* frame, std::int64_t send_deadline_ns,
                                             ReceivedFrame& out, std::int64_t now_ns,
                                             std::int64_t receive_deadline_ns) noexcept;
};

// Checks a frame against CAN / CAN FD limits (identifier range, length, FD lengths, no
// FD-only flags on classic frames). `fd_allowed`: whether FD frames may be sent.
[[nodiscard]] bool is_sendable(const CanFrame& frame, bool fd_allowed) noexcept;

// Whether a data frame passes a filter list (the kernel's rule, shared with SimBus).
[[nodiscard]] bool passes_filters(const CanFrame& frame, std::span<const CanFilter> filters) noexcept;

// The state an error frame reports, or `current` if it reports none.
[[nodiscard]] CanBusState state_after_error_frame(const CanFrame& error_frame,
                                                  CanBusState current) noexcept;

// After an interface loss: waits until `bus`'s interface is back and reopens the endpoint,
// trying every `interval`, in slices of at most `slice` so that `stop` is seen quickly and
// `on_slice()` runs after each (a daemon keeps its drive's time there; the plant just waits).
// Reopens even when the old binding might still work: after the interface was deleted and
// created again it would not, and reopening a working socket costs nothing. Returns true once
// reopened, false when stop became true. Not for the hot path: it sleeps.
template <typename OnSlice>
bool wait_and_reopen(CanBus& bus, std::chrono::nanoseconds interval, std::chrono::nanoseconds slice,
                     const std::atomic<bool>& stop, OnSlice on_slice) {
  slice = std::min(slice, interval);
  for (;;) {
    for (std::chrono::nanoseconds slept{0}; slept < interval; slept += slice) {
      if (stop.load(std::memory_order_relaxed)) {
        return false;
      }
      std::this_thread::sleep_for(slice);
      on_slice();
    }
    if (bus.interface_up() && bus.reopen().ok()) {
      return true;
    }
  }
}

}  // namespace pmsm::hal
