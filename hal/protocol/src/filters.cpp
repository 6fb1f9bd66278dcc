#include "pmsm/hal/protocol_filters.hpp"

namespace pmsm::hal::protocol {
namespace {

FilterSet make_filters(Role role, std::uint32_t node_bits, std::uint32_t mask) noexcept {
  FilterSet set;
  for (const MessageDef& def : kMessages) {
    if (def.received_by(role)) {
      set.filters[set.count++] = CanFilter{def.id_base | node_bits, mask, CanIdKind::kStandard};
    }
  }
  return set;
}

}  // namespace

FilterSet receive_filters(Role role, NodeId node) noexcept {
  if (node > kMaxNodeId) {
    return {};  // receives nothing: a bad node id shows up as a timeout, not as another axis's frames
  }
  return make_filters(role, node, kMaxStandardId);
}

FilterSet receive_filters_all_nodes(Role role) noexcept {
  return make_filters(role, 0, kIdBaseMask);
}

FilterSet published_filters(Role role, NodeId node) noexcept {
  FilterSet set;
  if (node > kMaxNodeId) {
    return set;
  }
  for (const MessageDef& def : kMessages) {
    if (def.sender == role && !def.received_by(Role::kPlant) && !def.received_by(Role::kDaemon)) {
      set.filters[set.count++] = CanFilter{def.can_id(node), kMaxStandardId, CanIdKind::kStandard};
    }
  }
  return set;
}

}  // namespace pmsm::hal::protocol
