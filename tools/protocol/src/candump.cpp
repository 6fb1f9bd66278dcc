#include "pmsm/tools/candump.hpp"

#include "can_interface_name.hpp"
#include "printable.hpp"

#include <charconv>
#include <cinttypes>
#include <cstdio>
#include <vector>

namespace pmsm::hal::candump {
namespace {

// A piece of the line as an error message quotes it: control characters as \xNN (a log's
// terminal escapes went raw to the reader's terminal through the message), at most 64
// characters.
std::string shown(std::string_view text) { return common::printable_excerpt(text); }

constexpr std::uint32_t kErrFlag = 0x2000'0000U;   // CAN_ERR_FLAG as candump prints it
constexpr std::uint32_t kEffMask = 0x1FFF'FFFFU;
constexpr std::uint32_t kSffMask = 0x7FFU;
constexpr std::uint8_t kFdFlagBrs = 0x1;

bool is_space(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\n'; }

std::string_view trim(std::string_view s) {
  while (!s.empty() && is_space(s.front())) {
    s.remove_prefix(1);
  }
  while (!s.empty() && is_space(s.back())) {
    s.remove_suffix(1);
  }
  return s;
}

std::vector<std::string_view> split(std::string_view s) {
  std::vector<std::string_view> out;
  std::size_t i = 0;
  while (i < s.size()) {
    while (i < s.size() && is_space(s[i])) {
      ++i;
    }
    const std::size_t start = i;
    while (i < s.size() && !is_space(s[i])) {
      ++i;
    }
    if (i > start) {
      out.push_back(s.substr(start, i - start));
    }
  }
  return out;
}

int hex_digit(char c) {
  if (c >= '0' && c <= '9') {
    return c - '0';
  }
  if (c >= 'A' && c <= 'F') {
    return c - 'A' + 10;
  }
  if (c >= 'a' && c <= 'f') {
    return c - 'a' + 10;
  }
  return -1;
}

bool parse_hex(std::string_view s, std::uint32_t& out) {
  if (s.empty() || s.size() > 8) {
    return false;
  }
  std::uint32_t value = 0;
  for (const char c : s) {
    const int d = hex_digit(c);
    if (d < 0) {
      return false;
    }
    value = (value << 4U) | static_cast<std::uint32_t>(d);
  }
  out = value;
  return true;
}

bool parse_byte(std::string_view s, std::uint8_t& out) {
  std::uint32_t value = 0;
  if (s.size() != 2 || !parse_hex(s, value)) {
    return false;
  }
  out = static_cast<std::uint8_t>(value);
  return true;
}

bool parse_decimal(std::string_view s, std::int64_t& out) {
  if (s.empty()) {
    return false;
  }
  const auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), out);
  return ec == std::errc() && ptr == s.data() + s.size() && out >= 0;
}

// "seconds[.fraction]" -> nanoseconds.
std::optional<std::chrono::nanoseconds> parse_seconds(std::string_view s) {
  const std::size_t dot = s.find('.');
  std::int64_t seconds = 0;
  if (!parse_decimal(s.substr(0, dot), seconds) || seconds > 9'000'000'000LL) {
    return std::nullopt;
  }
  std::int64_t nanos = 0;
  if (dot != std::string_view::npos) {
    const std::string_view fraction = s.substr(dot + 1);
    if (fraction.empty() || fraction.size() > 9 || !parse_decimal(fraction, nanos)) {
      return std::nullopt;
    }
    for (std::size_t i = fraction.size(); i < 9; ++i) {
      nanos *= 10;
    }
  }
  return std::chrono::nanoseconds(seconds * 1'000'000'000LL + nanos);
}

// "YYYY-MM-DD HH:MM:SS.ffffff" (candump -tA), read as UTC.
std::optional<std::chrono::nanoseconds> parse_date_time(std::string_view s) {
  if (s.size() < 19 || s[4] != '-' || s[7] != '-' || s[10] != ' ' || s[13] != ':' || s[16] != ':') {
    return std::nullopt;
  }
  std::int64_t y = 0;
  std::int64_t mo = 0;
  std::int64_t d = 0;
  std::int64_t h = 0;
  std::int64_t mi = 0;
  if (!parse_decimal(s.substr(0, 4), y) || !parse_decimal(s.substr(5, 2), mo) || !parse_decimal(s.substr(8, 2), d) ||
      !parse_decimal(s.substr(11, 2), h) || !parse_decimal(s.substr(14, 2), mi) || h > 23 || mi > 59) {
    return std::nullopt;
  }
  // The range parse_seconds() accepts (up to 9e9 s since the epoch): nanoseconds since the
  // epoch in 64 bits end in 2262, and candump prints no date before 1970. Found by fuzzing
  // (tests/fuzz/fuzz_candump): year 9999 overflowed the conversion (undefined behaviour).
  if (y < 1970 || y > 2255) {
    return std::nullopt;
  }
  const std::chrono::year_month_day date{std::chrono::year{static_cast<int>(y)},
                                          std::chrono::month{static_cast<unsigned>(mo)},
                                          std::chrono::day{static_cast<unsigned>(d)}};
  if (!date.ok()) {
    return std::nullopt;
  }
  const std::optional<std::chrono::nanoseconds> sec = parse_seconds(s.substr(17));
  if (!sec || *sec >= std::chrono::seconds(61)) {
    return std::nullopt;
  }
  return std::chrono::sys_days(date).time_since_epoch() + std::chrono::hours(h) + std::chrono::minutes(mi) + *sec;
}

// Sets id / extended / error from a 3- or 8-digit candump identifier.
std::string parse_identifier(std::string_view text, CanFrame& frame) {
  std::uint32_t id = 0;
  if ((text.size() != 3 && text.size() != 8) || !parse_hex(text, id)) {
    return "bad CAN identifier '" + shown(text) + "' (3 or 8 hex digits expected)";
  }
  if (text.size() == 3) {
    if (id > kSffMask) {
      return "standard identifier " + std::string(text) + " exceeds 7FF";
    }
    frame.id = id;
    return {};
  }
  if ((id & kErrFlag) != 0U) {
    frame.error = true;
    frame.id = id & kEffMask;
    return {};
  }
  if (id > kEffMask) {
    return "extended identifier " + std::string(text) + " exceeds 1FFFFFFF";
  }
  frame.extended = true;
  frame.id = id;
  return {};
}

// "123#DEADBEEF", "123##1DEADBEEF", "123#R", "123#R4", "123#11223344_9" (len8_dlc).
std::string parse_compact(std::string_view text, Record& record) {
  CanFrame& frame = record.frame;
  const std::size_t hash = text.find('#');
  if (std::string error = parse_identifier(text.substr(0, hash), frame); !error.empty()) {
    return error;
  }
  std::string_view data = text.substr(hash + 1);
  std::size_t max_length = CanFrame::kMaxClassicLength;
  if (!data.empty() && (data[0] == 'R' || data[0] == 'r')) {
    if (data.size() > 2 || (data.size() == 2 && (hex_digit(data[1]) < 0 || hex_digit(data[1]) > 8))) {
      return "bad remote request '" + shown(text) + "'";
    }
    record.remote_request = true;
    return {};
  }
  if (!data.empty() && data[0] == '#') {
    if (data.size() < 2 || hex_digit(data[1]) < 0) {
      return "missing CAN FD flags after '##' in '" + shown(text) + "'";
    }
    frame.fd = true;
    frame.bitrate_switch = (static_cast<unsigned>(hex_digit(data[1])) & kFdFlagBrs) != 0U;
    data.remove_prefix(2);
    max_length = CanFrame::kMaxFdLength;
  } else if (const std::size_t underscore = data.find('_'); underscore != std::string_view::npos) {
    // Classic frame with a raw DLC 9..F beyond its 8 bytes: the DLC is not kept.
    const std::string_view dlc = data.substr(underscore + 1);
    if (dlc.size() != 1 || hex_digit(dlc[0]) < 9) {
      return "bad DLC suffix in '" + shown(text) + "'";
    }
    data = data.substr(0, underscore);
  }
  std::size_t length = 0;
  std::size_t i = 0;
  while (i < data.size()) {
    if (data[i] == '.') {  // optional separators (cansend syntax)
      ++i;
      continue;
    }
    if (length == max_length) {
      return "too many data bytes in '" + shown(text) + "'";
    }
    if (i + 1 >= data.size() || !parse_byte(data.substr(i, 2), frame.data[length])) {
      return "bad data bytes in '" + shown(text) + "'";
    }
    ++length;
    i += 2;
  }
  if (frame.fd && !is_valid_fd_length(length)) {
    return "invalid CAN FD length " + std::to_string(length);
  }
  frame.length = static_cast<std::uint8_t>(length);
  return {};
}

// The default / timestamped layout after the interface: [RX|TX B|- E|-] ID [len] bytes [extra].
std::string parse_columns(const std::vector<std::string_view>& tokens, std::size_t index, Record& record) {
  CanFrame& frame = record.frame;
  const auto missing = [&](std::string_view what) { return "missing " + std::string(what); };
  if (index < tokens.size() && (tokens[index] == "RX" || tokens[index] == "TX")) {  // candump -x
    if (index + 2 >= tokens.size() || (tokens[index + 1] != "-" && tokens[index + 1] != "B") ||
        (tokens[index + 2] != "-" && tokens[index + 2] != "E")) {
      return "bad -x columns";
    }
    frame.bitrate_switch = tokens[index + 1] == "B";
    index += 3;
  }
  if (index >= tokens.size()) {
    return missing("CAN identifier");
  }
  if (std::string error = parse_identifier(tokens[index], frame); !error.empty()) {
    return error;
  }
  ++index;
  if (index >= tokens.size()) {
    return missing("length '[n]'");
  }
  const std::string_view len = tokens[index];
  std::int64_t length = 0;
  if (len.size() < 3 || len.front() != '[' || len.back() != ']' || len.size() > 4 ||
      !parse_decimal(len.substr(1, len.size() - 2), length)) {
    return "bad length field '" + shown(len) + "'";
  }
  frame.fd = len.size() == 4;  // "[12]": CAN FD prints two digits, classic one
  if (frame.fd ? !is_valid_fd_length(static_cast<std::size_t>(length))
               : length > static_cast<std::int64_t>(CanFrame::kMaxClassicLength)) {
    return "invalid length " + std::string(len);
  }
  if (!frame.fd && frame.bitrate_switch) {
    return "bit-rate switch on a classic frame";
  }
  ++index;
  if (index + 1 < tokens.size() && tokens[index] == "remote" && tokens[index + 1] == "request") {
    if (frame.fd) {  // found by tests/fuzz/fuzz_candump: CAN FD has no remote frames
      return "remote request on a CAN FD frame (two-digit length " + std::string(len) + ")";
    }
    record.remote_request = true;
    index += 2;
    if (index < tokens.size()) {
      return "unexpected text after remote request";
    }
    return {};
  }
  for (std::int64_t i = 0; i < length; ++i, ++index) {
    if (index >= tokens.size()) {
      return "expected " + std::to_string(length) + " data bytes, found " + std::to_string(i);
    }
    if (!parse_byte(tokens[index], frame.data[static_cast<std::size_t>(i)])) {
      return "bad data byte '" + shown(tokens[index]) + "'";
    }
  }
  frame.length = static_cast<std::uint8_t>(length);
  if (index < tokens.size()) {
    const std::string_view extra = tokens[index];
    const bool ascii = extra.front() == '\'' || extra.front() == '`';  // candump -a
    const bool error_tag = frame.error && extra == "ERRORFRAME";
    if (!ascii && !error_tag) {
      return "unexpected text '" + shown(extra) + "' after the data";
    }
  }
  return {};
}

}  // namespace

ParseResult parse_line(std::string_view line) {
  ParseResult result;
  Record record;
  std::string_view rest = trim(line);
  if (rest.empty()) {
    result.error = "empty line";
    return result;
  }
  if (rest.front() == '(') {
    const std::size_t close = rest.find(')');
    if (close == std::string_view::npos) {
      result.error = "unterminated timestamp";
      return result;
    }
    const std::string_view stamp = rest.substr(1, close - 1);
    record.timestamp = stamp.find('-') != std::string_view::npos ? parse_date_time(stamp) : parse_seconds(stamp);
    if (!record.timestamp) {
      result.error = "bad timestamp '(" + shown(stamp) + ")'";
      return result;
    }
    record.format = Format::kTimestamped;
    rest = rest.substr(close + 1);
  }
  const std::vector<std::string_view> tokens = split(rest);
  if (tokens.size() < 2) {
    result.error = "expected an interface and a frame";
    return result;
  }
  // decode and monitor print the interface back: a name can.interface would refuse (the
  // kernel's rule, and no control character) is no candump line.
  if (const std::string problem = common::can_interface_name_problem(tokens[0]); !problem.empty()) {
    result.error = "bad interface: " + problem;
    return result;
  }
  record.interface = std::string(tokens[0]);
  std::string error;
  if (tokens[1].find('#') != std::string_view::npos) {
    record.format = Format::kLog;
    error = parse_compact(tokens[1], record);
    if (error.empty() && (tokens.size() > 3 || (tokens.size() == 3 && tokens[2] != "R" && tokens[2] != "T"))) {
      error = "unexpected text after the frame";
    }
  } else {
    error = parse_columns(tokens, 1, record);
  }
  if (!error.empty()) {
    result.error = std::move(error);
    return result;
  }
  result.record = std::move(record);
  return result;
}

std::string to_log_line(const Record& record) {
  const CanFrame& f = record.frame;
  const std::int64_t ns = record.timestamp ? record.timestamp->count() : 0;
  char buffer[64];
  const long long seconds = ns / 1'000'000'000;
  const long long micros = (ns % 1'000'000'000) / 1000;
  std::snprintf(buffer, sizeof buffer, "(%lld.%06lld) ", seconds, micros);
  std::string out = buffer;
  out += record.interface;
  out += ' ';
  if (f.error) {
    std::snprintf(buffer, sizeof buffer, "%08" PRIX32 "#", (f.id & kEffMask) | kErrFlag);
  } else if (f.extended) {
    std::snprintf(buffer, sizeof buffer, "%08" PRIX32 "#", f.id & kEffMask);
  } else {
    std::snprintf(buffer, sizeof buffer, "%03" PRIX32 "#", f.id & kSffMask);
  }
  out += buffer;
  if (record.remote_request) {
    out += 'R';
    return out;
  }
  if (f.fd) {
    out += f.bitrate_switch ? "#1" : "#0";
  }
  const std::size_t length = std::min<std::size_t>(f.length, f.data.size());
  for (std::size_t i = 0; i < length; ++i) {
    std::snprintf(buffer, sizeof buffer, "%02X", static_cast<unsigned>(f.data[i]));
    out += buffer;
  }
  return out;
}

DecodedLine decode_line(const dbc::Database& db, std::string_view line) {
  DecodedLine out;
  while (!line.empty() && (line.back() == '\n' || line.back() == '\r')) {
    line.remove_suffix(1);
  }
  out.text = std::string(line);
  const ParseResult parsed = parse_line(line);
  if (!parsed.ok()) {
    return out;
  }
  out.parsed = true;
  const CanFrame& frame = parsed.record->frame;
  char buffer[96];
  if (frame.error) {
    std::snprintf(buffer, sizeof buffer, " :: Error frame (class 0x%" PRIX32 ")", frame.id);
    out.text += buffer;
    return out;
  }
  const std::optional<dbc::DecodedFrame> decoded = dbc::decode(db, frame);
  if (!decoded) {
    std::snprintf(buffer, sizeof buffer, " :: Unknown frame id %" PRIu32 " (0x%" PRIx32 ")", frame.id, frame.id);
    out.text += buffer;
    return out;
  }
  out.known = true;
  out.text += " :: ";
  out.text += dbc::format_single_line(*decoded);
  return out;
}

}  // namespace pmsm::hal::candump
