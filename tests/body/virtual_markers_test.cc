#include "framework/body/virtual_markers.h"

#include "framework/core/error.h"
#include "framework/core/random.h"

#include <gtest/gtest.h>

#include "tests/body/body_test_util.h"

namespace soma {
namespace {

using ::soma::testing::ProceduralBody;

// float32 skinning of coordinates ~1-3 m: ~1e-6 relative.
constexpr double kPositionTol = 2e-5;  // metres
constexpr double kNormalTol = 2e-4;

BodyPose RandomPose(Rng* rng, int num_joints) {
  BodyPose pose = BodyPose::Rest(num_joints);
  for (int j = 0; j < num_joints; ++j) {
    for (int c = 0; c < 3; ++c) pose.rotations(c, j) = 0.5 * rng->Normal();
  }
  pose.translation =
      Eigen::Vector3d(rng->Normal(), rng->Normal(), 0.3 * rng->Normal());
  return pose;
}

Eigen::VectorXd RandomBetas(Rng* rng, int n) {
  Eigen::VectorXd b(n);
  for (int k = 0; k < n; ++k) b(k) = 1.5 * rng->Normal();
  return b;
}

void ExpectMatchesFullPosing(const BodyModel& body,
                             const MarkerLayout& layout,
                             uint64_t seed) {
  const VirtualMarkerSampler sampler(body, layout);
  ASSERT_EQ(sampler.num_markers(), layout.num_markers());
  // Only 1-rings are posed, never the whole mesh.
  EXPECT_LT(sampler.num_local_vertices(), 10 * layout.num_markers());
  Rng rng(seed);
  VirtualMarkerSampler::Workspace ws;
  for (int trial = 0; trial < 5; ++trial) {
    const Eigen::VectorXd betas = RandomBetas(&rng, body.num_betas());
    const BodyPose pose = RandomPose(&rng, body.num_joints());
    const Eigen::Matrix3Xd full = PoseVertices(body, betas, pose);
    const Eigen::Matrix3Xd full_normals = VertexNormals(full, body.faces);
    Eigen::Matrix3Xd vertices, normals, markers;
    sampler.SampleSurface(betas, pose, &ws, &vertices, &normals);
    sampler.Sample(betas, pose, &ws, &markers);
    const Eigen::Matrix3Xd expected =
        MarkerPositions(layout, full, full_normals);
    for (int m = 0; m < layout.num_markers(); ++m) {
      const int vid = layout.markers[m].vertex_ids[0];
      EXPECT_LT((vertices.col(m) - full.col(vid)).norm(), kPositionTol) << m;
      EXPECT_LT((normals.col(m) - full_normals.col(vid)).norm(), kNormalTol)
          << m;
      EXPECT_LT((markers.col(m) - expected.col(m)).norm(), kPositionTol) << m;
    }
  }
}

TEST(VirtualMarkers, SubsetPosingEqualsFullPosing) {
  const BodyModel& body = ProceduralBody();
  ExpectMatchesFullPosing(body, MakeBuiltinLayout(body, "cmu41"), 1);
  ExpectMatchesFullPosing(body, MakeBuiltinLayout(body, "superset89"), 2);
}

TEST(VirtualMarkers, HandlesPoseCorrectivesAndPartialBetas) {
  BodyModel body = ProceduralBody();
  Rng rng(7);
  body.pose_dirs = Eigen::MatrixXd::Zero(3 * body.num_vertices(),
                                         9 * (body.num_joints() - 1));
  for (Eigen::Index i = 0; i < body.pose_dirs.size(); i += 31) {
    body.pose_dirs.data()[i] = 0.02 * rng.Normal();
  }
  const MarkerLayout layout = MakeBuiltinLayout(body, "cmu41");
  const VirtualMarkerSampler sampler(body, layout);
  const Eigen::VectorXd betas = RandomBetas(&rng, 4);  // fewer than num_betas
  const BodyPose pose = RandomPose(&rng, body.num_joints());
  const Eigen::Matrix3Xd full = PoseVertices(body, betas, pose);
  const Eigen::Matrix3Xd expected =
      MarkerPositions(layout, full, VertexNormals(full, body.faces));
  const Eigen::Matrix3Xd markers = sampler.Sample(betas, pose);
  EXPECT_LT((markers - expected).cwiseAbs().maxCoeff(), kPositionTol);
}

TEST(VirtualMarkers, RestPoseMarkersSitOnTheTemplate) {
  const BodyModel& body = ProceduralBody();
  const std::vector<int> ids = {0, 100, 2000};
  const VirtualMarkerSampler sampler(body, ids, {0.0});
  const Eigen::Matrix3Xd markers =
      sampler.Sample(Eigen::VectorXd(), BodyPose::Rest(body.num_joints()));
  for (int m = 0; m < 3; ++m) {
    EXPECT_LT((markers.col(m) - body.template_vertices.col(ids[m])).norm(),
              1e-5);
  }
  EXPECT_EQ(sampler.marker_vertex_ids(), ids);
}

TEST(VirtualMarkers, RepeatedVertexAndPerMarkerDistances) {
  const BodyModel& body = ProceduralBody();
  const VirtualMarkerSampler sampler(body, {10, 10}, {0.0, 0.05});
  const Eigen::Matrix3Xd m =
      sampler.Sample(Eigen::VectorXd(), BodyPose::Rest(24));
  EXPECT_NEAR((m.col(1) - m.col(0)).norm(), 0.05, 1e-6);
}

TEST(VirtualMarkers, RejectsBadInput) {
  const BodyModel& body = ProceduralBody();
  EXPECT_THROW(VirtualMarkerSampler(body, {body.num_vertices()}, {0.0095}),
               ShapeError);
  EXPECT_THROW(VirtualMarkerSampler(body, {}, {0.0095}), ShapeError);
  EXPECT_THROW(VirtualMarkerSampler(body, {1, 2, 3}, {0.1, 0.2}), ShapeError);
  const VirtualMarkerSampler sampler(body, {1, 2}, {0.0095});
  EXPECT_THROW(sampler.Sample(Eigen::VectorXd::Zero(body.num_betas() + 1),
                              BodyPose::Rest(24)),
               ShapeError);
  EXPECT_THROW(sampler.Sample(Eigen::VectorXd(), BodyPose::Rest(5)),
               ShapeError);
}

}  // namespace
}  // namespace soma
