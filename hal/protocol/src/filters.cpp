#include "pmsm/hal/protocol_filters.hpp"

namespace pmsm::hal::protocol {
namespace {

// One {base | node_bits, mask} filter per message `wanted` selects.
template <typename Wanted>
FilterSet make_filters(Wanted wanted, std::uint32_t node_bits, std::uint32_t mask) noexcept {
  FilterSet set;
  for (const MessageDef& def : kMessages) {
    if (wanted(def)) {
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
  return make_filters([role](const MessageDef& def) { return def.received_by(role); }, node, kMaxStandardId);
}

FilterSet receive_filters_all_nodes(Role role) noexcept {
  return make_filters([role](const MessageDef& def) { return def.received_by(role); }, 0, kIdBaseMask);
}

FilterSet published_filters(Role role, NodeId node) noexcept {
  if (node > kMaxNodeId) {
    return {};
  }
  return make_filters(
      [role](const MessageDef& def) {
        return def.sender == role && !def.received_by(Role::kPlant) && !def.received_by(Role::kDaemon);
      },
      node, kMaxStandardId);
}

}  // namespace pmsm::hal::protocol
