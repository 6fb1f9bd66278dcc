// Command-line validators of every executable (pmsm-thermal, pmsm-plant), with messages that
// name the problem in plain words (CLI11 prefixes them with the option's name:
// "--Ld: must be a number > 0, got -1"). NaN, inf and numbers beyond double are refused by
// every one of them, which CLI::Range does not do (NaN compares false both ways).
// Header only; the executable that includes it links CLI11.
#pragma once

#include <CLI/CLI.hpp>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <sstream>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "standard_output.hpp"

namespace pmsm::cli {

// A number within [lo, hi]; `strict_lo` excludes lo itself.
inline CLI::Validator number_in_range(double lo, double hi, bool strict_lo = false) {
  // (The upper bound shown too where there is one: "number > 0" was refused above 100000.)
  std::string description = strict_lo && !std::isfinite(hi) ? "number > " + CLI::detail::to_string(lo)
                            : (strict_lo ? "number in (" : "number in [") + CLI::detail::to_string(lo) + ", " +
                                  CLI::detail::to_string(hi) + "]";
  return CLI::Validator(
      [lo, hi, strict_lo](std::string& input) -> std::string {
        errno = 0;
        char* end = nullptr;
        const double value = std::strtod(input.c_str(), &end);
        // Decimal only, as the files read numbers (strtod took 0x10 as 16).
        if (end == input.c_str() || *end != '\0' || errno == ERANGE || !std::isfinite(value) ||
            input.find_first_of("xX") != std::string::npos) {
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

// A whole number within [lo, hi] (CLI::Range said "Value abc not in range 0 to 15" of a word).
inline CLI::Validator integer_in_range(long long lo, long long hi) {
  return CLI::Validator(
      [lo, hi](std::string& input) -> std::string {
        errno = 0;
        char* end = nullptr;
        const long long value = std::strtoll(input.c_str(), &end, 10);
        if (end == input.c_str() || *end != '\0' || errno == ERANGE) {
          return "expected a whole number, got '" + input + "'";
        }
        if (value < lo || value > hi) {
          return "must be in [" + std::to_string(lo) + ", " + std::to_string(hi) + "], got " + input;
        }
        return {};
      },
      "whole number in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]", "INT");
}

// Physical options take a finite upper bound too: a value far beyond any machine is a typo, and
// printing inf or nan as a planning result would be worse than refusing it.
inline CLI::Validator positive(double hi = HUGE_VAL) { return number_in_range(0.0, hi, true); }
inline CLI::Validator non_negative(double hi = HUGE_VAL) { return number_in_range(0.0, hi); }

// A text checked by a rule that names what is wrong with it, "" when nothing is (e.g.
// hal::can_interface_name_problem for an --iface): any callable taking a std::string_view.
template <class Rule>
CLI::Validator text_rule(Rule rule, std::string type_name) {
  return CLI::Validator([rule = std::move(rule)](std::string& text) { return std::string(rule(text)); },
                        std::move(type_name));
}

// A file or directory name: an empty one, given explicitly (--csv ''), is refused rather than
// read as "not given" (which wrote nothing, or read standard input, and said nothing).
inline CLI::Validator file_name() {
  return text_rule([](std::string_view text) { return text.empty() ? "expected a file name, got an empty one" : ""; },
                   "FILE");
}

// The exit code of a command line CLI11 refused, with its message printed: 0 for --help and
// --version (`write_failed_code`, naming `program`, when their text did not all reach standard
// output: a full disk), else `usage_exit_code`. CLI11 checks the required options before the words it did
// not know, so `--bogus` alone, or a misspelt flag beside a required one, read "A subcommand is
// required" or "--voltage is required" and never named the word: it is named first here.
inline int exit_on_parse_error(const CLI::App& app, const CLI::ParseError& e, int usage_exit_code,
                               const char* program, int write_failed_code) {
  const std::vector<std::string> unknown = app.remaining(true);
  if (e.get_exit_code() != 0 && !unknown.empty() && dynamic_cast<const CLI::ExtrasError*>(&e) == nullptr) {
    std::fprintf(stderr, "%s\n", CLI::ExtrasError(unknown).what());
  }
  if (e.get_exit_code() != 0) {
    (void)app.exit(e);
    return usage_exit_code;
  }
  // --help or --version: their text rendered here and written in one go, so that a failed write
  // is named with its own reason ("No space left on device"); CLI11 writes and flushes it itself,
  // and what its failed write left in errno was gone by the check.
  std::ostringstream text;
  (void)app.exit(e, text, std::cerr);
  (void)write_standard_output(text.str());
  return exit_with_standard_output_checked(program, 0, write_failed_code);
}

}  // namespace pmsm::cli
