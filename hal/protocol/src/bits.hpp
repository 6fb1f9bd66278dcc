// Little-endian (Intel) bit-field access on a payload, as the DBC "@1" byte order defines
// it: bit k of the payload is bit (k % 8) of byte (k / 8); a field's start bit is its LSB.
// Private to the codec. Callers guarantee that the field lies inside the payload.
#pragma once

#include <algorithm>
#include <cstdint>

namespace pmsm::hal::protocol::detail {

[[nodiscard]] inline std::uint64_t field_mask(unsigned length) noexcept {
  return length >= 64U ? ~std::uint64_t{0} : (std::uint64_t{1} << length) - 1U;
}

[[nodiscard]] inline std::uint64_t get_bits_le(const std::uint8_t* data, unsigned start, unsigned length) noexcept {
  if (start % 8U == 0U && length % 8U == 0U) {
    // Byte-aligned fields (all of the fast-loop frames): plain little-endian load.
    std::uint64_t value = 0;
    const unsigned first = start / 8U;
    for (unsigned i = length / 8U; i-- > 0U;) {
      value = (value << 8U) | data[first + i];
    }
    return value;
  }
  std::uint64_t value = 0;
  unsigned done = 0;
  unsigned bit = start;
  while (done < length) {
    const unsigned offset = bit % 8U;
    const unsigned n = std::min(8U - offset, length - done);
    const std::uint64_t chunk = (std::uint64_t{data[bit / 8U]} >> offset) & field_mask(n);
    value |= chunk << done;
    bit += n;
    done += n;
  }
  return value;
}

inline void put_bits_le(std::uint8_t* data, unsigned start, unsigned length, std::uint64_t value) noexcept {
  value &= field_mask(length);
  if (start % 8U == 0U && length % 8U == 0U) {
    const unsigned first = start / 8U;
    for (unsigned i = 0; i < length / 8U; ++i) {
      data[first + i] = static_cast<std::uint8_t>(value >> (8U * i));
    }
    return;
  }
  unsigned done = 0;
  unsigned bit = start;
  while (done < length) {
    const unsigned offset = bit % 8U;
    const unsigned n = std::min(8U - offset, length - done);
    const auto mask = static_cast<std::uint8_t>(field_mask(n) << offset);
    const auto bits = static_cast<std::uint8_t>(((value >> done) << offset) & mask);
    std::uint8_t& byte = data[bit / 8U];
    byte = static_cast<std::uint8_t>((byte & static_cast<std::uint8_t>(~mask)) | bits);
    bit += n;
    done += n;
  }
}

[[nodiscard]] inline std::int64_t sign_extend(std::uint64_t raw, unsigned length) noexcept {
  if (length >= 64U) {
    return static_cast<std::int64_t>(raw);
  }
  const std::uint64_t sign = std::uint64_t{1} << (length - 1U);
  return static_cast<std::int64_t>((raw ^ sign)) - static_cast<std::int64_t>(sign);
}

}  // namespace pmsm::hal::protocol::detail
