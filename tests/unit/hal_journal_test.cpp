// hal::stderr_is_journal: systemd's convention, JOURNAL_STREAM naming stderr's device and inode.
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cstdlib>
#include <optional>
#include <string>

#include "pmsm/hal/journal.hpp"

namespace pmsm::hal {
namespace {

// Sets JOURNAL_STREAM for one test and puts back what was there.
class JournalStream {
 public:
  JournalStream() {
    if (const char* v = std::getenv("JOURNAL_STREAM")) {
      before_ = v;
    }
  }
  ~JournalStream() {
    if (before_) {
      ::setenv("JOURNAL_STREAM", before_->c_str(), 1);
    } else {
      ::unsetenv("JOURNAL_STREAM");
    }
  }
  JournalStream(const JournalStream&) = delete;
  JournalStream& operator=(const JournalStream&) = delete;
  static void set(const std::string& value) { ::setenv("JOURNAL_STREAM", value.c_str(), 1); }

 private:
  std::optional<std::string> before_;
};

TEST(Journal, StderrIsTheJournalOnlyWhereJournalStreamNamesIt) {
  JournalStream keep;
  struct stat st {};
  ASSERT_EQ(::fstat(STDERR_FILENO, &st), 0);
  const std::string mine = std::to_string(st.st_dev) + ":" + std::to_string(st.st_ino);
  JournalStream::set(mine);
  EXPECT_TRUE(stderr_is_journal()) << mine;
  // Inherited from a unit while stderr goes elsewhere (a terminal, a pipe): not the journal.
  JournalStream::set(std::to_string(st.st_dev) + ":" + std::to_string(st.st_ino + 1));
  EXPECT_FALSE(stderr_is_journal());
  for (const char* bad : {"", "8", "8:", ":12", "x:y", "8:12:3", "8:12x"}) {
    JournalStream::set(bad);
    EXPECT_FALSE(stderr_is_journal()) << "'" << bad << "'";
  }
  JournalStream::set(mine + " ");
  EXPECT_FALSE(stderr_is_journal()) << "trailing text";
  ::unsetenv("JOURNAL_STREAM");
  EXPECT_FALSE(stderr_is_journal());
}

}  // namespace
}  // namespace pmsm::hal
