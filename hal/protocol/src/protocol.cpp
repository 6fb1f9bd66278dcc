// Compile-time checks of the protocol tables: a malformed table does not build.
#include "pmsm/hal/protocol.hpp"

#include "pmsm/hal/can_frame.hpp"

namespace pmsm::hal::protocol {
namespace {

constexpr double abs_value(double x) { return x < 0.0 ? -x : x; }

constexpr bool on_raw_grid(const SignalDef& s, double physical) {
  const double raw = (physical - s.offset) / s.factor;
  const double nearest = raw >= 0.0 ? static_cast<double>(static_cast<std::int64_t>(raw + 0.5))
                                    : -static_cast<double>(static_cast<std::int64_t>(-raw + 0.5));
  return abs_value(raw - nearest) <= 1e-6 * (abs_value(raw) > 1.0 ? abs_value(raw) : 1.0);
}

constexpr bool is_identifier(std::string_view name) {
  if (name.empty() || !((name[0] >= 'A' && name[0] <= 'Z') || (name[0] >= 'a' && name[0] <= 'z'))) {
    return false;
  }
  for (const char c : name) {
    const bool ok = (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_';
    if (!ok) {
      return false;
    }
  }
  return name.size() <= 32;  // DBC short-name limit
}

constexpr bool is_dbc_text(std::string_view text) {
  for (const char c : text) {
    if (c == '"' || c == '\\' || static_cast<unsigned char>(c) < 0x20 || static_cast<unsigned char>(c) > 0x7E) {
      return false;
    }
  }
  return true;
}

constexpr bool signal_ok(const SignalDef& s, const MessageDef& m) {
  if (!is_identifier(s.name) || !is_dbc_text(s.unit) || !is_dbc_text(s.comment)) {
    return false;
  }
  if (s.length < 1 || s.length > 32 || s.start_bit + s.length > m.length * 8U) {
    return false;
  }
  if (!(s.factor > 0.0) || s.minimum > s.maximum || !on_raw_grid(s, s.minimum) || !on_raw_grid(s, s.maximum)) {
    return false;
  }
  if (s.raw_min() < s.type_raw_min() || s.raw_max() > s.type_raw_max()) {
    return false;
  }
  for (std::size_t i = 0; i < s.values.size(); ++i) {
    if (s.values[i].value < s.raw_min() || s.values[i].value > s.raw_max() || !is_identifier(s.values[i].label)) {
      return false;
    }
    for (std::size_t j = 0; j < i; ++j) {
      if (s.values[j].value == s.values[i].value || s.values[j].label == s.values[i].label) {
        return false;
      }
    }
  }
  return true;
}

constexpr bool message_ok(const MessageDef& m, std::size_t index) {
  if (static_cast<std::size_t>(m.type) != index || !is_identifier(m.name) || !is_dbc_text(m.comment) ||
      !is_dbc_text(m.timing)) {
    return false;
  }
  if ((m.id_base & kNodeIdMask) != 0U || m.id_base == 0U || m.id_base > kIdBaseMask) {
    return false;
  }
  if (m.fd ? !is_valid_fd_length(m.length) : m.length > CanFrame::kMaxClassicLength) {
    return false;
  }
  if (m.receivers == 0U || m.received_by(m.sender)) {
    return false;
  }
  if (m.e2e && (m.fd || m.length != 8 || m.signals.size() < 2 || m.signals[0].name != e2e::kCrc.name ||
                m.signals[1].name != e2e::kAliveCounter.name)) {
    return false;
  }
  std::array<bool, CanFrame::kMaxFdLength * 8> used{};
  for (std::size_t i = 0; i < m.signals.size(); ++i) {
    const SignalDef& s = m.signals[i];
    if (!signal_ok(s, m)) {
      return false;
    }
    for (std::size_t j = 0; j < i; ++j) {
      if (m.signals[j].name == s.name) {
        return false;
      }
    }
    for (unsigned b = s.start_bit; b < s.start_bit + s.length; ++b) {
      if (used[b]) {
        return false;  // overlapping signals
      }
      used[b] = true;
    }
  }
  return true;
}

constexpr bool tables_ok() {
  for (std::size_t i = 0; i < kMessages.size(); ++i) {
    if (!message_ok(kMessages[i], i)) {
      return false;
    }
    // Strictly ascending IDs: MessageType order is priority order, and IDs are unique.
    if (i > 0 && kMessages[i - 1].id_base >= kMessages[i].id_base) {
      return false;
    }
  }
  for (std::size_t i = 0; i < kRoles.size(); ++i) {
    if (static_cast<std::size_t>(kRoles[i].role) != i || !is_identifier(kRoles[i].dbc_name)) {
      return false;
    }
  }
  return true;
}

static_assert(tables_ok(), "protocol.hpp: a message or signal definition is malformed");

}  // namespace
}  // namespace pmsm::hal::protocol
