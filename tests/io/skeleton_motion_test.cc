#include "framework/io/skeleton_motion.h"

#include "framework/core/error.h"
#include "framework/io/asf_amc.h"
#include "framework/io/bvh.h"
#include "framework/testing/rotations.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <vector>

namespace soma {
namespace {

constexpr double kTol = 1e-12;
// Rotation matrices written out element by element (testing/rotations.h),
// so the expectations do not share code with the implementation.
using testing::kPi;
using testing::Rx;
using testing::Ry;
using testing::Rz;

// root -> a -> b -> b_end, and root -> c.
Skeleton ChainSkeleton() {
  Skeleton skeleton;
  skeleton.names = {"root", "a", "b", "b_end", "c"};
  skeleton.parents = {-1, 0, 1, 2, 0};
  skeleton.offsets = {Eigen::Vector3d::Zero(),
                      Eigen::Vector3d(0.1, 0.0, 0.0),
                      Eigen::Vector3d(0.0, -0.4, 0.0),
                      Eigen::Vector3d(0.0, -0.3, 0.1),
                      Eigen::Vector3d(0.0, 0.5, 0.0)};
  skeleton.channels = {{{ChannelType::kXPosition},
                        {ChannelType::kYPosition},
                        {ChannelType::kZPosition},
                        {ChannelType::kZRotation},
                        {ChannelType::kYRotation},
                        {ChannelType::kXRotation}},
                       {{ChannelType::kXRotation},
                        {ChannelType::kYRotation},
                        {ChannelType::kZRotation}},
                       {{ChannelType::kXRotation}},
                       {},
                       {{ChannelType::kYRotation}}};
  skeleton.dof_frames.assign(5, Eigen::Quaterniond::Identity());
  return skeleton;
}

TEST(ForwardKinematics, MatchesExplicitMatrixProducts) {
  const Skeleton skeleton = ChainSkeleton();
  const Eigen::Matrix3d l0 = Rz(30) * Rx(-50);
  const Eigen::Matrix3d l1 = Ry(70) * Rx(20);
  const Eigen::Matrix3d l2 = Rx(-90);
  const Eigen::Matrix3d l4 = Rz(15);
  const std::vector<Eigen::Quaterniond> local = {Eigen::Quaterniond(l0),
                                                 Eigen::Quaterniond(l1),
                                                 Eigen::Quaterniond(l2),
                                                 Eigen::Quaterniond::Identity(),
                                                 Eigen::Quaterniond(l4)};
  const Eigen::Vector3d root(1.0, 0.9, -2.0);
  const std::vector<Eigen::Isometry3d> pose =
      ForwardKinematics(skeleton, root, local);
  ASSERT_EQ(pose.size(), 5u);

  const Eigen::Vector3d p1 = root + l0 * Eigen::Vector3d(0.1, 0, 0);
  const Eigen::Vector3d p2 = p1 + l0 * l1 * Eigen::Vector3d(0, -0.4, 0);
  const Eigen::Vector3d p3 = p2 + l0 * l1 * l2 * Eigen::Vector3d(0, -0.3, 0.1);
  const Eigen::Vector3d p4 = root + l0 * Eigen::Vector3d(0, 0.5, 0);
  EXPECT_TRUE(pose[0].translation().isApprox(root, kTol));
  EXPECT_TRUE(pose[1].translation().isApprox(p1, kTol));
  EXPECT_TRUE(pose[2].translation().isApprox(p2, kTol));
  EXPECT_TRUE(pose[3].translation().isApprox(p3, kTol));
  EXPECT_TRUE(pose[4].translation().isApprox(p4, kTol));
  EXPECT_TRUE(pose[2].linear().isApprox(l0 * l1 * l2, kTol));
  EXPECT_TRUE(pose[4].linear().isApprox(l0 * l4, kTol));
}

TEST(ForwardKinematics, HandComputedQuarterTurn) {
  Skeleton skeleton = ChainSkeleton();
  std::vector<Eigen::Quaterniond> local(5, Eigen::Quaterniond::Identity());
  // Root yawed +90 degrees about Z: +X maps to +Y.
  local[0] =
      Eigen::Quaterniond(Eigen::AngleAxisd(kPi / 2, Eigen::Vector3d::UnitZ()));
  const auto pose = ForwardKinematics(skeleton, Eigen::Vector3d::Zero(), local);
  EXPECT_TRUE(
      pose[1].translation().isApprox(Eigen::Vector3d(0, 0.1, 0), 1e-12));
  // p1 + Rz90 (0, -0.4, 0) = (0, 0.1, 0) + (0.4, 0, 0).
  EXPECT_TRUE(
      pose[2].translation().isApprox(Eigen::Vector3d(0.4, 0.1, 0), 1e-12));
}

TEST(ForwardKinematics, WrongSizeThrows) {
  const Skeleton skeleton = ChainSkeleton();
  EXPECT_THROW(ForwardKinematics(skeleton,
                                 Eigen::Vector3d::Zero(),
                                 std::vector<Eigen::Quaterniond>(3)),
               ShapeError);
}

TEST(Skeleton, FindChildrenEndSitesRestPositions) {
  const Skeleton skeleton = ChainSkeleton();
  EXPECT_NO_THROW(skeleton.Validate());
  EXPECT_EQ(skeleton.Find("b"), 2);
  EXPECT_EQ(skeleton.Find("missing"), -1);
  EXPECT_EQ(skeleton.Children(0), (std::vector<int>{1, 4}));
  EXPECT_TRUE(skeleton.IsEndSite(3));
  EXPECT_FALSE(skeleton.IsEndSite(2));
  const auto rest = skeleton.RestPositions();
  EXPECT_TRUE(rest[3].isApprox(Eigen::Vector3d(0.1, -0.7, 0.1), kTol));
}

TEST(Skeleton, ValidateRejectsBrokenTrees) {
  Skeleton bad_parent = ChainSkeleton();
  bad_parent.parents[2] = 3;
  EXPECT_THROW(bad_parent.Validate(), ShapeError);
  Skeleton duplicate = ChainSkeleton();
  duplicate.names[4] = "a";
  EXPECT_THROW(duplicate.Validate(), ShapeError);
  Skeleton sizes = ChainSkeleton();
  sizes.offsets.pop_back();
  EXPECT_THROW(sizes.Validate(), ShapeError);
  Skeleton translating = ChainSkeleton();
  translating.channels[1].push_back({ChannelType::kXPosition});
  EXPECT_THROW(translating.Validate(), ShapeError);
}

TEST(Skeleton, RotationFromChannelsConventions) {
  Skeleton skeleton = ChainSkeleton();
  const std::vector<double> angles = {
      0.3, -0.7, 1.1};  // rx, ry, rz for joint "a"
  const double d = 180 / kPi;
  // Moving axes (BVH): listed order X Y Z -> Rx * Ry * Rz.
  skeleton.euler_convention = EulerConvention::kMovingAxes;
  EXPECT_TRUE(
      skeleton.RotationFromChannels(1, angles).toRotationMatrix().isApprox(
          Rx(0.3 * d) * Ry(-0.7 * d) * Rz(1.1 * d), kTol));
  // Fixed axes (ASF): X applied first -> Rz * Ry * Rx.
  skeleton.euler_convention = EulerConvention::kFixedAxes;
  EXPECT_TRUE(
      skeleton.RotationFromChannels(1, angles).toRotationMatrix().isApprox(
          Rz(1.1 * d) * Ry(-0.7 * d) * Rx(0.3 * d), kTol));
  // A dof frame C conjugates: L = C R C^-1.
  const Eigen::Matrix3d c = Rz(20) * Rx(-35);
  skeleton.dof_frames[1] = Eigen::Quaterniond(c);
  EXPECT_TRUE(
      skeleton.RotationFromChannels(1, angles).toRotationMatrix().isApprox(
          c * Rz(1.1 * d) * Ry(-0.7 * d) * Rx(0.3 * d) * c.transpose(), kTol));
  // Root: position channels are skipped.
  EXPECT_EQ(skeleton.NumRotationChannels(0), 3);
  EXPECT_THROW(skeleton.RotationFromChannels(1, std::vector<double>{0.1}),
               ShapeError);
}

TEST(UpAxis, StringRoundTrip) {
  EXPECT_EQ(ToString(UpAxis::kY), "Y");
  EXPECT_EQ(UpAxisFromString("Z"), UpAxis::kZ);
  EXPECT_THROW(UpAxisFromString("X"), ConfigError);
  EXPECT_EQ(ToString(ChannelType::kZRotation), "Zrotation");
}

// A 9-frame clip at 120 Hz with distinct rotations and translations.
MotionClip SyntheticClip(int frames) {
  MotionClip clip;
  clip.name = "synthetic";
  clip.frame_rate = 120.0;
  clip.skeleton = ChainSkeleton();
  for (int t = 0; t < frames; ++t) {
    clip.root_translation.emplace_back(
        0.01 * t, 1.0 + 0.002 * t * t, -0.03 * t);
    std::vector<Eigen::Quaterniond> rotations;
    rotations.reserve(5);
    for (int j = 0; j < 5; ++j) {
      rotations.emplace_back(
          Eigen::AngleAxisd(0.05 * t * (j + 1),
                            Eigen::Vector3d(1.0, 0.5 * j, -0.3).normalized()));
    }
    clip.local_rotations.push_back(rotations);
  }
  return clip;
}

TEST(ResampleClip, AlignedFramesAreCopiedExactly) {
  const MotionClip clip = SyntheticClip(9);
  const MotionClip out = ResampleClip(clip, 30.0);
  EXPECT_DOUBLE_EQ(out.frame_rate, 30.0);
  ASSERT_EQ(out.num_frames(), 3);  // source frames 0, 4, 8
  for (int k = 0; k < out.num_frames(); ++k) {
    const size_t source = 4 * static_cast<size_t>(k);
    EXPECT_EQ(out.root_translation[k], clip.root_translation[source]);
    for (int j = 0; j < 5; ++j) {
      EXPECT_EQ(out.local_rotations[k][j].coeffs(),
                clip.local_rotations[source][j].coeffs());
    }
  }
}

TEST(ResampleClip, InterpolatesBetweenFrames) {
  const MotionClip clip = SyntheticClip(9);
  const MotionClip out = ResampleClip(clip, 80.0);  // source step 1.5 frames
  ASSERT_EQ(out.num_frames(), 6);                   // 0, 1.5, ..., 7.5
  // Frame 1 is source time 1.5: halfway between frames 1 and 2.
  EXPECT_TRUE(out.root_translation[1].isApprox(
      0.5 * (clip.root_translation[1] + clip.root_translation[2]), 1e-12));
  for (int j = 0; j < 5; ++j) {
    const Eigen::Quaterniond& q = out.local_rotations[1][j];
    const Eigen::Quaterniond& a = clip.local_rotations[1][j];
    const Eigen::Quaterniond& b = clip.local_rotations[2][j];
    // Same axis here, so slerp halfway = the mean angle.
    EXPECT_NEAR(q.angularDistance(a), q.angularDistance(b), 1e-9);
    EXPECT_NEAR(q.angularDistance(a), 0.5 * a.angularDistance(b), 1e-9);
  }
  // Frame 2 is source time 3.0 exactly.
  EXPECT_EQ(out.root_translation[2], clip.root_translation[3]);
}

TEST(ResampleClip, UpsamplesAndRejectsBadRates) {
  const MotionClip clip = SyntheticClip(5);
  const MotionClip up = ResampleClip(clip, 240.0);
  EXPECT_EQ(up.num_frames(), 9);
  EXPECT_EQ(up.root_translation[8], clip.root_translation[4]);
  EXPECT_THROW(ResampleClip(clip, 0.0), ShapeError);
  EXPECT_THROW(ResampleClip(SyntheticClip(0), 30.0), ShapeError);
}

TEST(ConvertYUpToZUp, RotatesWorldAndKeepsDistances) {
  const MotionClip clip = SyntheticClip(5);
  const MotionClip z_up = ConvertYUpToZUp(clip);
  EXPECT_EQ(z_up.up_axis, UpAxis::kZ);
  for (int t = 0; t < clip.num_frames(); ++t) {
    const auto before = clip.JointPositions(t);
    const auto after = z_up.JointPositions(t);
    for (size_t j = 0; j < before.size(); ++j) {
      // (x, y, z) -> (x, -z, y).
      EXPECT_NEAR(after[j].x(), before[j].x(), 1e-12);
      EXPECT_NEAR(after[j].y(), -before[j].z(), 1e-12);
      EXPECT_NEAR(after[j].z(), before[j].y(), 1e-12);
    }
  }
  // Rest pose stays world-aligned: offsets rotated the same way.
  EXPECT_TRUE(
      z_up.skeleton.offsets[2].isApprox(Eigen::Vector3d(0, 0, -0.4), kTol));
  EXPECT_THROW(ConvertYUpToZUp(z_up), InternalError);
}

TEST(ConvertYUpToZUp, RealTakeHeadAboveFeetAndDistancesKept) {
  const auto dir = testing::SharedDataDir() / "motion" / "hdm05_amc";
  if (!std::filesystem::exists(dir)) GTEST_SKIP() << "no " << dir;
  const MotionClip clip =
      ReadAsfAmc(dir / "HDM_bd.asf", dir / "HDM_bd_squat1Reps_003_120.amc");
  const MotionClip z_up = ConvertYUpToZUp(clip);
  const Skeleton& s = z_up.skeleton;
  for (int t = 0; t < z_up.num_frames(); t += 7) {
    const auto before = clip.JointPositions(t);
    const auto after = z_up.JointPositions(t);
    EXPECT_GT(after[s.Find("head")].z(), after[s.Find("ltoes")].z() + 0.5);
    EXPECT_GT(after[s.Find("head")].z(), after[s.Find("rfoot")].z() + 0.5);
    for (size_t i = 0; i < before.size(); ++i) {
      for (size_t j = i + 1; j < before.size(); j += 5) {
        EXPECT_NEAR(
            (after[i] - after[j]).norm(), (before[i] - before[j]).norm(), 1e-9);
      }
    }
  }
  // The dof frames still reproduce the local rotations from channel values:
  // frame 0 of rfemur is AMC "rfemur -10.3415 1.78495 26.6677" (degrees).
  const int rfemur = s.Find("rfemur");
  const double d = kPi / 180;
  const std::vector<double> angles = {-10.3415 * d, 1.78495 * d, 26.6677 * d};
  EXPECT_TRUE(s.RotationFromChannels(rfemur, angles)
                  .isApprox(z_up.local_rotations[0][rfemur], 1e-9));
}

TEST(MotionClip, ValidateAndDuration) {
  MotionClip clip = SyntheticClip(9);
  EXPECT_NO_THROW(clip.Validate());
  EXPECT_DOUBLE_EQ(clip.duration(), 8.0 / 120.0);
  clip.root_translation.pop_back();
  EXPECT_THROW(clip.Validate(), ShapeError);
  MotionClip rate = SyntheticClip(2);
  rate.frame_rate = 0.0;
  EXPECT_THROW(rate.Validate(), ShapeError);
}

}  // namespace
}  // namespace soma
