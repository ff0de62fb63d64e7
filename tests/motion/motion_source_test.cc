#include "framework/motion/motion_source.h"

#include "framework/config/yaml_io.h"
#include "framework/core/file.h"
#include "framework/motion/coverage.h"
#include "framework/registry/registry.h"
#include "framework/testing/body_fixture.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include <set>

namespace soma {
namespace {

const BodyModel& Body() { return testing::ProceduralBody(); }

std::unique_ptr<MotionSource> Procedural(const std::string& yaml) {
  BuildContext ctx;
  return Instantiate<MotionSource>(ParseYaml(yaml, "<test>"), ctx);
}

TEST(SplitOf, IsStableAndRoughlyProportional) {
  const SplitFractions fractions{.val = 0.2, .test = 0.1};
  int counts[3] = {0, 0, 0};
  for (int i = 0; i < 5000; ++i) {
    const std::string name = "clip_" + std::to_string(i);
    const Split split = SplitOf(name, 42, fractions);
    EXPECT_EQ(split, SplitOf(name, 42, fractions));
    ++counts[static_cast<int>(split)];
  }
  EXPECT_NEAR(counts[1] / 5000.0, 0.2, 0.03);
  EXPECT_NEAR(counts[2] / 5000.0, 0.1, 0.03);
}

TEST(ProceduralMotionSource, SplitsAreDisjointAndCoverEveryClip) {
  const auto source = Procedural(
      "name: procedural\nclips_per_type: 3\nduration_s: 0.5\ntypes: [walk, "
      "squat, flip]\n");
  Rng rng(1);
  std::set<std::string> seen;
  int total = 0;
  for (Split split : {Split::kTrain, Split::kVal, Split::kTest}) {
    for (const PoseSequence& clip : source->Load(Body(), split, 30.0, rng)) {
      EXPECT_TRUE(seen.insert(clip.name).second)
          << clip.name << " in two splits";
      EXPECT_EQ(clip.frame_rate, 30.0);
      EXPECT_EQ(clip.num_frames(), 15);
      ++total;
    }
  }
  EXPECT_EQ(total, 9);
}

TEST(ProceduralMotionSource, RejectsUnknownTypesAndKeys) {
  EXPECT_THROW(Procedural("name: procedural\ntypes: [moonwalk]\n"),
               ConfigError);
  EXPECT_THROW(Procedural("name: procedural\nclip_per_type: 3\n"), ConfigError);
}

TEST(Coverage, ReportsUprightAndInvertedFramesAndWritesPlots) {
  const auto source = Procedural(
      "name: procedural\nclips_per_type: 2\nduration_s: 2.0\ntypes: [walk, "
      "handstand]\n"
      "val_fraction: 0.0\ntest_fraction: 0.0\n");
  Rng rng(3);
  const std::vector<PoseSequence> clips =
      source->Load(Body(), Split::kTrain, 30.0, rng);
  const CoverageReport report = ComputeCoverage(Body(), clips);
  EXPECT_EQ(report.num_frames, 4 * 60);
  EXPECT_GT(report.UprightFraction(), 0.3);
  EXPECT_GT(report.InvertedFraction(), 0.1);
  EXPECT_EQ(report.frames_per_type.at("walk"), 120);
  const auto dir = testing::CreateTestDir();
  WriteCoverageReport(report, dir);
  EXPECT_NE(ReadFile(dir / "coverage.md").find("inverted"), std::string::npos);
  EXPECT_TRUE(std::filesystem::exists(dir / "coverage_tilt.png"));
  EXPECT_TRUE(std::filesystem::exists(dir / "coverage.csv"));
}

}  // namespace
}  // namespace soma
