#include "framework/body/body_model.h"

#include "framework/core/error.h"
#include "framework/core/random.h"

#include <gtest/gtest.h>

#include "tests/body/body_test_util.h"
#include <cmath>

namespace soma {
namespace {

constexpr double kTol = 1e-9;

using ::soma::testing::ProceduralBody;

Eigen::VectorXd RandomBetas(Rng* rng, int n, double scale = 1.0) {
  Eigen::VectorXd betas(n);
  for (int i = 0; i < n; ++i) betas(i) = scale * rng->Normal();
  return betas;
}

// A regular octahedron: 6 vertices, 8 outward CCW faces.
void Octahedron(Eigen::Matrix3Xd* v, Eigen::Matrix3Xi* f) {
  v->resize(3, 6);
  *v << 1, -1, 0, 0, 0, 0,  //
      0, 0, 1, -1, 0, 0,    //
      0, 0, 0, 0, 1, -1;
  f->resize(3, 8);
  // +x=0, -x=1, +y=2, -y=3, +z=4, -z=5.
  *f << 0, 2, 1, 3, 2, 1, 3, 0,  //
      2, 1, 3, 0, 0, 2, 1, 3,    //
      4, 4, 4, 4, 5, 5, 5, 5;
}

TEST(BodyModel, CoreJointNamesAndRestPose) {
  const auto& names = CoreJointNames();
  ASSERT_EQ(names.size(), static_cast<size_t>(kNumCoreJoints));
  EXPECT_EQ(names[kPelvis], "pelvis");
  EXPECT_EQ(names[kLeftWrist], "left_wrist");
  EXPECT_EQ(names[kRightHand], "right_hand");
  const BodyPose rest = BodyPose::Rest(24);
  EXPECT_EQ(rest.rotations.cols(), 24);
  EXPECT_EQ(rest.rotations.norm(), 0.0);
  EXPECT_EQ(rest.translation.norm(), 0.0);
  EXPECT_EQ(ProceduralBody().FindJoint("left_elbow"), kLeftElbow);
  EXPECT_EQ(ProceduralBody().FindJoint("tail"), -1);
}

TEST(BodyModel, ValidateCatchesInconsistencies) {
  const BodyModel& good = ProceduralBody();
  EXPECT_NO_THROW(good.Validate());
  {
    BodyModel body = good;
    body.faces(1, 5) = body.num_vertices();
    EXPECT_THROW(body.Validate(), IoError);
  }
  {
    BodyModel body = good;
    body.parents[5] = 7;
    EXPECT_THROW(body.Validate(), IoError);
  }
  {
    BodyModel body = good;
    body.skinning_weights
        .valuePtr()[body.skinning_weights.outerIndexPtr()[10]] += 0.5;
    EXPECT_THROW(body.Validate(), IoError);
  }
  {
    BodyModel body = good;
    body.shape_dirs.conservativeResize(body.shape_dirs.rows() - 3,
                                       Eigen::NoChange);
    EXPECT_THROW(body.Validate(), ShapeError);
  }
  {
    BodyModel body = good;
    body.joint_names.pop_back();
    EXPECT_THROW(body.Validate(), ShapeError);
  }
  {
    BodyModel body = good;
    body.pose_dirs = Eigen::MatrixXd::Zero(5, 5);
    EXPECT_THROW(body.Validate(), ShapeError);
  }
}

TEST(BodyModel, ShapedVerticesAreLinearInBetas) {
  const BodyModel& body = ProceduralBody();
  Rng rng(1);
  const Eigen::VectorXd b1 = RandomBetas(&rng, body.num_betas());
  const Eigen::VectorXd b2 = RandomBetas(&rng, 4);  // fewer betas: rest are 0
  Eigen::VectorXd b2_full = Eigen::VectorXd::Zero(body.num_betas());
  b2_full.head(4) = b2;
  EXPECT_TRUE(
      body.ShapedVertices(b2).isApprox(body.ShapedVertices(b2_full), kTol));
  const Eigen::Matrix3Xd v0 = body.ShapedVertices(Eigen::VectorXd());
  EXPECT_TRUE(v0.isApprox(body.template_vertices, 0.0));
  const Eigen::Matrix3Xd sum = body.ShapedVertices(b1 + b2_full);
  EXPECT_LT(
      (sum - (body.ShapedVertices(b1) + body.ShapedVertices(b2_full) - v0))
          .norm(),
      1e-9);
  EXPECT_THROW(body.ShapedVertices(Eigen::VectorXd::Zero(body.num_betas() + 1)),
               ShapeError);
}

TEST(BodyModel, RestPoseReproducesShapedVertices) {
  const BodyModel& body = ProceduralBody();
  Rng rng(2);
  const Eigen::VectorXd betas = RandomBetas(&rng, body.num_betas());
  const Eigen::Matrix3Xd posed =
      PoseVertices(body, betas, BodyPose::Rest(body.num_joints()));
  EXPECT_LT((posed - body.ShapedVertices(betas)).cwiseAbs().maxCoeff(), 1e-12);
}

TEST(BodyModel, RootRotationAndTranslationMoveTheBodyRigidly) {
  const BodyModel& body = ProceduralBody();
  Rng rng(3);
  const Eigen::VectorXd betas = RandomBetas(&rng, body.num_betas());
  BodyPose pose = BodyPose::Rest(body.num_joints());
  pose.rotations.col(0) = Eigen::Vector3d(0.3, -1.2, 0.7);
  pose.translation = Eigen::Vector3d(0.5, -2.0, 0.25);
  const Eigen::Matrix3Xd shaped = body.ShapedVertices(betas);
  const Eigen::Vector3d root = body.RestJoints(shaped).col(0);
  const Eigen::Matrix3d r =
      Eigen::AngleAxisd(pose.rotations.col(0).norm(),
                        pose.rotations.col(0).normalized())
          .toRotationMatrix();
  const Eigen::Matrix3Xd posed = PoseVertices(body, betas, pose);
  double max_err = 0.0;
  for (int i = 0; i < body.num_vertices(); ++i) {
    const Eigen::Vector3d expected =
        r * (shaped.col(i) - root) + root + pose.translation;
    max_err = std::max(max_err, (posed.col(i) - expected).norm());
  }
  EXPECT_LT(max_err, 1e-9);
  // Pairwise distances are preserved.
  for (int k = 0; k < 200; ++k) {
    const int a = static_cast<int>(rng.UniformInt(0, body.num_vertices() - 1));
    const int b = static_cast<int>(rng.UniformInt(0, body.num_vertices() - 1));
    EXPECT_NEAR((posed.col(a) - posed.col(b)).norm(),
                (shaped.col(a) - shaped.col(b)).norm(),
                1e-9);
  }
}

TEST(BodyModel, PoseSkeletonChainsLocalRotations) {
  const BodyModel& body = ProceduralBody();
  const Eigen::Matrix3Xd joints = body.RestJoints(body.template_vertices);
  BodyPose pose = BodyPose::Rest(body.num_joints());
  pose.rotations.col(kLeftShoulder) =
      Eigen::Vector3d(0, 0, M_PI / 2);  // arm forward? about z
  pose.translation = Eigen::Vector3d(1, 2, 3);
  const PosedSkeleton skel = PoseSkeleton(body, joints, pose);
  // Joints above the shoulder only translate.
  EXPECT_TRUE(skel.global[kSpine3].translation().isApprox(joints.col(kSpine3) +
                                                          pose.translation));
  // The elbow rotates 90 degrees about z around the shoulder.
  const Eigen::Vector3d arm =
      joints.col(kLeftElbow) - joints.col(kLeftShoulder);
  const Eigen::Vector3d expected =
      joints.col(kLeftShoulder) + pose.translation +
      Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitZ()) * arm;
  EXPECT_LT((skel.global[kLeftElbow].translation() - expected).norm(), 1e-12);
  // Skinning transform maps the rest joint to its posed position.
  EXPECT_LT(
      (skel.skinning[kLeftElbow] * joints.col(kLeftElbow) - expected).norm(),
      1e-12);
  EXPECT_THROW(PoseSkeleton(body, joints, BodyPose::Rest(3)), ShapeError);
}

TEST(BodyModel, LocalRotationLeavesOtherLimbsInPlace) {
  const BodyModel& body = ProceduralBody();
  BodyPose pose = BodyPose::Rest(body.num_joints());
  pose.rotations.col(kLeftElbow) = Eigen::Vector3d(0.0, 0.0, 1.5);
  const Eigen::Matrix3Xd posed = PoseVertices(body, Eigen::VectorXd(), pose);
  int moved = 0;
  for (int i = 0; i < body.num_vertices(); ++i) {
    const double d = (posed.col(i) - body.template_vertices.col(i)).norm();
    if (body.template_vertices(0, i) < 0.0) {
      EXPECT_LT(d, 1e-12) << "right-side vertex " << i;
    }
    if (d > 1e-6) ++moved;
  }
  EXPECT_GT(moved, 100);  // forearm and hand
}

TEST(BodyModel, PoseCorrectivesAreApplied) {
  BodyModel body = ProceduralBody();
  Rng rng(5);
  body.pose_dirs = Eigen::MatrixXd::Zero(3 * body.num_vertices(),
                                         9 * (body.num_joints() - 1));
  for (Eigen::Index i = 0; i < body.pose_dirs.size(); i += 97) {
    body.pose_dirs.data()[i] = 0.01 * rng.Normal();
  }
  body.Validate();
  // Rest pose: (R - I) = 0, no effect.
  EXPECT_LT((PoseVertices(body, Eigen::VectorXd(), BodyPose::Rest(24)) -
             body.template_vertices)
                .norm(),
            1e-12);
  // Root-only rotation: features of non-root joints are 0, so the result is
  // still rigid.
  BodyPose pose = BodyPose::Rest(24);
  pose.rotations.col(kLeftKnee) = Eigen::Vector3d(0.7, 0.0, 0.0);
  BodyModel plain = body;
  plain.pose_dirs.resize(0, 0);
  const Eigen::Matrix3Xd with = PoseVertices(body, Eigen::VectorXd(), pose);
  const Eigen::Matrix3Xd without = PoseVertices(plain, Eigen::VectorXd(), pose);
  EXPECT_GT((with - without).norm(), 1e-4);
}

TEST(BodyModel, NormalsOfAnOctahedronPointOutward) {
  Eigen::Matrix3Xd v;
  Eigen::Matrix3Xi f;
  Octahedron(&v, &f);
  const Eigen::Matrix3Xd n = VertexNormals(v, f);
  for (int i = 0; i < 6; ++i) {
    EXPECT_NEAR(n.col(i).norm(), 1.0, kTol);
    EXPECT_LT((n.col(i) - v.col(i)).norm(), 1e-12) << i;
  }
  Eigen::Matrix3Xi bad = f;
  bad(0, 0) = 6;
  EXPECT_THROW(VertexNormals(v, bad), ShapeError);
}

TEST(BodyModel, NeighboursAndRingsOfAnOctahedron) {
  Eigen::Matrix3Xd v;
  Eigen::Matrix3Xi f;
  Octahedron(&v, &f);
  const auto nb = VertexNeighbours(6, f);
  EXPECT_EQ(nb[0], (std::vector<int>{2, 3, 4, 5}));
  EXPECT_EQ(nb[4], (std::vector<int>{0, 1, 2, 3}));
  EXPECT_TRUE(NRing(nb, 0, 0).empty());
  EXPECT_EQ(NRing(nb, 0, 1), (std::vector<int>{2, 3, 4, 5}));
  EXPECT_EQ(NRing(nb, 0, 2), (std::vector<int>{1, 2, 3, 4, 5}));
  EXPECT_EQ(NRing(nb, 0, 10), (std::vector<int>{1, 2, 3, 4, 5}));
  EXPECT_THROW(NRing(nb, 6, 1), ShapeError);
}

TEST(BodyModel, RingsOfAPath) {
  // A strip of triangles 0-1-2-3-4-5 where ring distance is known.
  Eigen::Matrix3Xi f(3, 4);
  f << 0, 1, 2, 3,  //
      1, 2, 3, 4,   //
      2, 3, 4, 5;
  const auto nb = VertexNeighbours(6, f);
  EXPECT_EQ(NRing(nb, 0, 1), (std::vector<int>{1, 2}));
  EXPECT_EQ(NRing(nb, 0, 2), (std::vector<int>{1, 2, 3, 4}));
  EXPECT_EQ(NRing(nb, 5, 1), (std::vector<int>{3, 4}));
}

}  // namespace
}  // namespace soma
