#include "pmsm/hal/journal.hpp"

#include <sys/stat.h>
#include <unistd.h>

#include <cinttypes>
#include <cstdio>
#include <cstdlib>

namespace pmsm::hal {

bool stderr_is_journal() noexcept {
  const char* stream = std::getenv("JOURNAL_STREAM");
  if (stream == nullptr) {
    return false;
  }
  std::uintmax_t device = 0;
  std::uintmax_t inode = 0;
  char rest = '\0';
  if (std::sscanf(stream, "%" SCNuMAX ":%" SCNuMAX "%c", &device, &inode, &rest) != 2) {
    return false;
  }
  struct stat st {};
  if (::fstat(STDERR_FILENO, &st) != 0) {
    return false;
  }
  const std::uintmax_t stderr_device = st.st_dev;  // dev_t and ino_t: unsigned, at most uintmax_t
  const std::uintmax_t stderr_inode = st.st_ino;
  return stderr_device == device && stderr_inode == inode;
}

}  // namespace pmsm::hal
