// One CAN or CAN FD frame as the codec and every bus backend see it, independent of the
// kernel's struct can_frame / canfd_frame (the SocketCAN backend converts at its boundary).
#pragma once

#include <array>
#include <cstdint>
#include <span>

namespace pmsm::hal {

struct CanFrame {
  static constexpr std::size_t kMaxClassicLength = 8;
  static constexpr std::size_t kMaxFdLength = 64;

  std::uint32_t id = 0;      // 11-bit (standard) or 29-bit (extended) identifier
  bool extended = false;     // 29-bit identifier
  bool fd = false;           // CAN FD frame (up to 64 bytes)
  bool bitrate_switch = false; // CAN FD BRS flag
  bool error = false;        // an error frame reported by the controller (SocketCAN CAN_ERR_FLAG)
  std::uint8_t length = 0;   // data length in bytes
  std::array<std::uint8_t, kMaxFdLength> data{};

  [[nodiscard]] std::span<const std::uint8_t> payload() const { return {data.data(), length}; }
  [[nodiscard]] std::span<std::uint8_t> payload() { return {data.data(), length}; }
};

// Valid CAN FD data lengths are 0..8, 12, 16, 20, 24, 32, 48, 64.
[[nodiscard]] constexpr bool is_valid_fd_length(std::size_t length) {
  return length <= 8 || length == 12 || length == 16 || length == 20 || length == 24 ||
         length == 32 || length == 48 || length == 64;
}

// Receive filters are plain data too: the protocol derives them (protocol_filters.hpp) and
// the buses in hal/io install them.
inline constexpr std::uint32_t kMaxStandardId = 0x7FF;
inline constexpr std::uint32_t kMaxExtendedId = 0x1FFF'FFFF;

enum class CanIdKind : std::uint8_t {
  kStandard,  // matches 11-bit identifiers only
  kExtended,  // matches 29-bit identifiers only
  kAny,       // matches both (id/mask compared on the numeric identifier alone)
};

// One receive filter: a data frame passes if (frame.id & mask) == (id & mask) and its
// identifier kind matches. Remote (RTR) frames never pass a filter.
struct CanFilter {
  std::uint32_t id = 0;
  std::uint32_t mask = 0;
  CanIdKind kind = CanIdKind::kStandard;

  [[nodiscard]] static constexpr CanFilter exact(std::uint32_t frame_id, bool extended_id) {
    return {frame_id, extended_id ? kMaxExtendedId : kMaxStandardId,
            extended_id ? CanIdKind::kExtended : CanIdKind::kStandard};
  }
  [[nodiscard]] static constexpr CanFilter accept_all() { return {0, 0, CanIdKind::kAny}; }
};

}  // namespace pmsm::hal
