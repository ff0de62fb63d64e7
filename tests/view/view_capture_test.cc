#include "framework/view/view_capture.h"

#include "framework/core/error.h"
#include "framework/io/c3d.h"
#include "framework/io/mocap_dataset.h"
#include "framework/testing/testing.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
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

/// A capture of `frames` frames and 4 columns (mm): column k at
/// (100 k + t, 10 k, 1000); column 3 is missing in frame 1 (if any).
C3dData MakeCapture(int frames, std::vector<std::string> labels) {
  C3dData d;
  d.source = "capture";
  d.frame_rate = 120.0;
  d.num_frames = frames;
  d.num_points = 4;
  d.units = "mm";
  d.points.resize(frames, 12);
  d.residuals.setZero(frames, 4);
  d.valid.setConstant(frames, 4, true);
  for (int t = 0; t < frames; ++t) {
    for (int k = 0; k < 4; ++k) {
      d.points(t, 3 * k) = 100.0f * k + t;
      d.points(t, 3 * k + 1) = 10.0f * k;
      d.points(t, 3 * k + 2) = 1000.0f;
    }
  }
  if (frames > 1) {
    d.residuals(1, 3) = -1.0f;
    d.valid(1, 3) = false;
  }
  d.labels = std::move(labels);
  return d;
}

TEST(ReadViewFrames, LabelsTruthAndStatusFromLabelledC3ds) {
  const fs::path dir = CreateTestDir();
  // The labeller's output: columns LFHD, RFHD, a null column, C7.
  const C3dData rec = MakeCapture(3, {"LFHD", "RFHD", "*0", "C7"});
  WriteC3d(dir / "take_labeled.c3d", rec);
  // Ground truth: the same points, column 1 is really C7, column 2 is
  // RBAC (missed by the labeller), column 3 is a ghost.
  C3dData gt = MakeCapture(3, {"subject:LFHD", "C7", "RBAC", "*7"});
  WriteC3d(dir / "truth.c3d", gt);

  ViewInputs inputs;
  inputs.capture = (dir / "take_labeled.c3d").string();
  inputs.truth = (dir / "truth.c3d").string();
  const ViewFrames v = ReadViewFrames(inputs);
  EXPECT_EQ(v.num_frames(), 3);
  EXPECT_THAT(v.offsets, ElementsAre(0, 4, 7, 11));  // column 3 missing at 1
  EXPECT_DOUBLE_EQ(v.frame_rate, 120.0);
  // Capture columns first, then the truth's other labels.
  EXPECT_THAT(v.labels, ElementsAre("LFHD", "RFHD", "C7", "RBAC"));
  const int L = 4;
  EXPECT_THAT(std::vector<int>(v.label.begin(), v.label.begin() + 4),
              ElementsAre(0, 1, L, 2));
  EXPECT_THAT(std::vector<int>(v.truth.begin(), v.truth.begin() + 4),
              ElementsAre(0, 2, 3, L));
  std::vector<PointStatus> status;
  for (int i = 0; i < 4; ++i) {
    status.push_back(ClassifyPoint(v.label[i], v.truth[i], L));
  }
  EXPECT_THAT(status,
              ElementsAre(PointStatus::kCorrect,
                          PointStatus::kWrong,
                          PointStatus::kMissed,
                          PointStatus::kGhostAsMarker));
  // Metres, and track ids are the capture's columns without a sidecar.
  EXPECT_FLOAT_EQ(v.positions[3 * 5 + 0], 0.101f);  // frame 1, column 1
  EXPECT_THAT(std::vector<int>(v.track.begin() + 4, v.track.begin() + 7),
              ElementsAre(0, 1, 2));
  EXPECT_FALSE(v.has_confidence());
}

TEST(ReadViewFrames, PointsWithoutAGroundTruthMatchAreMarked) {
  const fs::path dir = CreateTestDir();
  WriteC3d(dir / "a.c3d", MakeCapture(2, {"A", "B", "C", "D"}));
  C3dData other = MakeCapture(2, {"A", "B", "C", "D"});
  other.points(0, 0) += 0.5f;  // 0.5 mm away: no exact match
  WriteC3d(dir / "b.c3d", other);
  ViewInputs inputs{.capture = (dir / "a.c3d").string(),
                    .truth = (dir / "b.c3d").string()};
  const ViewFrames v = ReadViewFrames(inputs);
  EXPECT_EQ(v.truth[0], v.null_id() + 1);
  EXPECT_EQ(ClassifyPoint(v.label[0], v.truth[0], v.null_id()),
            PointStatus::kNoTruth);
  EXPECT_EQ(v.truth[1], 1);
}

TEST(ReadViewFrames, SidecarGivesConfidencesTrackIdsAndNullColumnLabels) {
  const fs::path dir = CreateTestDir();
  WriteC3d(dir / "take_labeled.c3d", MakeCapture(2, {"A", "*1", "*2", "D"}));
  // A sidecar in the labeller's packing: points in another order, metres,
  // input columns 7..10, one padding point per frame.
  DatasetInfo info;
  info.labels = {"A", "B", "D"};
  info.num_points = 5;
  LabeledFrames frames;
  frames.Resize(2, 5);
  std::vector<float> confidence(10, 0.0f), column(10, -1.0f);
  for (int t = 0; t < 2; ++t) {
    for (int n = 0; n < 5; ++n) {
      float* p = frames.frame_points(t) + 3 * n;
      p[0] = p[1] = p[2] = 0.0f;
      frames.frame_labels(t)[n] = 3;  // null
    }
    const int present = t == 1 ? 3 : 4;  // column 3 missing in frame 1
    for (int n = 0; n < present; ++n) {
      const int k = present - 1 - n;  // reversed
      float* p = frames.frame_points(t) + 3 * n;
      p[0] = static_cast<float>((100.0f * k + t) * 0.001);
      p[1] = static_cast<float>(10.0f * k * 0.001);
      p[2] = static_cast<float>(1000.0f * 0.001);
      frames.frame_labels(t)[n] = k == 0 ? 0 : k == 1 ? 1 : k == 3 ? 2 : 3;
      confidence[5 * t + n] = 0.25f * k;
      column[5 * t + n] = 7.0f + k;
    }
  }
  {
    DatasetWriter writer(dir / "take_labels.h5", info);
    writer.Append(frames);
    writer.WritePointArray("confidence", confidence);
    writer.WritePointArray("column", column);
    writer.Close();
  }
  const std::string capture = (dir / "take_labeled.c3d").string();
  ASSERT_EQ(FindSidecar(capture), (dir / "take_labels.h5").string());
  const ViewFrames v =
      ReadViewFrames({.capture = capture, .sidecar = FindSidecar(capture)});
  ASSERT_TRUE(v.has_confidence());
  // Labels: capture columns A, D, then the sidecar's B; the null column 1
  // takes the sidecar's B, column 2 stays null.
  EXPECT_THAT(v.labels, ElementsAre("A", "D", "B"));
  EXPECT_THAT(std::vector<int>(v.label.begin(), v.label.begin() + 4),
              ElementsAre(0, 2, 3, 1));
  EXPECT_THAT(
      std::vector<float>(v.confidence.begin(), v.confidence.begin() + 4),
      ElementsAre(0.0f, 0.25f, 0.5f, 0.75f));
  EXPECT_THAT(std::vector<int>(v.track.begin(), v.track.begin() + 4),
              ElementsAre(7, 8, 9, 10));
  EXPECT_THAT(v.track_source, HasSubstr("input column of the labeller"));
}

TEST(ReadViewFrames, RefusesInputsOfAnotherLength) {
  const fs::path dir = CreateTestDir();
  WriteC3d(dir / "a.c3d", MakeCapture(3, {"A", "B", "C", "D"}));
  WriteC3d(dir / "b.c3d", MakeCapture(2, {"A", "B", "C", "D"}));
  ViewInputs inputs{.capture = (dir / "a.c3d").string(),
                    .truth = (dir / "b.c3d").string()};
  EXPECT_THAT(ErrorMessage<IoError>([&] { ReadViewFrames(inputs); }),
              HasSubstr("b.c3d: 2 frames, but the capture"));
  inputs.truth = (dir / "truth.txt").string();
  EXPECT_THAT(ErrorMessage<IoError>([&] { ReadViewFrames(inputs); }),
              HasSubstr("truth.txt: ground truth must be"));
  inputs.truth = (dir / "missing.h5").string();
  EXPECT_THAT(ErrorMessage<IoError>([&] { ReadViewFrames(inputs); }),
              HasSubstr("needs its corrupted capture"));
}

TEST(ReadViewFrames, LeavesNonPositionOutputsOfARealPlugInGaitTakeOut) {
  // 193 columns: markers and virtual points (positions, kept), and 26 joint
  // angles, 20 forces, 18 moments, 16 powers stored as points (POINT:ANGLES
  // ... name them), left out.
  const fs::path take =
      testing::SharedDataDir() / "c3d" / "PiG_Motion-FlatFoot-Hole.c3d";
  const C3dData c3d = ReadC3d(take);
  ASSERT_EQ(c3d.num_points, 193);
  const ViewFrames v = ReadViewFrames({.capture = take.string()});
  EXPECT_EQ(v.labels.size(), 193u - 26 - 20 - 18 - 16);
  EXPECT_EQ(v.num_frames(), c3d.num_frames);
  EXPECT_THAT(v.labels, ::testing::Contains("LFWT"));  // LASI, canonical
  EXPECT_THAT(v.labels, ::testing::Contains("CENTREOFMASS"));
  EXPECT_THAT(v.labels, ::testing::Not(::testing::Contains("LHIPANGLES")));
  EXPECT_THAT(v.labels, ::testing::Not(::testing::Contains("LANKLEPOWER")));
}

TEST(FindSidecar, OnlyBesideALabelledCapture) {
  const fs::path dir = CreateTestDir();
  EXPECT_EQ(FindSidecar((dir / "take_labeled.c3d").string()), "");
  WriteC3d(dir / "take.c3d", MakeCapture(1, {"A", "B", "C", "D"}));
  testing::WriteTextFile(dir, "take_labels.h5", "x");
  EXPECT_EQ(FindSidecar((dir / "take.c3d").string()), "");
  EXPECT_EQ(FindSidecar((dir / "take_labeled.c3d").string()),
            (dir / "take_labels.h5").string());
}

TEST(NeighbourSticks, JoinsEachMarkerToItsNearestLayoutMarkers) {
  // Layout markers on a line at 0, 1, 3, 6 (+ one the capture lacks at 0.5).
  const std::vector<std::string> layout = {"A", "B", "C", "D", "X"};
  Eigen::Matrix3Xd rest = Eigen::Matrix3Xd::Zero(3, 5);
  rest.row(0) << 0.0, 1.0, 3.0, 6.0, 0.5;
  // Capture label ids: D, C, B, A, and one label the layout lacks.
  const std::vector<std::string> labels = {"D", "C", "B", "A", "Q"};
  EXPECT_THAT(NeighbourSticks(labels, layout, rest, 1),
              ElementsAre(std::array<int, 2>{0, 1},    // D-C
                          std::array<int, 2>{1, 2},    // C-B
                          std::array<int, 2>{2, 3}));  // B-A
  // k = 2 adds A-C and B-D.
  EXPECT_EQ(NeighbourSticks(labels, layout, rest, 2).size(), 5u);
  EXPECT_TRUE(NeighbourSticks(labels, layout, rest, 0).empty());
  EXPECT_TRUE(NeighbourSticks({"Q"}, layout, rest, 2).empty());
  EXPECT_THROW(NeighbourSticks(labels, {"A"}, rest, 1), ShapeError);
}

}  // namespace
}  // namespace soma
