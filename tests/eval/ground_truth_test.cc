#include "framework/eval/ground_truth.h"

#include "framework/core/error.h"
#include "framework/eval/labeling_metrics.h"
#include "framework/io/c3d.h"
#include "framework/io/mocap_dataset.h"
#include "framework/testing/testing.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <string>
#include <vector>

namespace soma {
namespace {

namespace fs = std::filesystem;
using ::soma::testing::CreateTestDir;
using ::soma::testing::ErrorMessage;
using ::testing::ElementsAre;
using ::testing::HasSubstr;

const std::string kNull(kNullLabel);

/// 3 frames of 3 columns in mm: column k at (100 k + t, 10 k, 1000);
/// column 2 is invalid in frame 1.
C3dData MakeCapture(std::vector<std::string> labels) {
  C3dData d;
  d.source = "capture";
  d.frame_rate = 120.0;
  d.num_frames = 3;
  d.num_points = 3;
  d.units = "mm";
  d.points.resize(3, 9);
  d.residuals.setZero(3, 3);
  d.valid.setConstant(3, 3, true);
  for (int t = 0; t < 3; ++t) {
    for (int k = 0; k < 3; ++k) {
      d.points(t, 3 * k) = 100.0f * k + t;
      d.points(t, 3 * k + 1) = 10.0f * k;
      d.points(t, 3 * k + 2) = 1000.0f;
    }
  }
  d.residuals(1, 2) = -1.0f;
  d.valid(1, 2) = false;
  d.labels = std::move(labels);
  return d;
}

/// A dataset of 3 frames x 3 points with labels {C7, LFHD} and the given
/// label ids per frame (2 = null).
void WriteTruth(const fs::path& path,
                const std::vector<std::vector<int16_t>>& ids) {
  DatasetInfo info;
  info.labels = {"C7", "LFHD"};
  info.num_points = 3;
  LabeledFrames frames;
  frames.Resize(static_cast<int64_t>(ids.size()), 3);
  std::fill(frames.points.begin(), frames.points.end(), 0.0f);
  for (size_t t = 0; t < ids.size(); ++t) {
    for (int k = 0; k < 3; ++k) frames.frame_labels(t)[k] = ids[t][k];
  }
  DatasetWriter writer(path, info);
  writer.Append(frames);
  writer.Close();
}

TEST(GroundTruth, ClassOfColumnIsTheCanonicalNameOrNull) {
  EXPECT_EQ(ClassOfColumn("meinard:lasi"), "LFWT");
  EXPECT_EQ(ClassOfColumn("C7"), "C7");
  EXPECT_EQ(ClassOfColumn("*12"), kNull);
  EXPECT_EQ(ClassOfColumn(""), kNull);
}

TEST(GroundTruth, LabelledC3dInMetresWithMissingPointsAtZero) {
  const fs::path dir = CreateTestDir();
  WriteC3d(dir / "take.c3d", MakeCapture({"subject:C7", "*1", "LFHD"}));
  const ScoredSequence seq = ReadC3dSequence(dir / "take.c3d");
  ASSERT_EQ(seq.frames.size(), 3u);
  EXPECT_THAT(seq.column_labels, ElementsAre("C7", kNull, "LFHD"));
  EXPECT_TRUE(seq.frame_labels.empty());
  EXPECT_EQ(&seq.LabelsAt(2), &seq.column_labels);
  for (int t = 0; t < 3; ++t) {
    ASSERT_EQ(seq.frames[t].cols(), 3);
    for (int k = 0; k < 3; ++k) {
      if (t == 1 && k == 2) {
        EXPECT_TRUE(seq.frames[t].col(k).isZero()) << "invalid point";
        continue;
      }
      EXPECT_NEAR(seq.frames[t](0, k), 0.001 * (100.0 * k + t), 1e-9);
      EXPECT_NEAR(seq.frames[t](1, k), 0.01 * k, 1e-9);
      EXPECT_NEAR(seq.frames[t](2, k), 1.0, 1e-9);
    }
  }
}

TEST(GroundTruth, CorruptedTruthTakesPointsFromTheC3dAndLabelsPerFrame) {
  const fs::path dir = CreateTestDir();
  WriteC3d(dir / "take.c3d", MakeCapture({"*000", "*001", "*002"}));
  // Column 0 is C7 until frame 1, then a ghost; column 1 is LFHD from
  // frame 1 on; column 2 is always null.
  WriteTruth(dir / "take.h5", {{0, 2, 2}, {0, 1, 2}, {2, 1, 2}});
  const ScoredSequence seq = ReadGroundTruth(dir / "take.h5");
  ASSERT_EQ(seq.frames.size(), 3u);
  EXPECT_NEAR(seq.frames[2](0, 1), 0.102, 1e-9);
  EXPECT_THAT(seq.column_labels, ElementsAre(kNull, kNull, kNull));
  ASSERT_EQ(seq.frame_labels.size(), 3u);
  EXPECT_THAT(seq.LabelsAt(0), ElementsAre("C7", kNull, kNull));
  EXPECT_THAT(seq.LabelsAt(1), ElementsAre("C7", "LFHD", kNull));
  EXPECT_THAT(seq.LabelsAt(2), ElementsAre(kNull, "LFHD", kNull));
}

TEST(GroundTruth, BadInputIsAClearIoError) {
  const fs::path dir = CreateTestDir();
  WriteTruth(dir / "alone.h5", {{0, 1, 2}});
  EXPECT_THAT(ErrorMessage<IoError>([&] { ReadGroundTruth(dir / "alone.h5"); }),
              HasSubstr("needs its corrupted capture"));

  WriteC3d(dir / "short.c3d", MakeCapture({"*000", "*001", "*002"}));
  WriteTruth(dir / "short.h5", {{0, 1, 2}, {0, 1, 2}});  // 2 frames, not 3
  EXPECT_THAT(ErrorMessage<IoError>([&] { ReadGroundTruth(dir / "short.h5"); }),
              HasSubstr("ground truth has 2 frames x 3 columns but"));

  EXPECT_THAT(ErrorMessage<IoError>([&] { ReadGroundTruth(dir / "take.trc"); }),
              HasSubstr("ground truth must be a soma corrupt .h5"));
}

}  // namespace
}  // namespace soma
