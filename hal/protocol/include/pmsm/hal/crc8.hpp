// CRC-8 SAE J1850 (AUTOSAR "CRC8"): polynomial 0x1D, initial value 0xFF, no reflection,
// final XOR 0xFF. Check value 0x4B for the ASCII bytes "123456789".
//
// AUTOSAR E2E profile 1 pairs this CRC with a 4-bit alive counter; the command frames of
// the pmsm-thermal protocol do the same (see protocol.hpp and docs/protocol.md).
// Table-driven, constexpr, no allocation: usable on the real-time thread.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>

namespace pmsm::hal {

inline constexpr std::uint8_t kCrc8SaeJ1850Polynomial = 0x1D;
inline constexpr std::uint8_t kCrc8SaeJ1850Init = 0xFF;
inline constexpr std::uint8_t kCrc8SaeJ1850XorOut = 0xFF;

namespace detail {

[[nodiscard]] constexpr std::array<std::uint8_t, 256> make_crc8_table(std::uint8_t polynomial) {
  std::array<std::uint8_t, 256> table{};
  for (std::size_t dividend = 0; dividend < table.size(); ++dividend) {
    auto remainder = static_cast<std::uint8_t>(dividend);
    for (int bit = 0; bit < 8; ++bit) {
      const bool top = (remainder & 0x80U) != 0U;
      remainder = static_cast<std::uint8_t>(remainder << 1U);
      if (top) {
        remainder = static_cast<std::uint8_t>(remainder ^ polynomial);
      }
    }
    table[dividend] = remainder;
  }
  return table;
}

inline constexpr std::array<std::uint8_t, 256> kCrc8SaeJ1850Table =
    make_crc8_table(kCrc8SaeJ1850Polynomial);

}  // namespace detail

// Incremental form, for data that is not contiguous (the E2E data ID followed by payload).
class Crc8SaeJ1850 {
 public:
  constexpr void update(std::uint8_t byte) noexcept {
    state_ = detail::kCrc8SaeJ1850Table[static_cast<std::uint8_t>(state_ ^ byte)];
  }
  constexpr void update(std::span<const std::uint8_t> bytes) noexcept {
    for (const std::uint8_t byte : bytes) {
      update(byte);
    }
  }
  [[nodiscard]] constexpr std::uint8_t value() const noexcept {
    return static_cast<std::uint8_t>(state_ ^ kCrc8SaeJ1850XorOut);
  }

 private:
  std::uint8_t state_ = kCrc8SaeJ1850Init;
};

[[nodiscard]] constexpr std::uint8_t crc8_sae_j1850(std::span<const std::uint8_t> bytes) noexcept {
  Crc8SaeJ1850 crc;
  crc.update(bytes);
  return crc.value();
}

}  // namespace pmsm::hal
