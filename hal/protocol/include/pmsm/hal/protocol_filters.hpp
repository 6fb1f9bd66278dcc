// Kernel receive filters (CAN_RAW_FILTER) per role, derived from the protocol tables: the
// list that admits exactly the frames a role receives, so that unrelated traffic never
// wakes the RT thread (DESIGN §6). Install with
//   const FilterSet filters = receive_filters(Role::kDaemon, node);
//   bus.set_filters(filters.view());
#pragma once

#include <array>
#include <cstddef>
#include <span>

#include "pmsm/hal/can_frame.hpp"
#include "pmsm/hal/protocol.hpp"

namespace pmsm::hal::protocol {

struct FilterSet {
  std::array<CanFilter, kMessageCount> filters{};
  std::size_t count = 0;

  [[nodiscard]] std::span<const CanFilter> view() const& noexcept { return {filters.data(), count}; }
  // No view of a temporary: `for (auto& f : receive_filters(r, n).view())` would dangle.
  std::span<const CanFilter> view() const&& = delete;
};

// One exact filter per message the role receives, for one node: {base + node, 0x7FF,
// standard IDs only}. Extended-ID and remote frames never pass. An invalid node (> 15)
// gives an empty set, which passes nothing.
[[nodiscard]] FilterSet receive_filters(Role role, NodeId node) noexcept;

// The same for every node at once ({base, 0x7F0}): a bench monitor watching all axes.
[[nodiscard]] FilterSet receive_filters_all_nodes(Role role) noexcept;

// One exact filter per message `role` publishes to the watchers for one node (its frames
// other than the fast loop's, which the plant and the daemon exchange): installed on the endpoint that sends them, which does not
// receive its own frames, it passes only those another sender transmits as this node (a
// second daemon configured with the same node id). An invalid node gives an empty set.
[[nodiscard]] FilterSet published_filters(Role role, NodeId node) noexcept;

}  // namespace pmsm::hal::protocol
