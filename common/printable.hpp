// Quoting input back in a message: a log line, a configured name or a command-line value may
// carry terminal escapes, and a message prints them to the reader's terminal or the journal.
// Header only, standard library only.
#pragma once

#include <cstddef>
#include <cstdio>
#include <string>
#include <string_view>

namespace pmsm::common {

// Whether text[i] begins a C1 control in UTF-8 (U+0080-U+009F: C2 80 to C2 9F), which a
// terminal may take as an escape.
[[nodiscard]] inline bool c1_control_at(std::string_view text, std::size_t i) {
  return i + 1 < text.size() && static_cast<unsigned char>(text[i]) == 0xC2U &&
         static_cast<unsigned char>(text[i + 1]) < 0xA0U && static_cast<unsigned char>(text[i + 1]) >= 0x80U;
}

// `text` with its control characters as \xNN (C0, DEL, and the C1 controls U+0080-U+009F,
// which a terminal may take as an escape; tabs too unless `keep_tabs`) and at most `max_chars`
// bytes of it, followed by "..." when cut. A well-formed UTF-8 sequence passes whole; any other
// byte at or above 0x80 is shown as \xNN.
[[nodiscard]] inline std::string printable_excerpt(std::string_view text, std::size_t max_chars = 64,
                                                   bool keep_tabs = false) {
  std::string out;
  const std::string_view cut = text.substr(0, max_chars);
  const auto hex = [&out](unsigned byte) {
    char code[8];
    std::snprintf(code, sizeof code, "\\x%02x", byte);
    out += code;
  };
  std::size_t i = 0;
  while (i < cut.size()) {
    const auto u = static_cast<unsigned char>(cut[i]);
    if (u < 0x80U) {
      if ((u < 0x20U && !(keep_tabs && u == '\t')) || u == 0x7fU) {
        hex(u);
      } else {
        out += cut[i];
      }
      ++i;
      continue;
    }
    std::size_t length = 0;
    if (u >= 0xC2U && u <= 0xDFU) {
      length = 2;
    } else if (u >= 0xE0U && u <= 0xEFU) {
      length = 3;
    } else if (u >= 0xF0U && u <= 0xF4U) {
      length = 4;
    }
    bool whole = length > 0 && i + length <= cut.size();
    for (std::size_t k = 1; whole && k < length; ++k) {
      whole = (static_cast<unsigned char>(cut[i + k]) & 0xC0U) == 0x80U;
    }
    if (whole && c1_control_at(cut, i)) {
      whole = false;
    }
    if (whole) {
      out.append(cut.substr(i, length));
      i += length;
    } else {
      hex(u);
      ++i;
    }
  }
  return text.size() > max_chars ? out + "..." : out;
}

}  // namespace pmsm::common
