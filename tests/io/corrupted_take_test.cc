#include "framework/io/corrupted_take.h"

#include "framework/core/error.h"
#include "framework/testing/testing.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <vector>

namespace soma {
namespace {

namespace fs = std::filesystem;
using ::soma::testing::CreateTestDir;
using ::soma::testing::ErrorMessage;
using ::testing::HasSubstr;

/// `frames` frames of 2 columns, column k at (k, t, 0) mm.
void WriteCapture(const fs::path& path, int frames) {
  C3dData d;
  d.frame_rate = 100.0;
  d.num_frames = frames;
  d.num_points = 2;
  d.units = "mm";
  d.points.setZero(frames, 6);
  for (int t = 0; t < frames; ++t) {
    for (int k = 0; k < 2; ++k) {
      d.points(t, 3 * k) = static_cast<float>(k);
      d.points(t, 3 * k + 1) = static_cast<float>(t);
    }
  }
  WriteC3d(path, d);
}

/// Ground truth of `frames` frames x `points` columns, labels {A, B}:
/// column k has label id (t + k) % 3 (2 = null).
void WriteTruth(const fs::path& path, int frames, int points) {
  DatasetInfo info;
  info.labels = {"A", "B"};
  info.num_points = points;
  LabeledFrames truth;
  truth.Resize(frames, points);
  std::fill(truth.points.begin(), truth.points.end(), 0.0f);
  for (int t = 0; t < frames; ++t) {
    for (int k = 0; k < points; ++k) {
      truth.frame_labels(t)[k] = static_cast<int16_t>((t + k) % 3);
    }
  }
  DatasetWriter writer(path, info);
  writer.Append(truth);
  writer.Close();
}

TEST(CorruptedTake, ReadsTheCaptureBesideItsGroundTruth) {
  const fs::path dir = CreateTestDir();
  WriteCapture(dir / "take.c3d", 4);
  WriteTruth(dir / "take.h5", 4, 2);
  const CorruptedTake take = ReadCorruptedTake(dir / "take.h5");
  EXPECT_EQ(take.c3d_path, dir / "take.c3d");
  EXPECT_EQ(take.c3d.num_frames, 4);
  EXPECT_EQ(take.c3d.num_points, 2);
  EXPECT_FLOAT_EQ(take.c3d.Point(3, 1).y(), 3.0f);
  EXPECT_EQ(take.info.labels, (std::vector<std::string>{"A", "B"}));
  ASSERT_EQ(take.truth.num_frames(), 4);
  EXPECT_EQ(take.truth.frame_labels(2)[0], 2);
  EXPECT_EQ(take.truth.frame_labels(2)[1], 0);
}

TEST(CorruptedTake, MissingCaptureOrMismatchIsAClearIoError) {
  const fs::path dir = CreateTestDir();
  WriteTruth(dir / "alone.h5", 4, 2);
  EXPECT_THAT(
      ErrorMessage<IoError>([&] { ReadCorruptedTake(dir / "alone.h5"); }),
      HasSubstr("alone.h5: ground truth needs its corrupted capture"));
  WriteCapture(dir / "frames.c3d", 5);
  WriteTruth(dir / "frames.h5", 4, 2);
  EXPECT_THAT(
      ErrorMessage<IoError>([&] { ReadCorruptedTake(dir / "frames.h5"); }),
      HasSubstr("ground truth has 4 frames x 2 columns but"));
  WriteCapture(dir / "columns.c3d", 4);
  WriteTruth(dir / "columns.h5", 4, 3);
  EXPECT_THAT(
      ErrorMessage<IoError>([&] { ReadCorruptedTake(dir / "columns.h5"); }),
      HasSubstr("has 4 x 2"));
}

}  // namespace
}  // namespace soma
