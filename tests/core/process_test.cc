#include "framework/core/process.h"

#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/testing/testing.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cerrno>
#include <set>
#include <signal.h>
#include <sstream>

namespace soma {
namespace {

using ::testing::HasSubstr;

TEST(ProcessTest, RunProcessReturnsTheExitCodeAndCapturesOutput) {
  const auto dir = testing::CreateTestDir();
  const int code = RunProcess(
      {{"/bin/sh", "-c", "echo to-stdout; echo to-stderr >&2; exit 3"},
       dir / "logs" / "out.txt"});
  EXPECT_EQ(code, 3);
  const std::string log = ReadFile(dir / "logs" / "out.txt");
  EXPECT_THAT(log, HasSubstr("to-stdout"));
  EXPECT_THAT(log, HasSubstr("to-stderr"));
}

TEST(ProcessTest, ASignalIsReportedAs128PlusTheSignal) {
  EXPECT_EQ(RunProcess({{"/bin/sh", "-c", "kill -9 $$"}, {}}), 128 + 9);
}

TEST(ProcessTest, AMissingExecutableIsAnIoErrorNamingIt) {
  const std::string message = testing::ErrorMessage<IoError>([] {
    RunProcess({{"/nonexistent/soma", "train"}, {}});
  });
  EXPECT_THAT(message, HasSubstr("/nonexistent/soma: not an executable"));
}

TEST(ProcessTest, PoolRunsAtMostMaxParallelAndReportsEveryChild) {
  const auto dir = testing::CreateTestDir();
  ProcessPool pool(2);
  std::set<int64_t> ids;
  for (int i = 0; i < 5; ++i) {
    // Each child records how many siblings run beside it.
    ids.insert(
        pool.Start({{"/bin/sh",
                     "-c",
                     "cd '" + dir.string() +
                         "'; touch running.$$; ls running.* | wc -l >> counts; "
                         "sleep 0.1; rm running.$$; exit " +
                         std::to_string(i)},
                    {}}));
    EXPECT_LE(pool.num_running(), 2);
  }
  std::set<int64_t> reported;
  std::multiset<int> codes;
  while (auto result = pool.WaitAny()) {
    reported.insert(result->id);
    codes.insert(result->exit_code);
    EXPECT_GE(result->wall_time_s, 0.05);
  }
  EXPECT_EQ(reported, ids);
  EXPECT_EQ(codes, (std::multiset<int>{0, 1, 2, 3, 4}));
  std::istringstream counts(ReadFile(dir / "counts"));
  int n = 0, lines = 0;
  while (counts >> n) {
    EXPECT_LE(n, 2);
    ++lines;
  }
  EXPECT_EQ(lines, 5);
}

TEST(ProcessTest, DestroyingThePoolTerminatesRunningChildren) {
  const auto dir = testing::CreateTestDir();
  const auto pid_file = dir / "pid";
  {
    ProcessPool pool(1);
    pool.Start({{"/bin/sh",
                 "-c",
                 "echo $$ > '" + pid_file.string() + "'; exec sleep 30"},
                {}});
    for (int i = 0; i < 200 && !std::filesystem::exists(pid_file); ++i) {
      usleep(10000);
    }
    usleep(50000);  // let the shell finish writing and exec sleep
  }
  const pid_t pid = std::stoi(ReadFile(pid_file));
  EXPECT_EQ(::kill(pid, 0), -1);
  EXPECT_EQ(errno, ESRCH);
}

TEST(ProcessTest, ShellQuoteRoundTripsThroughTheShell) {
  const auto dir = testing::CreateTestDir();
  const std::vector<std::string> args = {
      "plain", "a b", "it's", "task.files=[a.c3d,b.c3d]", "$HOME", ""};
  EXPECT_EQ(ShellQuote({"soma", "train", "seed=1"}), "soma train seed=1");
  const auto out = dir / "args.txt";
  ASSERT_EQ(RunProcess({{"/bin/sh",
                         "-c",
                         "printf '%s\\n' " + ShellQuote(args) + " > '" +
                             out.string() + "'"},
                        {}}),
            0);
  std::string expected;
  for (const std::string& a : args) expected += a + "\n";
  EXPECT_EQ(ReadFile(out), expected);
}

TEST(ProcessTest, CurrentExecutableIsThisTestBinary) {
  EXPECT_THAT(CurrentExecutable().filename().string(), HasSubstr("core_tests"));
}

}  // namespace
}  // namespace soma
