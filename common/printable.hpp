// Quoting input back in a message: a log line, a configured name or a command-line value may
// carry terminal escapes, and a message prints them to the reader's terminal or the journal.
// Header only, standard library only.
#pragma once

#include <cstddef>
#include <cstdio>
#include <string>
#include <string_view>

namespace pmsm::common {

// `text` with its control characters (below 0x20, and 0x7f) as \xNN and at most `max_chars` of
// it, followed by "..." when cut.
[[nodiscard]] inline std::string printable_excerpt(std::string_view text, std::size_t max_chars = 64) {
  std::string out;
  for (const char ch : text.substr(0, max_chars)) {
    const auto u = static_cast<unsigned char>(ch);
    if (u < 0x20U || u == 0x7fU) {
      char code[8];
      std::snprintf(code, sizeof code, "\\x%02x", static_cast<unsigned>(u));
      out += code;
    } else {
      out += ch;
    }
  }
  return text.size() > max_chars ? out + "..." : out;
}

}  // namespace pmsm::common
