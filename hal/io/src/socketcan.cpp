// SocketCAN backend (see socketcan.hpp for the set-up order, taken from can-utils).
#include "pmsm/hal/socketcan.hpp"

#include <liburing.h>
#include <linux/can.h>
#include <linux/can/raw.h>
#include <linux/net_tstamp.h>
#include <net/if.h>
#include <net/if_arp.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <sys/syscall.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cctype>
#include <cstring>
#include <limits>
#include <new>
#include <utility>

#include "filter_rule.hpp"
#include "can_interface_name.hpp"
#include "pmsm/hal/rt.hpp"

namespace pmsm::hal {

namespace {

static_assert(socketcan_detail::kClassicMtu == CAN_MTU && socketcan_detail::kFdMtu == CANFD_MTU);

std::string quoted(const std::string& name) { return "'" + name + "'"; }

bool is_interface_gone(int error_number) {
  return error_number == ENETDOWN || error_number == ENODEV || error_number == ENXIO;
}

// Copies the interface name into an ifreq; false if it does not fit.
bool fill_ifreq(ifreq& ifr, const std::string& name) {
  static_assert(IFNAMSIZ == 16, "can_interface_name_problem assumes Linux's 15-character names");
  std::memset(&ifr, 0, sizeof ifr);
  if (name.empty() || name.size() >= sizeof ifr.ifr_name) {
    return false;
  }
  std::memcpy(ifr.ifr_name, name.data(), name.size());
  return true;
}

template <typename T>
Status set_option(int fd, int level, int option, const T& value, const char* option_name,
                  const std::string& interface) {
  if (::setsockopt(fd, level, option, &value, sizeof value) != 0) {
    const int e = errno;
    return Status::error(e, std::string{"setsockopt("} + option_name + ") on CAN interface " +
                                quoted(interface) + " failed: " + errno_text(e));
  }
  return {};
}

// Room for SO_TIMESTAMPING (3 timespecs) and SO_RXQ_OVFL (a u32), as candump sizes it.
constexpr std::size_t kControlBytes = CMSG_SPACE(3 * sizeof(timespec)) + CMSG_SPACE(sizeof(std::uint32_t)) + 64;

// Tags of the io_uring operations (user_data).
constexpr std::uint64_t kTagSend = 1;
constexpr std::uint64_t kTagReceive = 2;
constexpr std::uint64_t kTagCancel = 3;

__kernel_timespec kernel_timespec(std::int64_t ns) {
  return __kernel_timespec{ns / 1'000'000'000, ns % 1'000'000'000};
}

std::int64_t to_ns(const timespec& ts) {
  return std::int64_t{ts.tv_sec} * 1'000'000'000 + std::int64_t{ts.tv_nsec};
}

void bump(std::atomic<std::uint64_t>& counter, std::uint64_t by = 1) noexcept {
  counter.fetch_add(by, std::memory_order_relaxed);
}

// ppoll() for one descriptor, as the kernel gives it: a finite wait leaves in `*ts` the time
// that was left of it (fs/select.c, poll_select_finish: the wait's end, set at entry from the
// monotonic clock, minus the clock at return), which glibc's wrapper hides by passing a copy.
// The time waited is then the timeout less what is left, to the nanosecond and without a clock
// reading of ours. Only where the kernel's timespec is the C library's (64-bit targets); else
// the wrapper, and the time left is not known (`*left_known` false). A zero timeout is never
// written back (nothing is left to tell).
int poll_one(pollfd& p, timespec* ts, bool& left_known) noexcept {
#if defined(SYS_ppoll) && defined(__LP64__)
  static_assert(sizeof(timespec) == 16, "the kernel's __kernel_timespec on a 64-bit target");
  left_known = ts != nullptr && (ts->tv_sec != 0 || ts->tv_nsec != 0);
  return static_cast<int>(::syscall(SYS_ppoll, &p, 1UL, ts, nullptr, 0UL));
#else
  left_known = false;
  return ::ppoll(&p, 1, ts, nullptr);
#endif
}

}  // namespace

namespace socketcan_detail {

std::size_t encode(const CanFrame& frame, std::span<std::uint8_t, kFdMtu> bytes) noexcept {
  std::uint32_t can_id = frame.id;
  if (frame.error) {
    can_id = (frame.id & CAN_ERR_MASK) | CAN_ERR_FLAG;
  } else if (frame.extended) {
    can_id = (frame.id & CAN_EFF_MASK) | CAN_EFF_FLAG;
  } else {
    can_id = frame.id & CAN_SFF_MASK;
  }
  const std::size_t capacity = frame.fd ? CanFrame::kMaxFdLength : CanFrame::kMaxClassicLength;
  const std::uint8_t length = static_cast<std::uint8_t>(std::min<std::size_t>(frame.length, capacity));
  if (frame.fd) {
    canfd_frame k{};
    k.can_id = can_id;
    k.len = length;
    k.flags = static_cast<std::uint8_t>(CANFD_FDF | (frame.bitrate_switch ? CANFD_BRS : 0));
    std::memcpy(k.data, frame.data.data(), length);
    std::memcpy(bytes.data(), &k, sizeof k);
    return sizeof k;
  }
  can_frame k{};
  k.can_id = can_id;
  k.len = length;
  std::memcpy(k.data, frame.data.data(), length);
  std::memcpy(bytes.data(), &k, sizeof k);
  return sizeof k;
}

bool decode(std::span<const std::uint8_t> bytes, CanFrame& frame) noexcept {
  if (bytes.size() != CAN_MTU && bytes.size() != CANFD_MTU) {
    return false;
  }
  // Both layouts start with can_id and len; canfd_frame is the larger one.
  canfd_frame k{};
  std::memcpy(&k, bytes.data(), bytes.size());
  const bool fd = bytes.size() == CANFD_MTU;
  const std::size_t capacity = fd ? CanFrame::kMaxFdLength : CanFrame::kMaxClassicLength;
  if (k.len > capacity || (fd && !is_valid_fd_length(k.len))) {
    return false;
  }
  frame = CanFrame{};
  frame.error = (k.can_id & CAN_ERR_FLAG) != 0U;
  frame.extended = !frame.error && (k.can_id & CAN_EFF_FLAG) != 0U;
  if (frame.error) {
    frame.id = k.can_id & CAN_ERR_MASK;
  } else {
    frame.id = k.can_id & (frame.extended ? CAN_EFF_MASK : CAN_SFF_MASK);
  }
  frame.fd = fd;
  frame.bitrate_switch = fd && (k.flags & CANFD_BRS) != 0U;
  frame.length = k.len;
  std::memcpy(frame.data.data(), k.data, k.len);
  return true;
}

}  // namespace socketcan_detail

// The ring of send_and_receive() and what its operations read and write, together: the kernel
// reads the send's bytes and fills the read's buffer and control messages while they are in
// flight, after the call that queued them has left its stack frame for the wait.
struct SocketCanBus::Ring {
  io_uring ring{};
  std::array<std::uint8_t, CANFD_MTU> rx{};
  alignas(cmsghdr) std::array<char, kControlBytes> control{};
  iovec iov{};
  msghdr msg{};
  std::array<std::uint8_t, socketcan_detail::kFdMtu> tx{};
  bool set_up = false;

  Ring() = default;
  Ring(const Ring&) = delete;
  Ring& operator=(const Ring&) = delete;
  ~Ring() {
    if (set_up) {
      io_uring_queue_exit(&ring);  // cancels whatever is still in flight
    }
  }

  // A ring of 8 entries (a period needs 2, a cancellation 1) with what the exchange needs: a
  // send whose success posts no completion (5.17) and a wait with a timeout in the same call
  // (5.11). Null where there is none: no io_uring (ENOSYS), seccomp or kernel.io_uring_disabled
  // refusing it (EPERM), an older kernel.
  static std::unique_ptr<Ring> create() noexcept {
    auto r = std::unique_ptr<Ring>(new (std::nothrow) Ring);
    if (r == nullptr) {
      return nullptr;
    }
    io_uring_params params{};
    if (io_uring_queue_init_params(8, &r->ring, &params) < 0) {
      return nullptr;
    }
    r->set_up = true;
    if ((params.features & IORING_FEAT_EXT_ARG) == 0U || (params.features & IORING_FEAT_CQE_SKIP) == 0U) {
      return nullptr;  // ~Ring exits the ring
    }
    r->iov = iovec{r->rx.data(), r->rx.size()};
    r->msg.msg_iov = &r->iov;
    r->msg.msg_iovlen = 1;
    return r;
  }

  // The next free entry. The ring has 8 and a call takes at most 3, submitting all it took, so
  // one is always free; were none, submitting what is queued would free them.
  io_uring_sqe* next_sqe() noexcept {
    for (;;) {
      if (io_uring_sqe* sqe = io_uring_get_sqe(&ring); sqe != nullptr) {
        return sqe;
      }
      (void)io_uring_submit(&ring);
    }
  }

  // Takes every completion there is: a failed send's result into `send_res`, the receive's into
  // `receive_res` (each kNone until seen); a cancellation's is dropped. No system call.
  static constexpr int kNone = std::numeric_limits<int>::min();
  void reap(int& send_res, int& receive_res) noexcept {
    io_uring_cqe* cqe = nullptr;
    while (io_uring_peek_cqe(&ring, &cqe) == 0 && cqe != nullptr) {
      const std::uint64_t tag = io_uring_cqe_get_data64(cqe);
      if (tag == kTagSend) {
        send_res = cqe->res;
      } else if (tag == kTagReceive) {
        receive_res = cqe->res;
      }
      io_uring_cqe_seen(&ring, cqe);
    }
  }
};

SocketCanBus::SocketCanBus(SocketCanConfig config) : config_(std::move(config)) {
  Status status = open_socket();
  if (!status.ok()) {
    throw HalError(status.error_number(), status.message());
  }
  if (config_.io_uring) {
    ring_ = Ring::create();
  }
}

SocketCanBus::~SocketCanBus() = default;

std::unique_ptr<SocketCanBus> SocketCanBus::open(SocketCanConfig config, Status& error) {
  try {
    auto bus = std::make_unique<SocketCanBus>(std::move(config));
    error = Status{};
    return bus;
  } catch (const HalError& e) {
    error = Status::error(e.error_number(), e.what());
    return nullptr;
  }
}

std::string can_interface_name_problem(std::string_view name) { return common::can_interface_name_problem(name); }

Status SocketCanBus::open_socket() {
  const std::string& name = config_.interface;
  fd_.reset();
  ifindex_ = 0;
  last_drop_count_ = 0;
  last_receive_waited_ = false;
  receive_timeout_ns_ = 0;
  state_.store(CanBusState::kErrorActive);

  UniqueFd fd{::socket(PF_CAN, SOCK_RAW | SOCK_CLOEXEC, CAN_RAW)};
  if (!fd.valid()) {
    const int e = errno;
    if (e == EAFNOSUPPORT || e == EPROTONOSUPPORT) {
      return Status::error(e, "cannot open CAN interface " + quoted(name) +
                                  ": this kernel has no CAN support (socket(PF_CAN, SOCK_RAW, CAN_RAW) failed: " +
                                  errno_text(e) +
                                  "); run under scripts/vcan-env, or load the can and can-raw modules");
    }
    return Status::error(e, "socket(PF_CAN, SOCK_RAW, CAN_RAW) for CAN interface " + quoted(name) +
                                " failed: " + errno_text(e));
  }

  ifreq ifr{};
  if (const std::string problem = can_interface_name_problem(name); !problem.empty() || !fill_ifreq(ifr, name)) {
    return Status::error(EINVAL, "invalid CAN interface name " + quoted(name) + ": " + problem);
  }
  if (::ioctl(fd.get(), SIOCGIFINDEX, &ifr) != 0) {
    const int e = errno;
    if (e == ENODEV) {
      return Status::error(e, "no such CAN interface " + quoted(name));
    }
    return Status::error(e, "cannot look up CAN interface " + quoted(name) + ": " + errno_text(e));
  }
  const int ifindex = ifr.ifr_ifindex;

  fill_ifreq(ifr, name);
  if (::ioctl(fd.get(), SIOCGIFHWADDR, &ifr) != 0) {
    const int e = errno;
    return Status::error(e, "cannot read the link type of interface " + quoted(name) + ": " + errno_text(e));
  }
  if (ifr.ifr_hwaddr.sa_family != ARPHRD_CAN) {
    return Status::error(ENODEV, "interface " + quoted(name) + " is not a CAN interface");
  }

  if (config_.fd) {
    // can-utils: check the MTU before enabling FD frames; an MTU-16 interface would
    // accept the option but drop every FD frame we send.
    fill_ifreq(ifr, name);
    if (::ioctl(fd.get(), SIOCGIFMTU, &ifr) != 0) {
      const int e = errno;
      return Status::error(e, "cannot read the MTU of CAN interface " + quoted(name) + ": " + errno_text(e));
    }
    if (ifr.ifr_mtu < static_cast<int>(CANFD_MTU)) {
      return Status::error(EPROTONOSUPPORT,
                           "CAN FD requested on " + quoted(name) + " but its MTU is " +
                               std::to_string(ifr.ifr_mtu) + " (classic CAN only); set it with 'ip link set " +
                               name + " mtu 72' or disable FD");
    }
    const int on = 1;
    if (Status s = set_option(fd.get(), SOL_CAN_RAW, CAN_RAW_FD_FRAMES, on, "CAN_RAW_FD_FRAMES", name); !s) {
      return s;
    }
  }

  // The fd is in place from here on so that apply_filters / apply_error_mask can use it.
  fd_ = std::move(fd);
  if (Status s = apply_filters(); !s) {
    fd_.reset();
    return s;
  }
  if (Status s = apply_error_mask(); !s) {
    fd_.reset();
    return s;
  }

  const int on = 1;
  if (Status s = set_option(fd_.get(), SOL_SOCKET, SO_RXQ_OVFL, on, "SO_RXQ_OVFL", name); !s) {
    fd_.reset();
    return s;
  }
  // Software receive timestamps always; hardware ones where the driver has them.
  const int stamping = SOF_TIMESTAMPING_SOFTWARE | SOF_TIMESTAMPING_RX_SOFTWARE |
                       SOF_TIMESTAMPING_RAW_HARDWARE | SOF_TIMESTAMPING_RX_HARDWARE;
  if (Status s = set_option(fd_.get(), SOL_SOCKET, SO_TIMESTAMPING, stamping, "SO_TIMESTAMPING", name); !s) {
    fd_.reset();
    return s;
  }
  if (config_.receive_buffer_bytes > 0) {
    // As candump -r does: SO_RCVBUFFORCE first, which a process with CAP_NET_ADMIN may set
    // beyond net.core.rmem_max; SO_RCVBUF otherwise, which the kernel caps there silently
    // (receive_buffer_granted_bytes() says what was granted).
    if (::setsockopt(fd_.get(), SOL_SOCKET, SO_RCVBUFFORCE, &config_.receive_buffer_bytes,
                     sizeof config_.receive_buffer_bytes) != 0) {
      if (Status s = set_option(fd_.get(), SOL_SOCKET, SO_RCVBUF, config_.receive_buffer_bytes, "SO_RCVBUF", name);
          !s) {
        fd_.reset();
        return s;
      }
    }
  }
  {
    // The kernel reports twice the size asked (its bookkeeping share included); half of it is
    // the figure comparable with the request.
    int granted = 0;
    socklen_t length = sizeof granted;
    receive_buffer_granted_bytes_ =
        ::getsockopt(fd_.get(), SOL_SOCKET, SO_RCVBUF, &granted, &length) == 0 ? granted / 2 : 0;
  }

  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = ifindex;
  if (::bind(fd_.get(), reinterpret_cast<const sockaddr*>(&addr), sizeof addr) != 0) {
    const int e = errno;
    fd_.reset();
    return Status::error(e, "cannot bind to CAN interface " + quoted(name) + ": " + errno_text(e));
  }
  ifindex_ = ifindex;
  return {};
}

Status SocketCanBus::apply_filters() {
  if (!config_.filters.has_value()) {
    return {};  // never set: the kernel default (one filter passing everything)
  }
  std::vector<can_filter> kernel;
  kernel.reserve(config_.filters->size());
  for (const CanFilter& f : *config_.filters) {
    const detail::KernelFilter k = detail::to_kernel_filter(f);
    kernel.push_back(can_filter{k.id, k.mask});
  }
  const auto bytes = static_cast<socklen_t>(kernel.size() * sizeof(can_filter));
  if (::setsockopt(fd_.get(), SOL_CAN_RAW, CAN_RAW_FILTER, kernel.empty() ? nullptr : kernel.data(), bytes) !=
      0) {
    const int e = errno;
    return Status::error(e, "setsockopt(CAN_RAW_FILTER) with " + std::to_string(kernel.size()) +
                                " filters on CAN interface " + quoted(config_.interface) +
                                " failed: " + errno_text(e));
  }
  return {};
}

Status SocketCanBus::apply_error_mask() {
  const can_err_mask_t mask = config_.error_mask & CAN_ERR_MASK;
  return set_option(fd_.get(), SOL_CAN_RAW, CAN_RAW_ERR_FILTER, mask, "CAN_RAW_ERR_FILTER", config_.interface);
}

Status SocketCanBus::set_filters(std::span<const CanFilter> filters) {
  // Swapped in and, on failure, back (a move-assignment of the optional drew GCC 12's false
  // -Wmaybe-uninitialized at -O3).
  std::optional<std::vector<CanFilter>> other(std::in_place, filters.begin(), filters.end());
  config_.filters.swap(other);
  if (!fd_.valid()) {
    return {};  // applied by the next reopen()
  }
  Status s = apply_filters();
  if (!s) {
    config_.filters.swap(other);
  }
  return s;
}

Status SocketCanBus::accept_all_frames() {
  const CanFilter all = CanFilter::accept_all();
  Status s = set_filters(std::span<const CanFilter>{&all, 1});
  if (s) {
    config_.filters.reset();
  }
  return s;
}

Status SocketCanBus::set_error_mask(std::uint32_t error_classes) {
  const std::uint32_t previous = config_.error_mask;
  config_.error_mask = error_classes;
  if (!fd_.valid()) {
    return {};
  }
  Status s = apply_error_mask();
  if (!s) {
    config_.error_mask = previous;
  }
  return s;
}

Status SocketCanBus::reopen() { return open_socket(); }

CanBusCounters SocketCanBus::counters() const noexcept {
  CanBusCounters c;
  const auto get = [](const std::atomic<std::uint64_t>& a) { return a.load(std::memory_order_relaxed); };
  c.tx_frames = get(counters_.tx_frames);
  c.rx_frames = get(counters_.rx_frames);
  c.tx_dropped_enobufs = get(counters_.tx_dropped_enobufs);
  c.tx_would_block = get(counters_.tx_would_block);
  c.tx_errors = get(counters_.tx_errors);
  c.rx_overflow = get(counters_.rx_overflow);
  c.rx_errors = get(counters_.rx_errors);
  c.error_frames = get(counters_.error_frames);
  c.bad_size_reads = get(counters_.bad_size_reads);
  c.bus_off_events = get(counters_.bus_off_events);
  c.interface_down_events = get(counters_.interface_down_events);
  return c;
}

CanBusState SocketCanBus::state() const noexcept { return state_.load(std::memory_order_relaxed); }

bool SocketCanBus::interface_up() const noexcept {
  // A separate socket so that this works from any thread and while fd_ is being reopened.
  UniqueFd probe{::socket(AF_CAN, SOCK_RAW | SOCK_CLOEXEC, CAN_RAW)};
  ifreq ifr{};
  if (!probe.valid() || !fill_ifreq(ifr, config_.interface)) {
    return false;
  }
  if (::ioctl(probe.get(), SIOCGIFFLAGS, &ifr) != 0) {
    return false;
  }
  const int flags = ifr.ifr_flags;
  return (flags & IFF_UP) != 0 && (flags & IFF_RUNNING) != 0;
}

SendResult SocketCanBus::do_send(const CanFrame& frame, std::chrono::nanoseconds max_wait) noexcept {
  return send_until(frame, max_wait, 0);
}

SendResult SocketCanBus::do_send_before(const CanFrame& frame, std::int64_t deadline_ns) noexcept {
  return send_until(frame, std::chrono::nanoseconds{0}, deadline_ns);
}

SendResult SocketCanBus::send_until(const CanFrame& frame, std::chrono::nanoseconds max_wait,
                                    std::int64_t deadline_ns) noexcept {
  if (!is_sendable(frame, config_.fd)) {
    bump(counters_.tx_errors);
    return SendResult::kInvalidFrame;
  }
  if (!fd_.valid()) {
    bump(counters_.tx_errors);
    bump(counters_.interface_down_events);
    return SendResult::kInterfaceDown;
  }
  std::array<std::uint8_t, socketcan_detail::kFdMtu> bytes{};
  const std::size_t size = socketcan_detail::encode(frame, bytes);
  // The clock is read only when the queue is full: a send that goes through costs one system
  // call (clock_gettime is one too where there is no vDSO, e.g. under User-Mode Linux).

  for (;;) {
    const ssize_t n = ::send(fd_.get(), bytes.data(), size, MSG_DONTWAIT);
    if (n == static_cast<ssize_t>(size)) {
      bump(counters_.tx_frames);
      return SendResult::kOk;
    }
    const int e = n < 0 ? errno : EIO;  // a short write of a CAN frame is an error
    if (e == EINTR) {
      continue;
    }
    last_errno_ = e;
    if ((e == ENOBUFS || e == EAGAIN) && (deadline_ns > 0 || max_wait.count() > 0)) {
      const std::int64_t now_ns = monotonic_ns();
      if (deadline_ns == 0) {
        deadline_ns = now_ns + max_wait.count();
      }
      const std::int64_t left_ns = deadline_ns - now_ns;
      if (left_ns > 0) {
        // As cangen does: wait for room, then retry. POLLOUT reflects the socket's send
        // buffer; for a full device queue (ENOBUFS) it may return at once, so the wait is
        // bounded by the deadline and retried in short steps.
        pollfd p{fd_.get(), POLLOUT, 0};
        const std::int64_t step_ns = std::min<std::int64_t>(left_ns, 100'000);
        const timespec ts{0, static_cast<long>(step_ns)};
        (void)::ppoll(&p, 1, &ts, nullptr);
        if ((p.revents & POLLOUT) != 0 && e == ENOBUFS) {
          // Room in the socket but not necessarily in the device queue: back off a little.
          const timespec pause{0, static_cast<long>(std::min<std::int64_t>(step_ns, 20'000))};
          (void)::clock_nanosleep(CLOCK_MONOTONIC, 0, &pause, nullptr);
        }
        continue;
      }
    }
    if (e == ENOBUFS) {
      bump(counters_.tx_dropped_enobufs);
      return SendResult::kNoBufferSpace;
    }
    if (e == EAGAIN) {
      bump(counters_.tx_would_block);
      return SendResult::kWouldBlock;
    }
    bump(counters_.tx_errors);
    if (is_interface_gone(e)) {
      bump(counters_.interface_down_events);
      return SendResult::kInterfaceDown;
    }
    return SendResult::kError;
  }
}

ReceiveStatus SocketCanBus::do_receive(ReceivedFrame& out, std::chrono::nanoseconds timeout) noexcept {
  out.waited_ns = -1;
  if (!fd_.valid()) {
    bump(counters_.interface_down_events);
    return ReceiveStatus::kInterfaceDown;
  }
  // Read first when the previous call found its frame already queued (a burst: one system call
  // per frame); wait first when the previous call had to wait (a lockstep peer: its answer is
  // not there yet, and a read that fails costs a system call for nothing).
  if (timeout.count() == 0 || !last_receive_waited_) {
    const ReceiveStatus status = read_one(out);
    if (status != ReceiveStatus::kTimeout || timeout.count() == 0) {
      last_receive_waited_ = false;
      out.waited_ns = 0;
      return status;
    }
  }
  last_receive_waited_ = true;
  // The first wait takes the timeout as given. A wait that ends without a frame before the
  // timeout (a signal, or a frame another reader took) waits the rest: the kernel's time left
  // where it tells it, else from the clock. The time waited is told (out.waited_ns) when the
  // first wait ended with the frame.
  const bool forever = timeout.count() < 0;
  std::int64_t deadline_ns = 0;
  std::int64_t left_ns = timeout.count();
  for (bool first = true;; first = false) {
    timespec ts{left_ns / 1'000'000'000, left_ns % 1'000'000'000};
    pollfd p{fd_.get(), POLLIN, 0};
    bool left_known = false;
    const int n = poll_one(p, forever ? nullptr : &ts, left_known);
    if (n == 0) {
      return ReceiveStatus::kTimeout;
    }
    if (n > 0) {
      const ReceiveStatus status = read_one(out);
      if (status != ReceiveStatus::kTimeout) {
        // Only a time left strictly inside the wait is the kernel's account of it: 0 is a wait
        // that ran out (rounded up from a late return, by how much is not told), the whole
        // timeout a kernel that did not write it back (the STICKY_TIMEOUTS personality).
        const std::int64_t left_after = to_ns(ts);
        out.waited_ns = first && left_known && left_after > 0 && left_after < left_ns ? left_ns - left_after : -1;
        return status;
      }
    } else if (errno != EINTR) {
      last_errno_ = errno;
      bump(counters_.rx_errors);
      return ReceiveStatus::kError;
    }
    if (!forever) {
      if (left_known) {
        left_ns = to_ns(ts);  // the rest of the same wait, as the kernel counted it
      } else {
        const std::int64_t now_ns = monotonic_ns();
        if (deadline_ns == 0) {
          deadline_ns = now_ns + left_ns;  // a little later than the call's: by one wait's length
        }
        left_ns = deadline_ns - now_ns;
      }
      if (left_ns <= 0) {
        return ReceiveStatus::kTimeout;
      }
    }
  }
}

ReceiveStatus SocketCanBus::do_receive_backstop(ReceivedFrame& out, std::chrono::nanoseconds timeout) noexcept {
  if (!fd_.valid()) {
    bump(counters_.interface_down_events);
    return ReceiveStatus::kInterfaceDown;
  }
  if (timeout.count() <= 0) {
    return do_receive(out, timeout);
  }
  if (timeout.count() != receive_timeout_ns_) {
    // The kernel rounds the timeout up to its tick (jiffies). Set only when it changes: a
    // caller that waits the same backstop every period pays one blocking read per frame.
    const timeval tv{timeout.count() / 1'000'000'000, (timeout.count() % 1'000'000'000 + 999) / 1000};
    if (::setsockopt(fd_.get(), SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv) != 0) {
      last_errno_ = errno;
      bump(counters_.rx_errors);
      return ReceiveStatus::kError;
    }
    receive_timeout_ns_ = timeout.count();
  }
  last_receive_waited_ = true;
  out.waited_ns = -1;  // SO_RCVTIMEO's wait is not told back
  return read_one(out, true);  // EAGAIN (the timeout) and EINTR (a signal) both read as a timeout
}

ExchangeResult SocketCanBus::do_send_and_receive(const CanFrame* frame, std::int64_t send_deadline_ns,
                                                 ReceivedFrame& out, std::int64_t now_ns,
                                                 std::int64_t receive_deadline_ns) noexcept {
  if (!exchanges_in_one_call() || !fd_.valid() || receive_deadline_ns <= now_ns ||
      (frame != nullptr && !is_sendable(*frame, config_.fd))) {
    return CanBus::do_send_and_receive(frame, send_deadline_ns, out, now_ns, receive_deadline_ns);
  }
  Ring& r = *ring_;
  int send_res = Ring::kNone;
  int receive_res = Ring::kNone;
  r.reap(send_res, receive_res);  // nothing is left from a call before (each ends with its receive's)
  send_res = Ring::kNone;
  receive_res = Ring::kNone;
  // The send first: the kernel issues the entries in order, the send at once (MSG_DONTWAIT: a full
  // queue fails it instead of queueing it in the ring), the read next, which finds a frame already
  // queued at once or else waits on the socket inside the kernel.
  if (frame != nullptr) {
    const std::size_t size = socketcan_detail::encode(*frame, r.tx);
    io_uring_sqe* sqe = r.next_sqe();
    io_uring_prep_send(sqe, fd_.get(), r.tx.data(), size, MSG_DONTWAIT);
    io_uring_sqe_set_flags(sqe, IOSQE_CQE_SKIP_SUCCESS);
    io_uring_sqe_set_data64(sqe, kTagSend);
  }
  r.msg.msg_control = r.control.data();
  r.msg.msg_controllen = r.control.size();
  r.msg.msg_flags = 0;
  io_uring_sqe* sqe = r.next_sqe();
  io_uring_prep_recvmsg(sqe, fd_.get(), &r.msg, 0);
  io_uring_sqe_set_data64(sqe, kTagReceive);
  last_receive_waited_ = true;
  out.waited_ns = -1;

  ExchangeResult result;
  __kernel_timespec ts = kernel_timespec(receive_deadline_ns - now_ns);
  io_uring_cqe* cqe = nullptr;
  // One system call in the steady state: submit both, wait for a completion or the timeout.
  int rc = io_uring_submit_and_wait_timeout(&r.ring, &cqe, 1, &ts, nullptr);
  for (;;) {
    r.reap(send_res, receive_res);
    if (send_res != Ring::kNone) {
      // Refused (a full queue, the interface gone, ...): the read waits in the kernel meanwhile,
      // and the send goes the plain way, with its wait for room and its counting.
      result.sent = send_until(*frame, std::chrono::nanoseconds{0}, send_deadline_ns);
      send_res = Ring::kNone;
      frame = nullptr;
    }
    if (receive_res != Ring::kNone) {
      break;
    }
    // The wait ended without the read: its timeout (or the deadline passed while the refused
    // send waited for room), or a signal, or the refused send's completion, or a failed wait.
    // Wait on to the deadline, or take the read back.
    const bool wait_over = rc == -ETIME || (rc < 0 && rc != -EINTR);
    const std::int64_t left_ns = wait_over ? 0 : receive_deadline_ns - monotonic_ns();
    if (left_ns > 0) {
      ts = kernel_timespec(left_ns);
      rc = io_uring_wait_cqe_timeout(&r.ring, &cqe, &ts);
      continue;
    }
    io_uring_sqe* cancel = r.next_sqe();
    io_uring_prep_cancel64(cancel, kTagReceive, 0);
    io_uring_sqe_set_data64(cancel, kTagCancel);
    // Until the read's own completion: ECANCELED, or a frame that came meanwhile (delivered).
    for (;;) {
      const int submitted = io_uring_submit_and_wait(&r.ring, 1);
      r.reap(send_res, receive_res);
      if (receive_res != Ring::kNone) {
        break;
      }
      if (submitted < 0 && submitted != -EINTR) {
        // The ring itself fails (not seen). It is parked, never freed while the read may be in
        // the kernel's hands, and the calls after this one take the two-call way; the send is
        // counted as failed, whether or not it went.
        last_errno_ = -submitted;
        bump(counters_.rx_errors);
        ring_failed_ = true;
        if (frame != nullptr) {
          bump(counters_.tx_errors);
          result.sent = SendResult::kError;
        }
        result.received = ReceiveStatus::kError;
        return result;
      }
    }
  }
  if (frame != nullptr) {
    bump(counters_.tx_frames);  // sent: a refusal would have posted its completion at submission
  }
  const int res = receive_res;
  if (res == -ECANCELED) {
    result.received = ReceiveStatus::kTimeout;
    return result;
  }
  result.received = finish_read(res, res < 0 ? -res : 0, r.msg, r.rx.data(), out);
  return result;
}

ReceiveStatus SocketCanBus::read_one(ReceivedFrame& out, bool block) noexcept {
  std::array<std::uint8_t, CANFD_MTU> buffer{};
  iovec iov{buffer.data(), buffer.size()};
  alignas(cmsghdr) std::array<char, kControlBytes> control{};
  msghdr msg{};
  msg.msg_iov = &iov;
  msg.msg_iovlen = 1;
  msg.msg_control = control.data();
  msg.msg_controllen = control.size();

  ssize_t n = -1;
  do {
    n = ::recvmsg(fd_.get(), &msg, block ? 0 : MSG_DONTWAIT);
  } while (n < 0 && errno == EINTR && !block);
  return finish_read(n, n < 0 ? errno : 0, msg, buffer.data(), out);
}

ReceiveStatus SocketCanBus::finish_read(long n, int error_number, msghdr& msg, const std::uint8_t* buffer,
                                        ReceivedFrame& out) noexcept {
  if (n < 0) {
    const int e = error_number;
    if (e == EAGAIN || e == EINTR) {
      return ReceiveStatus::kTimeout;  // nothing queued (or, blocking, the wait ended without a frame)
    }
    last_errno_ = e;
    if (is_interface_gone(e)) {
      bump(counters_.interface_down_events);
      return ReceiveStatus::kInterfaceDown;
    }
    bump(counters_.rx_errors);
    return ReceiveStatus::kError;
  }

  std::int64_t software_ns = 0;
  std::int64_t hardware_ns = 0;
  for (cmsghdr* c = CMSG_FIRSTHDR(&msg); c != nullptr; c = CMSG_NXTHDR(&msg, c)) {
    if (c->cmsg_level != SOL_SOCKET) {
      continue;
    }
    if (c->cmsg_type == SO_TIMESTAMPING && c->cmsg_len >= CMSG_LEN(3 * sizeof(timespec))) {
      std::array<timespec, 3> ts{};
      std::memcpy(ts.data(), CMSG_DATA(c), sizeof ts);
      software_ns = to_ns(ts[0]);
      hardware_ns = to_ns(ts[2]);
    } else if (c->cmsg_type == SO_RXQ_OVFL && c->cmsg_len >= CMSG_LEN(sizeof(std::uint32_t))) {
      std::uint32_t dropped = 0;
      std::memcpy(&dropped, CMSG_DATA(c), sizeof dropped);
      // The kernel's count runs for the socket's life and wraps at 2^32.
      const std::uint32_t delta = dropped - last_drop_count_;
      last_drop_count_ = dropped;
      if (delta != 0U) {
        bump(counters_.rx_overflow, delta);
      }
    }
  }

  const auto size = static_cast<std::size_t>(n);
  if ((size != CAN_MTU && size != CANFD_MTU) || (msg.msg_flags & MSG_TRUNC) != 0 ||
      !socketcan_detail::decode(std::span<const std::uint8_t>{buffer, size}, out.frame)) {
    bump(counters_.bad_size_reads);
    bump(counters_.rx_errors);
    last_errno_ = EBADMSG;
    return ReceiveStatus::kError;
  }
  out.hardware_timestamp = hardware_ns != 0;
  out.timestamp_ns = hardware_ns != 0 ? hardware_ns : software_ns;
  out.software_timestamp_ns = software_ns;

  if (out.frame.error) {
    bump(counters_.error_frames);
    const CanBusState before = state_.load(std::memory_order_relaxed);
    const CanBusState after = state_after_error_frame(out.frame, before);
    if (after == CanBusState::kBusOff && before != CanBusState::kBusOff) {
      bump(counters_.bus_off_events);
    }
    state_.store(after, std::memory_order_relaxed);
  } else {
    bump(counters_.rx_frames);
  }
  return ReceiveStatus::kFrame;
}

}  // namespace pmsm::hal
