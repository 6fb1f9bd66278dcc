// candump (can-utils) output lines <-> CanFrame, and decoding them with a DBC, for the
// `pmsm-thermal decode` tool and tests. Formats (classic and CAN FD):
//   default:  "  vcan0  123   [4]  DE AD BE EF"        FD: "  vcan0  123  [12]  00 11 ..."
//   -ta/-td/-tz: "(1436509052.249713)  vcan0  123   [4]  DE AD BE EF"
//   -tA:      "(2015-07-10 08:17:32.249713)  vcan0  123   [4]  DE AD BE EF"
//   -L (log): "(1436509052.249713) vcan0 123#DEADBEEF"  FD: "... 123##1DEADBEEF" where the
//             digit after "##" is the CAN FD flags nibble (BRS = 1, ESI = 2, FDF = 4).
// Also accepted: -x (RX/TX, BRS, ESI columns), -a (ASCII column), error frames (8-digit ID
// with 0x20000000 set), remote requests, extended IDs (8 digits). Classic lengths print as
// one digit "[4]", CAN FD lengths as two "[04]", which is how the default format tells
// them apart. Malformed lines give an error message, never an exception or a crash.
#pragma once

#include <chrono>
#include <optional>
#include <string>
#include <string_view>

#include "pmsm/hal/can_frame.hpp"
#include "pmsm/tools/dbc.hpp"

namespace pmsm::hal::candump {

enum class Format : std::uint8_t {
  kDefault,      // no timestamp
  kTimestamped,  // -ta, -td, -tz, -tA
  kLog,          // -L
};

struct Record {
  Format format = Format::kDefault;
  // As printed: since the epoch (-ta, -L; -tA read as UTC), since the first frame (-tz) or
  // since the previous frame (-td). Empty without a timestamp.
  std::optional<std::chrono::nanoseconds> timestamp;
  std::string interface;
  CanFrame frame;
  bool remote_request = false;  // CanFrame has no RTR flag; such frames carry no data
};

struct ParseResult {
  std::optional<Record> record;
  std::string error;  // why the line was rejected; empty when record is set

  [[nodiscard]] bool ok() const noexcept { return record.has_value(); }
};

[[nodiscard]] ParseResult parse_line(std::string_view line);

// The candump -L form of a record: "(seconds.micros) iface ID#DATA" or "ID##FDATA".
[[nodiscard]] std::string to_log_line(const Record& record);

struct DecodedLine {
  std::string text;     // the input line, then " :: NAME(...)" or " :: Unknown frame id ..."
  bool parsed = false;  // the line was a frame
  bool known = false;   // the frame's ID is in the database
};

// One line of `candump` output decoded like `cantools decode --single-line`. Lines that are
// not frames come back unchanged (parsed = false).
[[nodiscard]] DecodedLine decode_line(const dbc::Database& db, std::string_view line);

}  // namespace pmsm::hal::candump
