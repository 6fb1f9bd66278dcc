// Command-line validators with messages that name the problem in plain words (CLI11 prefixes
// them with the option's name: "--Ld: must be a number > 0, got -1").
#pragma once

#include <CLI/CLI.hpp>

#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <string>

namespace pmsm::app {

// A number within [lo, hi]; `strict_lo` excludes lo itself.
inline CLI::Validator number_in_range(double lo, double hi, bool strict_lo = false) {
  std::string description = strict_lo ? "number > " + CLI::detail::to_string(lo)
                                      : "number in [" + CLI::detail::to_string(lo) + ", " +
                                            CLI::detail::to_string(hi) + "]";
  return CLI::Validator(
      [lo, hi, strict_lo](std::string& input) -> std::string {
        errno = 0;
        char* end = nullptr;
        const double value = std::strtod(input.c_str(), &end);
        if (end == input.c_str() || *end != '\0' || errno == ERANGE || !std::isfinite(value)) {
          return "expected a number, got '" + input + "'";
        }
        if (strict_lo ? value <= lo : value < lo) {
          return "must be " + std::string(strict_lo ? "> " : ">= ") + CLI::detail::to_string(lo) +
                 ", got " + input;
        }
        if (value > hi) {
          return "must be <= " + CLI::detail::to_string(hi) + ", got " + input;
        }
        return {};
      },
      description, "NUMBER");
}

inline CLI::Validator positive() { return number_in_range(0.0, HUGE_VAL, true); }
inline CLI::Validator non_negative() { return number_in_range(0.0, HUGE_VAL); }

}  // namespace pmsm::app
