// The test support code the other tests stand on (tests/support).
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <string>
#include <system_error>

#include "scratch_dir.hpp"

namespace pmsm::test {
namespace {

namespace fs = std::filesystem;

// A scratch directory is made under the temporary directory with its prefix, is its own (two
// made at once differ), and is gone with what a test left in it, a read-only directory
// included, when the object goes.
TEST(ScratchDir, IsUniqueAndRemovedWithItsContents) {
  fs::path first;
  fs::path second;
  {
    const ScratchDir a{"pmsm-support-test"};
    const ScratchDir b{"pmsm-support-test"};
    first = a.path();
    second = b.path();
    EXPECT_NE(first, second);
    EXPECT_TRUE(fs::is_directory(first));
    EXPECT_TRUE(fs::equivalent(first.parent_path(), fs::temp_directory_path())) << first;
    EXPECT_EQ(first.filename().string().rfind("pmsm-support-test-", 0), 0U) << first;
    EXPECT_EQ(a / "x.toml", first / "x.toml");
    fs::create_directories(a / "sub" / "deeper");
    std::ofstream(a / "sub" / "deeper" / "file.txt") << "text";
    fs::permissions(first, fs::perms::owner_read | fs::perms::owner_exec);  // taken away by a test
  }
  EXPECT_FALSE(fs::exists(first));
  EXPECT_FALSE(fs::exists(second));
}

// A temporary directory that cannot be made is an error that says where.
TEST(ScratchDir, AnImpossiblePrefixThrowsNamingThePath) {
  try {
    const ScratchDir d{"no-such-directory/pmsm"};
    ADD_FAILURE() << "made " << d.path();
  } catch (const std::system_error& e) {
    EXPECT_NE(std::string(e.what()).find("mkdtemp " + (fs::temp_directory_path() / "no-such-directory/pmsm-").string()),
              std::string::npos)
        << e.what();
    EXPECT_EQ(e.code(), std::errc::no_such_file_or_directory) << e.what();
  }
}

}  // namespace
}  // namespace pmsm::test
