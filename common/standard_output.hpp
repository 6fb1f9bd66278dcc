// A command's standard output, checked at its end (pmsm-thermal, pmsm-thermald --keys and
// --check, pmsm-dbc-gen). Header only.
#pragma once

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <string>
#include <string_view>

namespace pmsm::cli {

// The errno of the first write_standard_output() that failed (0: none failed).
inline int& standard_output_errno() {
  static int error = 0;
  return error;
}

// Writes `text` to standard output and flushes it, keeping a failure's errno for
// standard_output_failure(): a text written in one go is named with its own reason ("No space
// left on device"), where pieces written through the stream leave only its error flag.
inline bool write_standard_output(std::string_view text) {
  errno = 0;
  const bool written = std::fwrite(text.data(), 1, text.size(), stdout) == text.size() && std::fflush(stdout) == 0;
  if (!written && standard_output_errno() == 0) {
    standard_output_errno() = errno != 0 ? errno : EIO;
  }
  return written;
}

// Standard output flushed and checked at a command's end: a full disk (or any failed write)
// must not pass as done. Empty when everything reached it, else the reason ("No space left on
// device" where the failed write's is still known, else "a write failed"). (A closed pipe ends
// the process with SIGPIPE before this, as for any program.)
inline std::string standard_output_failure() {
  // (The reason is the failed write's where it is still known: a write that failed during the
  // command has left only the stream's error flag.)
  errno = 0;
  std::cout.flush();
  int error = errno;
  const bool flushed = std::fflush(stdout) == 0;
  error = error != 0 ? error : errno;
  if (flushed && std::ferror(stdout) == 0 && std::cout.good()) {
    return {};
  }
  error = error != 0 ? error : standard_output_errno();
  return error != 0 ? std::strerror(error) : "a write failed";
}

// A command's exit status with its standard output checked: a command that succeeded (`code`
// 0) but whose output did not all reach standard output says so on standard error (`program:
// cannot write standard output (reason)`) and exits `write_failed_code`. A command that failed
// keeps its own code and its own message (one that wrote to standard output itself, as `dbc`
// does, has named the failure already).
inline int exit_with_standard_output_checked(const char* program, int code, int write_failed_code) {
  if (code != 0) {
    return code;
  }
  const std::string failure = standard_output_failure();
  if (failure.empty()) {
    return code;
  }
  std::fprintf(stderr, "%s: cannot write standard output (%s)\n", program, failure.c_str());
  return write_failed_code;
}

}  // namespace pmsm::cli
