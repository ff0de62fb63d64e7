#include "framework/eval/attention_span.h"

#include "framework/body/marker_layout.h"
#include "framework/core/error.h"
#include "framework/io/c3d.h"
#include "framework/testing/body_fixture.h"
#include "framework/testing/testing.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <string>
#include <vector>

namespace soma {
namespace {

Eigen::Matrix3Xd FourPoints() {
  Eigen::Matrix3Xd p(3, 4);
  p << 0, 1, 0, 3,  //
      0, 0, 2, 0,   //
      0, 0, 0, 0;
  return p;
}

TEST(AttentionSpan, SelfAttentionHasNoSpanAndUniformAttentionTheMeanDistance) {
  const Eigen::MatrixXd d = PairwiseDistances(FourPoints());
  EXPECT_DOUBLE_EQ(d(0, 3), 3.0);
  EXPECT_DOUBLE_EQ(d(1, 2), std::sqrt(5.0));
  EXPECT_EQ(d, d.transpose());
  const Eigen::MatrixXd identity = Eigen::MatrixXd::Identity(4, 4);
  const Eigen::MatrixXd uniform = Eigen::MatrixXd::Constant(4, 4, 0.25);
  const std::vector<AttentionSpanLayer> layers =
      ComputeAttentionSpan({uniform, identity}, d);
  ASSERT_EQ(layers.size(), 2u);
  for (int i = 0; i < 4; ++i) {
    EXPECT_NEAR(layers[0].per_marker_m[i], d.row(i).mean(), 1e-12);
  }
  EXPECT_NEAR(layers[0].mean_m, d.mean(), 1e-12);
  EXPECT_GT(layers[0].ci95_m, 0.0);
  EXPECT_EQ(layers[1].mean_m, 0.0);  // every marker attends to itself
  EXPECT_EQ(layers[1].ci95_m, 0.0);
}

TEST(AttentionSpan, RowsAreNormalisedAfterTheHeadMaximum) {
  const Eigen::MatrixXd d = PairwiseDistances(FourPoints());
  // Marker 0 attends to itself and marker 3 equally (weights 2 and 2 after
  // a max over heads need not sum to 1): span 0.5 * 0 + 0.5 * 3.
  Eigen::MatrixXd w = Eigen::MatrixXd::Identity(4, 4);
  w(0, 0) = 2.0;
  w(0, 3) = 2.0;
  const std::vector<AttentionSpanLayer> layers = ComputeAttentionSpan({w}, d);
  EXPECT_DOUBLE_EQ(layers[0].per_marker_m[0], 1.5);
  EXPECT_DOUBLE_EQ(layers[0].mean_m, 1.5 / 4);
}

TEST(AttentionSpan, BadInputThrows) {
  const Eigen::MatrixXd d = PairwiseDistances(FourPoints());
  EXPECT_THROW(ComputeAttentionSpan({Eigen::MatrixXd::Identity(3, 3)}, d),
               ShapeError);
  EXPECT_THROW(ComputeAttentionSpan({Eigen::MatrixXd::Zero(4, 4)}, d),
               ShapeError);
  EXPECT_THROW(ComputeAttentionSpan({-Eigen::MatrixXd::Identity(4, 4)}, d),
               ShapeError);
  EXPECT_THROW(ComputeAttentionSpan({}, Eigen::MatrixXd::Zero(4, 3)),
               ShapeError);
}

TEST(APoseMarkers, RestPoseInLabelOrderAndLoweredArms) {
  const BodyModel& body = testing::ProceduralBody();
  const MarkerLayout layout = MakeBuiltinLayout(body, "cmu41");
  const std::vector<std::string> labels = {"RWRA", "LFHD", "LWRA"};
  const Eigen::Matrix3Xd vertices =
      PoseVertices(body,
                   Eigen::VectorXd::Zero(body.num_betas()),
                   BodyPose::Rest(body.num_joints()));
  const Eigen::Matrix3Xd all =
      MarkerPositions(layout, vertices, VertexNormals(vertices, body.faces));
  const Eigen::Matrix3Xd rest = APoseMarkers(body, layout, labels, 0.0);
  ASSERT_EQ(rest.cols(), 3);
  for (int l = 0; l < 3; ++l) {
    EXPECT_TRUE(rest.col(l).isApprox(all.col(layout.FindLabel(labels[l]))))
        << labels[l];
  }
  // 45 degrees: both wrists drop by about sin(45) of the shoulder-wrist
  // distance and come closer to the body; the head does not move.
  const Eigen::Matrix3Xd a_pose = APoseMarkers(body, layout, labels, 45.0);
  EXPECT_TRUE(a_pose.col(1).isApprox(rest.col(1), 1e-12));
  for (const int l : {0, 2}) {
    EXPECT_LT(a_pose(2, l), rest(2, l) - 0.25) << labels[l];
    EXPECT_LT(std::abs(a_pose(0, l)), std::abs(rest(0, l)) - 0.05) << labels[l];
  }
}

TEST(APoseMarkers, UnknownLabelIsAConfigError) {
  const BodyModel& body = testing::ProceduralBody();
  const MarkerLayout layout = MakeBuiltinLayout(body, "cmu41");
  EXPECT_THAT(testing::ErrorMessage<ConfigError>([&] {
                APoseMarkers(body, layout, {"LFHD", "NOPE"}, 45.0);
              }),
              ::testing::HasSubstr("label 'NOPE' is not in the layout"));
}

/// 6 frames of 3 columns in mm: column k at (t, k, 1000); column 1 is
/// invalid in frame 1 and at the origin in frame 3.
C3dData MakeTake() {
  C3dData d;
  d.num_frames = 6;
  d.num_points = 3;
  d.units = "mm";
  d.labels = {"subject:C7", "LFHD", "*2"};
  d.points.resize(6, 9);
  d.residuals.setZero(6, 3);
  d.valid.setConstant(6, 3, true);
  for (int t = 0; t < 6; ++t) {
    for (int k = 0; k < 3; ++k) {
      d.points(t, 3 * k) = static_cast<float>(t);
      d.points(t, 3 * k + 1) = static_cast<float>(k);
      d.points(t, 3 * k + 2) = 1000.0f;
    }
  }
  d.valid(1, 1) = false;
  d.residuals(1, 1) = -1.0f;
  for (int c = 0; c < 3; ++c) d.points(3, 3 + c) = 0.0f;
  return d;
}

TEST(SelectCompleteFrames, FramesWithEveryLabelInLabelOrderInMetres) {
  const CompleteFrames all =
      SelectCompleteFrames(MakeTake(), {"LFHD", "C7"}, "take.c3d", 100, 0);
  EXPECT_EQ(all.frames, (std::vector<int>{0, 2, 4, 5}));
  ASSERT_EQ(all.points.size(), 4u * 2 * 3);
  // Frame 2: LFHD (column 1) first, then C7 (column 0).
  const float* f = all.points.data() + 1 * 2 * 3;
  EXPECT_FLOAT_EQ(f[0], 0.002f);
  EXPECT_FLOAT_EQ(f[1], 0.001f);
  EXPECT_FLOAT_EQ(f[2], 1.0f);
  EXPECT_FLOAT_EQ(f[3], 0.002f);
  EXPECT_FLOAT_EQ(f[4], 0.0f);
  EXPECT_FLOAT_EQ(f[5], 1.0f);

  // At most max_frames, drawn per seed, ascending.
  const CompleteFrames two =
      SelectCompleteFrames(MakeTake(), {"LFHD", "C7"}, "take.c3d", 2, 7);
  ASSERT_EQ(two.frames.size(), 2u);
  EXPECT_TRUE(std::is_sorted(two.frames.begin(), two.frames.end()));
  for (const int t : two.frames) {
    EXPECT_NE(std::find(all.frames.begin(), all.frames.end(), t),
              all.frames.end());
  }
  EXPECT_EQ(
      SelectCompleteFrames(MakeTake(), {"LFHD", "C7"}, "take.c3d", 2, 7).frames,
      two.frames);
}

TEST(SelectCompleteFrames, MissingLabelOrNoCompleteFrameIsAnIoError) {
  EXPECT_THAT(
      testing::ErrorMessage<IoError>([] {
        SelectCompleteFrames(MakeTake(), {"C7", "RBAC"}, "take.c3d", 10, 0);
      }),
      ::testing::HasSubstr("take.c3d: no column labelled 'RBAC'"));
  C3dData broken = MakeTake();
  broken.valid.col(0).setConstant(false);
  EXPECT_THAT(testing::ErrorMessage<IoError>([&] {
                SelectCompleteFrames(broken, {"C7"}, "take.c3d", 10, 0);
              }),
              ::testing::HasSubstr("no frame has all 1 labels"));
}

}  // namespace
}  // namespace soma
