#include "pmsm/hal/wait.hpp"

#include <poll.h>

#include <cerrno>

namespace pmsm::hal {

std::size_t DescriptorWait::add(int fd) noexcept {
  if (count_ == kCapacity) {
    return kCapacity;  // never ready: a programming error shows as a slot that never wakes
  }
  fds_[count_] = fd;
  return count_++;
}

void DescriptorWait::set(std::size_t slot, int fd) noexcept {
  if (slot < count_) {
    fds_[slot] = fd;
  }
}

WaitResult DescriptorWait::wait_for(std::chrono::nanoseconds timeout) noexcept {
  std::array<pollfd, kCapacity> p{};
  for (std::size_t i = 0; i < count_; ++i) {
    p[i].fd = fds_[i];  // poll ignores negative descriptors
    p[i].events = POLLIN;
  }
  const std::int64_t ns = timeout.count() > 0 ? timeout.count() : 0;
  timespec ts{};
  ts.tv_sec = ns / 1'000'000'000;
  ts.tv_nsec = ns % 1'000'000'000;
  WaitResult r;
  const int n = ::ppoll(p.data(), count_, &ts, nullptr);
  if (n == 0) {
    r.timed_out = true;
    return r;
  }
  if (n < 0) {
    if (errno == EINTR) {
      r.interrupted = true;
    } else {
      r.error = errno;
    }
    return r;
  }
  for (std::size_t i = 0; i < count_; ++i) {
    if (p[i].revents != 0) {
      r.ready_mask |= 1U << i;
    }
  }
  return r;
}

}  // namespace pmsm::hal
