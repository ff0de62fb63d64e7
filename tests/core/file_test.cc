#include "framework/core/file.h"

#include "framework/core/error.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <stdexcept>

namespace soma {
namespace {

TEST(WriteFileAtomic, WritesAndReplaces) {
  const auto dir = testing::CreateTestDir();
  const auto path = dir / "sub" / "a.txt";
  WriteFileAtomic(path, "first");
  EXPECT_EQ(ReadFile(path), "first");
  WriteFileAtomic(path, "second");
  EXPECT_EQ(ReadFile(path), "second");
  // No temp file left behind.
  int files = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir / "sub")) {
    (void)entry;
    ++files;
  }
  EXPECT_EQ(files, 1);
}

TEST(AtomicFileWriter, AbandonedWriteLeavesOldFile) {
  const auto dir = testing::CreateTestDir();
  const auto path = dir / "b.txt";
  WriteFileAtomic(path, "old");
  try {
    AtomicFileWriter writer(path);
    writer.stream() << "half of the new cont";
    throw std::runtime_error("killed");
  } catch (const std::runtime_error&) {
  }
  EXPECT_EQ(ReadFile(path), "old");
  EXPECT_FALSE(std::filesystem::exists(TempPathFor(path)));
}

TEST(ReadFile, MissingFileNamesThePath) {
  try {
    ReadFile("/nonexistent/dir/file.yaml");
    FAIL() << "expected IoError";
  } catch (const IoError& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/dir/file.yaml"),
              std::string::npos);
  }
}

}  // namespace
}  // namespace soma
