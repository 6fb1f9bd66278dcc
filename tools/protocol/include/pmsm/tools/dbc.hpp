// An independent DBC reader and generic frame decoder.
//
// Written from the DBC format alone, without the protocol tables, so that tests can check
// the codec against the committed can/pmsm-thermal.dbc (a shared mistake would otherwise
// pass), and so that tools (`pmsm-thermal decode`) can decode candump logs with any DBC.
//
// Supported: VERSION, NS_, BS_, BU_, BO_, SG_ (Intel and Motorola byte order, signed and
// unsigned, simple multiplexing M / mN), CM_, VAL_, VAL_TABLE_, BA_DEF_, BA_DEF_DEF_, BA_
// (VFrameFormat decides classic / CAN FD, as cantools does), SIG_VALTYPE_ (IEEE float and
// double signals), BO_TX_BU_. Other sections are skipped to their ';'. Errors name the line.
// Not for the real-time thread: it allocates.
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "pmsm/hal/can_frame.hpp"

namespace pmsm::hal::dbc {

// what(): "line 12: expected '|' between start bit and length, found '8'" from parse(),
// "can/x.dbc:12: ..." from load().
class ParseError : public std::runtime_error {
 public:
  ParseError(int line, const std::string& message, const std::string& file = {});
  [[nodiscard]] int line() const noexcept { return line_; }  // 1-based; 0 when not tied to a line
  [[nodiscard]] const std::string& message() const noexcept { return message_; }

 private:
  int line_;
  std::string message_;
};

enum class ByteOrder : std::uint8_t { kLittleEndian, kBigEndian };  // DBC @1 (Intel), @0 (Motorola)
enum class ValueType : std::uint8_t { kInteger, kFloat32, kFloat64 };

struct ValueDescription {
  std::int64_t value = 0;
  std::string label;
};

struct Signal {
  std::string name;
  unsigned start_bit = 0;   // as written in the DBC (Motorola: the MSB, in sawtooth numbering)
  unsigned length = 0;
  ByteOrder byte_order = ByteOrder::kLittleEndian;
  bool is_signed = false;
  ValueType value_type = ValueType::kInteger;
  double factor = 1.0;
  double offset = 0.0;
  double minimum = 0.0;
  double maximum = 0.0;
  std::string unit;
  std::vector<std::string> receivers;
  std::string comment;
  std::vector<ValueDescription> values;
  bool is_multiplexer = false;
  std::optional<std::int64_t> multiplexer_value;  // set for "mN" signals

  [[nodiscard]] const ValueDescription* find_value(std::int64_t raw) const noexcept;
};

struct Message {
  std::uint32_t id = 0;     // without the DBC's extended flag (bit 31)
  bool extended = false;
  std::string name;
  unsigned length = 0;      // bytes
  bool fd = false;          // VFrameFormat StandardCAN_FD / ExtendedCAN_FD
  std::string sender;
  std::vector<std::string> extra_senders;  // BO_TX_BU_
  std::string comment;
  std::vector<Signal> signals;

  [[nodiscard]] const Signal* find_signal(std::string_view name) const noexcept;
};

struct Database {
  std::string version;
  std::vector<std::string> nodes;
  std::vector<Message> messages;
  std::string comment;

  [[nodiscard]] const Message* find(std::uint32_t id, bool extended) const noexcept;
  [[nodiscard]] const Message* find(std::string_view name) const noexcept;
};

// Parses DBC text; throws ParseError with the line number on malformed input.
[[nodiscard]] Database parse(std::string_view text);
// Reads and parses a file; throws ParseError (line 0 if the file cannot be read).
[[nodiscard]] Database load(const std::filesystem::path& path);

struct DecodedSignal {
  const Signal* signal = nullptr;
  std::int64_t raw = 0;     // integer signals; for float signals the raw bits
  double value = 0.0;       // physical
  const ValueDescription* label = nullptr;  // value-table entry matching raw, if any
};

struct DecodedFrame {
  const Message* message = nullptr;
  std::vector<DecodedSignal> signals;  // in DBC order; signals outside the frame are left out
  bool length_mismatch = false;        // frame length differs from the message's
  bool format_mismatch = false;        // classic frame for an FD message or vice versa
};

// Decodes any frame with a database; nullopt if the ID is not in it (or for error frames).
[[nodiscard]] std::optional<DecodedFrame> decode(const Database& db, const CanFrame& frame);

// Raw value of one signal in a payload (exposed for tests of the bit numbering).
[[nodiscard]] std::uint64_t extract_raw_bits(const Signal& signal, std::span<const std::uint8_t> payload);

// "NAME(Sig: 1.25 unit, Mode: SPEED, ...)", as `cantools decode --single-line` prints it.
// Numbers show as many decimals as the signal's factor needs.
[[nodiscard]] std::string format_single_line(const DecodedFrame& decoded);
[[nodiscard]] std::string format_value(const DecodedSignal& decoded);

}  // namespace pmsm::hal::dbc
