// The kernel's form of a receive filter (struct can_filter), shared by the SocketCAN and
// the simulated backend so that both apply the same rule.
#pragma once

#include <cstdint>

#include "pmsm/hal/can_bus.hpp"

namespace pmsm::hal::detail {

struct KernelFilter {
  std::uint32_t id = 0;    // can_id incl. CAN_EFF_FLAG
  std::uint32_t mask = 0;  // can_mask incl. CAN_EFF_FLAG / CAN_RTR_FLAG
};

[[nodiscard]] KernelFilter to_kernel_filter(const CanFilter& filter) noexcept;
// A data frame's can_id as the kernel compares it (identifier | CAN_EFF_FLAG).
[[nodiscard]] std::uint32_t kernel_id(const CanFrame& frame) noexcept;

}  // namespace pmsm::hal::detail
