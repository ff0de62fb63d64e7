#include "framework/core/provenance.h"

#include "framework/core/file.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <filesystem>

namespace soma {
namespace {

using ::testing::HasSubstr;

GitState Checkout(std::string sha, bool dirty) {
  GitState git;
  git.available = true;
  git.sha = std::move(sha);
  git.dirty = dirty;
  return git;
}

TEST(Provenance, CommitLabelMarksUncommittedChanges) {
  EXPECT_EQ(CommitLabel(Checkout("abc", false)), "abc");
  EXPECT_EQ(CommitLabel(Checkout("abc", true)), "abc-dirty");
  EXPECT_EQ(CommitLabel(GitState{}), "unknown");
}

TEST(Provenance, BinaryCompiledAtAnotherCommitIsReported) {
  EXPECT_EQ(BuildCommitMismatch("abc", Checkout("abc", false)), "");
  EXPECT_EQ(BuildCommitMismatch("abc-dirty", Checkout("abc", true)), "");
  EXPECT_EQ(BuildCommitMismatch("unknown", Checkout("abc", false)), "");
  EXPECT_EQ(BuildCommitMismatch("abc", GitState{}), "");
  const std::string moved = BuildCommitMismatch("abc", Checkout("def", false));
  EXPECT_THAT(moved, HasSubstr("compiled at commit abc"));
  EXPECT_THAT(moved, HasSubstr("checkout is at def"));
  EXPECT_THAT(BuildCommitMismatch("abc", Checkout("abc", true)),
              HasSubstr("checkout is at abc-dirty"));
}

TEST(Provenance, BuildRecordsTheCommitOfThisCheckout) {
  // The test binary was compiled from this checkout: its commit is the
  // checkout's HEAD, possibly with "-dirty" (this test cannot know whether
  // the tree changed after the build, only that the SHA is HEAD's).
  const GitState git = QueryGit();
  if (!git.available || git.sha.empty()) GTEST_SKIP() << "not a git checkout";
  EXPECT_EQ(GetBuildInfo().git_commit.substr(0, git.sha.size()), git.sha);
}

TEST(Provenance, CpuModelComesFromCpuinfo) {
  const std::filesystem::path cpuinfo = "/proc/cpuinfo";
  if (!std::filesystem::exists(cpuinfo) ||
      ReadFile(cpuinfo).find("model name") == std::string::npos) {
    GTEST_SKIP() << "no model name in /proc/cpuinfo";
  }
  const std::string cpu = CpuModel();
  EXPECT_FALSE(cpu.empty());
  EXPECT_EQ(cpu.find('\n'), std::string::npos);
  EXPECT_NE(cpu.front(), ' ');
  EXPECT_THAT(ReadFile(cpuinfo), HasSubstr(cpu));
}

}  // namespace
}  // namespace soma
