#include "framework/core/progress.h"

#include "framework/core/file.h"
#include "framework/core/logging.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include <string>

namespace soma {
namespace {

TEST(ProgressBar, StatusLineShowsCountsRateAndEta) {
  ProgressBar bar(200, {.label = "synth", .unit = "frames", .enabled = false});
  bar.Update(50, "loss=0.5");
  const std::string line = bar.StatusLine();
  EXPECT_NE(line.find("synth"), std::string::npos) << line;
  EXPECT_NE(line.find("50/200"), std::string::npos) << line;
  EXPECT_NE(line.find("25%"), std::string::npos) << line;
  EXPECT_NE(line.find("frames/s"), std::string::npos) << line;
  EXPECT_NE(line.find("ETA"), std::string::npos) << line;
  EXPECT_NE(line.find("loss=0.5"), std::string::npos) << line;
}

TEST(ProgressBar, ResumedPositionCounts) {
  ProgressBar bar(10, {.enabled = false});
  bar.SetPosition(7);
  bar.Update(1);
  EXPECT_EQ(bar.done(), 8);
  EXPECT_NE(bar.StatusLine().find("8/10"), std::string::npos);
}

TEST(FormatDuration, Formats) {
  EXPECT_EQ(FormatDuration(5.04), "5.0s");
  EXPECT_EQ(FormatDuration(125), "2m05s");
  EXPECT_EQ(FormatDuration(3725), "1h02m05s");
}

TEST(Logger, WritesHydraFormatToTheLogFile) {
  const auto dir = testing::CreateTestDir();
  const auto path = dir / "job.log";
  Logger::OpenFile(path.string());
  Logger::SetConsoleLevel(LogLevel::kError);
  SOMA_LOG(INFO, "hello {}", 42);
  Logger::SetConsoleLevel(LogLevel::kInfo);
  Logger::CloseFile();
  const std::string text = ReadFile(path);
  EXPECT_NE(text.find("][INFO] - hello 42"), std::string::npos) << text;
  EXPECT_EQ(text.front(), '[');
}

}  // namespace
}  // namespace soma
