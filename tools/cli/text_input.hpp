// A text input named on the command line (decode, monitor --log): a file, or standard input
// for "-" or no name. A directory is refused by name: a std::ifstream opens one and reads
// nothing, which read as an empty log and passed every check. A read that fails is told apart
// from the end of the input. Lines are read up to kMaxLine characters: a log line is a few
// hundred at most, and an input without newlines (a binary file, /dev/zero) must not be read
// into memory whole.
#pragma once

#include <sys/stat.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <limits>
#include <string>
#include <string_view>
#include <system_error>

#include "pmsm/tools/candump.hpp"

namespace pmsm::app {

class TextInput {
 public:
  // "" when the input is open; else what is wrong with it, naming it.
  [[nodiscard]] std::string open(const std::string& path) {
    from_stdin_ = path.empty() || path == "-";
    if (from_stdin_) {
      name_ = "stdin";
      struct stat st {};
      if (::fstat(STDIN_FILENO, &st) == 0 && S_ISDIR(st.st_mode)) {
        return "standard input is a directory, not a file";
      }
      return {};
    }
    name_ = path;
    std::error_code ec;
    if (std::filesystem::is_directory(path, ec)) {
      return "'" + path + "' is a directory, not a file";
    }
    file_.open(path, std::ios::binary);
    if (!file_) {
      return "cannot open '" + path + "': " + std::strerror(errno);
    }
    return {};
  }
  [[nodiscard]] std::istream& stream() { return from_stdin_ ? std::cin : file_; }

  static constexpr std::size_t kMaxLine = 4096;
  // The next line into `line`, without its newline; false at the end of the input or on a read
  // error (failed()). A line longer than kMaxLine characters comes cut there, the rest of it
  // skipped, with `too_long` set.
  [[nodiscard]] bool next_line(std::string& line, bool& too_long) {
    too_long = false;
    std::istream& in = stream();
    in.getline(buffer_.data(), static_cast<std::streamsize>(buffer_.size()));
    const auto got = static_cast<std::size_t>(in.gcount());
    if (in.bad()) {
      return false;
    }
    if (in.fail()) {
      if (got == 0) {
        return false;  // nothing left
      }
      // The buffer filled before a newline came.
      too_long = true;
      in.clear();
      in.ignore(std::numeric_limits<std::streamsize>::max(), '\n');
      line.assign(buffer_.data(), kMaxLine);
      return !in.bad();
    }
    // gcount counts the newline, which is not stored, unless the input ended first.
    line.assign(buffer_.data(), in.eof() ? got : got - 1);
    return true;
  }
  // A line next_line() gave, as a candump frame: one it cut is none, whatever it holds.
  [[nodiscard]] static hal::candump::ParseResult parse_candump(std::string_view line, bool too_long) {
    if (too_long) {
      return {.record = std::nullopt,
              .error = "longer than " + std::to_string(kMaxLine) + " characters (the rest of it skipped)"};
    }
    return hal::candump::parse_line(line);
  }
  // Said when an input had lines and not a single candump frame: it is no capture.
  [[nodiscard]] std::string no_frame_error() const {
    return "no line of '" + name_ + "' is a candump frame: not a capture";
  }
  // A read error, not the end of the input (std::cin reads through stdio: its errors are
  // stdin's).
  [[nodiscard]] bool failed() { return stream().bad() || (from_stdin_ && std::ferror(stdin) != 0); }
  [[nodiscard]] bool from_stdin() const { return from_stdin_; }
  [[nodiscard]] const std::string& name() const { return name_; }

 private:
  bool from_stdin_ = true;
  std::string name_ = "stdin";
  std::ifstream file_;
  std::array<char, kMaxLine + 1> buffer_{};
};

}  // namespace pmsm::app
