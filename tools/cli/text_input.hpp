// A text input named on the command line (decode, monitor --log): a file, or standard input
// for "-" or no name. A directory is refused by name: a std::ifstream opens one and reads
// nothing, which read as an empty log and passed every check. A read that fails is told apart
// from the end of the input.
#pragma once

#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <string>
#include <system_error>

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
  // A read error, not the end of the input (std::cin reads through stdio: its errors are
  // stdin's).
  [[nodiscard]] bool failed() { return stream().bad() || (from_stdin_ && std::ferror(stdin) != 0); }
  [[nodiscard]] bool from_stdin() const { return from_stdin_; }
  [[nodiscard]] const std::string& name() const { return name_; }

 private:
  bool from_stdin_ = true;
  std::string name_ = "stdin";
  std::ifstream file_;
};

}  // namespace pmsm::app
