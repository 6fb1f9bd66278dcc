// Backend-independent CAN helpers: names, frame limits, the kernel's filter rule and the
// error-frame state machine, shared by SocketCanBus and SimBus so that both agree.
#include "pmsm/hal/can_bus.hpp"

#include <linux/can.h>
#include <linux/can/error.h>

#include <cstring>

#include "filter_rule.hpp"
#include "pmsm/hal/rt.hpp"
#include "pmsm/hal/status.hpp"

namespace pmsm::hal {

static_assert(kCanErrTxTimeout == CAN_ERR_TX_TIMEOUT && kCanErrLostArbitration == CAN_ERR_LOSTARB &&
              kCanErrController == CAN_ERR_CRTL && kCanErrProtocol == CAN_ERR_PROT &&
              kCanErrTransceiver == CAN_ERR_TRX && kCanErrNoAck == CAN_ERR_ACK &&
              kCanErrBusOff == CAN_ERR_BUSOFF && kCanErrBusError == CAN_ERR_BUSERROR &&
              kCanErrRestarted == CAN_ERR_RESTARTED && kCanErrCounters == CAN_ERR_CNT &&
              kCanErrAll == CAN_ERR_MASK);
static_assert(kCanCtrlRxOverflow == CAN_ERR_CRTL_RX_OVERFLOW &&
              kCanCtrlTxOverflow == CAN_ERR_CRTL_TX_OVERFLOW &&
              kCanCtrlRxWarning == CAN_ERR_CRTL_RX_WARNING &&
              kCanCtrlTxWarning == CAN_ERR_CRTL_TX_WARNING &&
              kCanCtrlRxPassive == CAN_ERR_CRTL_RX_PASSIVE &&
              kCanCtrlTxPassive == CAN_ERR_CRTL_TX_PASSIVE && kCanCtrlActive == CAN_ERR_CRTL_ACTIVE);
static_assert(kMaxStandardId == CAN_SFF_MASK && kMaxExtendedId == CAN_EFF_MASK);

std::string errno_text(int error_number) {
  char buffer[256] = {};
  // GNU strerror_r: returns a pointer to the text (in buffer or a static string).
  const char* text = strerror_r(error_number, buffer, sizeof buffer);
  return text != nullptr ? std::string{text} : std::string{"errno "} + std::to_string(error_number);
}

const char* to_string(CanBusState state) noexcept {
  switch (state) {
    case CanBusState::kErrorActive: return "error-active";
    case CanBusState::kErrorWarning: return "error-warning";
    case CanBusState::kErrorPassive: return "error-passive";
    case CanBusState::kBusOff: return "bus-off";
  }
  return "unknown";
}

const char* to_string(SendResult result) noexcept {
  switch (result) {
    case SendResult::kOk: return "ok";
    case SendResult::kWouldBlock: return "would block";
    case SendResult::kNoBufferSpace: return "no buffer space (ENOBUFS)";
    case SendResult::kInterfaceDown: return "interface down";
    case SendResult::kInvalidFrame: return "invalid frame";
    case SendResult::kError: return "error";
  }
  return "unknown";
}

const char* to_string(ReceiveStatus status) noexcept {
  switch (status) {
    case ReceiveStatus::kFrame: return "frame";
    case ReceiveStatus::kTimeout: return "timeout";
    case ReceiveStatus::kInterfaceDown: return "interface down";
    case ReceiveStatus::kError: return "error";
  }
  return "unknown";
}

bool is_sendable(const CanFrame& frame, bool fd_allowed) noexcept {
  if (frame.error) {
    // Error frames (only useful to inject them on vcan for tests) are classic frames whose
    // identifier carries the error classes.
    return !frame.fd && frame.id <= kMaxExtendedId && frame.length <= CanFrame::kMaxClassicLength;
  }
  const std::uint32_t max_id = frame.extended ? kMaxExtendedId : kMaxStandardId;
  if (frame.id > max_id) {
    return false;
  }
  if (frame.fd) {
    return fd_allowed && is_valid_fd_length(frame.length);
  }
  return !frame.bitrate_switch && frame.length <= CanFrame::kMaxClassicLength;
}

namespace detail {

KernelFilter to_kernel_filter(const CanFilter& filter) noexcept {
  KernelFilter k;
  switch (filter.kind) {
    case CanIdKind::kStandard:
      k.id = filter.id & CAN_SFF_MASK;
      k.mask = (filter.mask & CAN_SFF_MASK) | CAN_EFF_FLAG | CAN_RTR_FLAG;
      break;
    case CanIdKind::kExtended:
      k.id = (filter.id & CAN_EFF_MASK) | CAN_EFF_FLAG;
      k.mask = (filter.mask & CAN_EFF_MASK) | CAN_EFF_FLAG | CAN_RTR_FLAG;
      break;
    case CanIdKind::kAny:
      k.id = filter.id & CAN_EFF_MASK;
      k.mask = (filter.mask & CAN_EFF_MASK) | CAN_RTR_FLAG;
      break;
  }
  return k;
}

std::uint32_t kernel_id(const CanFrame& frame) noexcept {
  std::uint32_t id = frame.id & (frame.extended ? CAN_EFF_MASK : CAN_SFF_MASK);
  if (frame.extended) {
    id |= CAN_EFF_FLAG;
  }
  return id;
}

}  // namespace detail

bool passes_filters(const CanFrame& frame, std::span<const CanFilter> filters) noexcept {
  const std::uint32_t id = detail::kernel_id(frame);
  for (const CanFilter& filter : filters) {
    const detail::KernelFilter k = detail::to_kernel_filter(filter);
    if ((id & k.mask) == (k.id & k.mask)) {
      return true;
    }
  }
  return false;
}

CanBusState state_after_error_frame(const CanFrame& error_frame, CanBusState current) noexcept {
  if (!error_frame.error) {
    return current;
  }
  const std::uint32_t classes = error_frame.id;
  if ((classes & CAN_ERR_BUSOFF) != 0U) {
    return CanBusState::kBusOff;
  }
  if ((classes & CAN_ERR_RESTARTED) != 0U) {
    return CanBusState::kErrorActive;
  }
  if ((classes & CAN_ERR_CRTL) != 0U && error_frame.length > 1) {
    const std::uint8_t crtl = error_frame.data[1];
    if ((crtl & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE)) != 0U) {
      return CanBusState::kErrorPassive;
    }
    if ((crtl & (CAN_ERR_CRTL_RX_WARNING | CAN_ERR_CRTL_TX_WARNING)) != 0U) {
      return CanBusState::kErrorWarning;
    }
    if ((crtl & CAN_ERR_CRTL_ACTIVE) != 0U) {
      return CanBusState::kErrorActive;
    }
  }
  return current;
}

ExchangeResult CanBus::do_send_and_receive(const CanFrame* frame, std::int64_t send_deadline_ns, ReceivedFrame& out,
                                           std::int64_t now_ns, std::int64_t receive_deadline_ns) noexcept {
  ExchangeResult result;
  if (frame != nullptr) {
    result.sent = do_send_before(*frame, send_deadline_ns);
    now_ns = monotonic_ns();
  }
  result.received = do_receive(out, std::chrono::nanoseconds{std::max<std::int64_t>(receive_deadline_ns - now_ns, 0)});
  return result;
}

SendResult CanBus::do_send_before(const CanFrame& frame, std::int64_t deadline_ns) noexcept {
  const std::int64_t left_ns = deadline_ns - monotonic_ns();
  return do_send(frame, std::chrono::nanoseconds{left_ns > 0 ? left_ns : 0});
}

}  // namespace pmsm::hal
