// Reading a whole text file the program was pointed at (a configuration, a stored calibration,
// a DBC): what is wrong with the path is said in words, not read as an empty file. A directory
// (an ifstream opens one and reads nothing), a device (/dev/zero would be read forever), a
// file beyond any such file's size, and a read that fails part way are each refused.
// Header only, standard library and POSIX only.
#pragma once

#include <cerrno>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <system_error>

#include <unistd.h>

namespace pmsm::common {

inline constexpr std::uintmax_t kMaxTextFileBytes = 256U << 20U;

// Reads `path` into `text`; returns "" when it did, else what is wrong ("no such file", "is a
// directory", ...), for the caller to put behind the path and what the file is.
[[nodiscard]] inline std::string read_text_file(const std::filesystem::path& path, std::string& text) {
  std::error_code ec;
  const std::filesystem::file_status status = std::filesystem::status(path, ec);
  if (status.type() == std::filesystem::file_type::not_found) {
    return "no such file";
  }
  if (ec) {
    return "cannot read (" + ec.message() + ")";
  }
  if (status.type() == std::filesystem::file_type::directory) {
    return "is a directory";
  }
  if (status.type() != std::filesystem::file_type::regular) {
    return "is not a regular file";
  }
  const std::uintmax_t bytes = std::filesystem::file_size(path, ec);
  if (!ec && bytes > kMaxTextFileBytes) {
    return "is " + std::to_string(bytes) + " bytes, more than any such file (256 MiB)";
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    return std::string("cannot read (") + std::strerror(errno) + ")";
  }
  text.clear();
  char chunk[1U << 16U];
  // read() sets badbit on a failed read (an inserter of rdbuf() would not tell it).
  while (in.read(chunk, sizeof chunk) || in.gcount() > 0) {
    text.append(chunk, static_cast<std::size_t>(in.gcount()));
  }
  if (in.bad()) {
    return std::string("cannot read (") + std::strerror(errno) + ")";
  }
  return {};
}

// What stands in the way of writing `path` (creating or replacing a file there), in words; ""
// when nothing visible does. Checked before a long run, so that an output that cannot be written
// is said at once rather than after the run (a directory in the file's place, a directory that
// does not exist, a read-only one). A full disk shows only as the write fails.
[[nodiscard]] inline std::string writable_file_problem(const std::filesystem::path& path) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) {
    return "is a directory";
  }
  const std::filesystem::path parent = path.has_parent_path() ? path.parent_path() : std::filesystem::path(".");
  if (!std::filesystem::exists(parent, ec)) {
    return "no such directory: " + parent.string();
  }
  if (!std::filesystem::is_directory(parent, ec)) {
    return parent.string() + " is not a directory";
  }
  const bool exists = std::filesystem::exists(path, ec);
  if (::access((exists ? path : parent).c_str(), W_OK) != 0) {
    return std::string(exists ? "" : "its directory: ") + std::strerror(errno);
  }
  return {};
}

// Whether two paths name one file: the same file under two spellings (a symbolic link, "..",
// a hard link), whether or not it exists yet (an output about to be written over an input).
[[nodiscard]] inline bool same_file(const std::filesystem::path& a, const std::filesystem::path& b) {
  std::error_code ec;
  if (std::filesystem::equivalent(a, b, ec)) {
    return true;  // both there, one file (a hard link, a bind mount too)
  }
  // Absolute first: weakly_canonical leaves a relative path relative when nothing of it exists
  // yet ("x.csv"), and "./x.csv" or a stored absolute name then never compared equal to it.
  std::error_code ec_a;
  std::error_code ec_b;
  const std::filesystem::path aa = std::filesystem::absolute(a, ec_a).lexically_normal();
  const std::filesystem::path ab = std::filesystem::absolute(b, ec_b).lexically_normal();
  if (ec_a || ec_b) {
    return a.lexically_normal() == b.lexically_normal();
  }
  const std::filesystem::path ca = std::filesystem::weakly_canonical(aa, ec_a);
  const std::filesystem::path cb = std::filesystem::weakly_canonical(ab, ec_b);
  if (ec_a || ec_b) {
    return aa == ab;
  }
  return ca == cb;
}

}  // namespace pmsm::common
