// The depth of a TOML text's dotted keys and table headers, checked before the text is parsed:
// toml++ (3.3, Debian 12) bounds the nesting of values but builds the tables of a dotted key
// (`a.b.c = 1`, `[a.b.c]`, `[[a.b.c]]`, also inside an inline table) by recursion, one frame per
// segment, so a key of some ten thousand segments (a 20-100 KB line, well under the readers'
// size caps) overflowed the stack: every configuration, scenario and calibration reader died on
// SIGSEGV without a word. The deepest key any of the project's files uses has four segments.
// Header only, no toml++: a scanner of the text's tokens, strings and comments opaque.
#pragma once

#include <cstddef>
#include <optional>
#include <string>
#include <string_view>

namespace pmsm::common {

inline constexpr std::size_t kMaxTomlKeyDepth = 64;

struct TomlDepthProblem {
  std::size_t line = 0;   // 1-based
  std::size_t depth = 0;  // the segments counted when the limit was passed
};

// The first place where a run of dot-separated tokens (bare words, quoted strings) outside
// strings and comments exceeds `max_depth` segments; nothing when none does. A number such as
// 1.5e-3 counts as two tokens, a date as one or two: far below any limit worth setting.
[[nodiscard]] inline std::optional<TomlDepthProblem> toml_key_depth_problem(std::string_view text,
                                                                           std::size_t max_depth = kMaxTomlKeyDepth) {
  std::size_t line = 1;
  std::size_t run = 0;         // tokens in the current dotted run
  bool after_dot = false;      // a '.' followed the last token: the next token extends the run
  bool in_token = false;       // inside a bare word
  auto token = [&] {
    run = after_dot ? run + 1 : 1;
    after_dot = false;
    return run > max_depth;
  };
  auto end_run = [&] {
    run = 0;
    after_dot = false;
  };
  const std::size_t n = text.size();
  for (std::size_t i = 0; i < n; ++i) {
    const char c = text[i];
    const bool bare = (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_' || c == '-' ||
                      c == '+';
    if (bare) {
      if (!in_token) {
        in_token = true;
        if (token()) {
          return TomlDepthProblem{line, run};
        }
      }
      continue;
    }
    in_token = false;
    if (c == '"' || c == '\'') {
      // A string, opaque: one token. Multi-line ones (""" and ''') may span lines.
      const bool multi = i + 2 < n && text[i + 1] == c && text[i + 2] == c;
      const std::string_view close = multi ? (c == '"' ? std::string_view{"\"\"\""} : std::string_view{"'''"})
                                           : (c == '"' ? std::string_view{"\""} : std::string_view{"'"});
      std::size_t j = i + close.size();
      for (; j < n; ++j) {
        if (c == '"' && text[j] == '\\') {
          ++j;  // the escaped character
          if (j < n && text[j] == '\n') {
            ++line;
          }
          continue;
        }
        if (text[j] == '\n') {
          if (!multi) {
            break;  // an unterminated one-line string: the parser says so
          }
          ++line;
        }
        if (text.compare(j, close.size(), close) == 0) {
          break;
        }
      }
      if (token()) {
        return TomlDepthProblem{line, run};
      }
      if (j < n && text[j] == '\n') {
        i = j - 1;  // the newline is seen by the loop
      } else {
        i = j < n ? j + close.size() - 1 : n;
      }
      continue;
    }
    if (c == '#') {  // a comment, to the end of its line
      while (i + 1 < n && text[i + 1] != '\n') {
        ++i;
      }
      continue;
    }
    if (c == '.') {
      after_dot = run > 0;
      continue;
    }
    if (c == ' ' || c == '\t') {
      continue;  // a key may be spaced around its dots
    }
    if (c == '\n') {
      ++line;
    }
    end_run();  // '=', brackets, braces, commas, a newline, anything else
  }
  return std::nullopt;
}

[[nodiscard]] inline std::string toml_depth_message(const TomlDepthProblem& p, std::string_view source) {
  return std::string(source) + ":" + std::to_string(p.line) + ": a key or table header nested more than " +
         std::to_string(kMaxTomlKeyDepth) + " levels deep (no configuration of this project nests more than four)";
}

}  // namespace pmsm::common
