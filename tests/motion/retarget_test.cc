#include "framework/motion/retarget.h"

#include "framework/config/yaml_io.h"
#include "framework/io/asf_amc.h"
#include "framework/io/bvh.h"
#include "framework/motion/motion_source.h"
#include "framework/registry/registry.h"
#include "framework/testing/body_fixture.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include <cmath>

namespace soma {
namespace {

const BodyModel& Body() { return testing::ProceduralBody(); }

/// Angle (degrees) between the body's bone (joint -> child) and the source
/// bone (s -> s_child) at frame t.
double BoneAngleDeg(const PoseSequence& seq,
                    const MotionClip& clip,
                    int t,
                    int joint,
                    int child,
                    const std::string& s,
                    const std::string& s_child) {
  const BodyModel& body = Body();
  const PosedSkeleton posed = PoseSkeleton(
      body, body.RestJoints(body.template_vertices), seq.frames[t]);
  const Eigen::Vector3d ours =
      posed.global[child].translation() - posed.global[joint].translation();
  const std::vector<Eigen::Vector3d> p = clip.JointPositions(t);
  const Eigen::Vector3d theirs =
      p[clip.skeleton.Find(s_child)] - p[clip.skeleton.Find(s)];
  return std::acos(std::clamp(
             ours.normalized().dot(theirs.normalized()), -1.0, 1.0)) *
         180 / M_PI;
}

void ExpectBonesFollowTheSource(const MotionClip& clip,
                                const RetargetMap& map) {
  const PoseSequence seq = Retarget(clip, Body(), map);
  ASSERT_EQ(seq.num_frames(), clip.num_frames());
  const struct {
    int joint, child;
    const char* s;
    const char* s_child;
  } bones_cmu[] = {{kLeftHip, kLeftKnee, "LeftHip", "LeftKnee"},
                   {kRightKnee, kRightAnkle, "RightKnee", "RightAnkle"},
                   {kLeftShoulder, kLeftElbow, "LeftShoulder", "LeftElbow"},
                   {kRightElbow, kRightWrist, "RightElbow", "RightWrist"}},
    bones_asf[] = {{kLeftHip, kLeftKnee, "lfemur", "ltibia"},
                   {kRightKnee, kRightAnkle, "rtibia", "rfoot"},
                   {kLeftShoulder, kLeftElbow, "lhumerus", "lradius"},
                   {kRightElbow, kRightWrist, "rradius", "rwrist"}};
  const bool cmu = map.name == "cmu_bvh";
  for (int t = 0; t < clip.num_frames();
       t += std::max(1, clip.num_frames() / 7)) {
    for (const auto& b : cmu ? bones_cmu : bones_asf) {
      EXPECT_LT(BoneAngleDeg(seq, clip, t, b.joint, b.child, b.s, b.s_child),
                1.0)
          << clip.name << " frame " << t << " " << b.s;
    }
  }
}

TEST(Retarget, CmuBvhBonesPointWhereTheSourceBonesPoint) {
  const MotionClip clip = ConvertYUpToZUp(ResampleClip(
      ReadBvh(testing::SharedDataDir() / "motion/cmu_bvh/131_03.bvh"), 30.0));
  ExpectBonesFollowTheSource(clip, DetectRetargetMap(clip.skeleton, "131_03"));
}

TEST(Retarget, Hdm05AmcBonesPointWhereTheSourceBonesPoint) {
  const auto dir = testing::SharedDataDir() / "motion/hdm05_amc";
  const MotionClip clip = ConvertYUpToZUp(ResampleClip(
      ReadAsfAmc(dir / "HDM_bd.asf", dir / "HDM_bd_squat1Reps_003_120.amc"),
      30.0));
  ExpectBonesFollowTheSource(clip, DetectRetargetMap(clip.skeleton, "squat"));
}

TEST(Retarget, FeetStayNearTheFloorAndTheBodyFacesTheSourceDirection) {
  const auto dir = testing::SharedDataDir() / "motion/hdm05_amc";
  const MotionClip clip = ConvertYUpToZUp(ResampleClip(
      ReadAsfAmc(dir / "HDM_dg.asf",
                 dir / "HDM_dg_rotateArmsBothBackward1Reps_010_120.amc"),
      30.0));
  const PoseSequence seq = Retarget(clip, Body(), AsfRetargetMap());
  const BodyModel& body = Body();
  const Eigen::Matrix3Xd rest = body.RestJoints(body.template_vertices);
  for (int t = 0; t < seq.num_frames(); t += 5) {
    const PosedSkeleton s = PoseSkeleton(body, rest, seq.frames[t]);
    const double ankle = std::min(s.global[kLeftAnkle].translation().z(),
                                  s.global[kRightAnkle].translation().z());
    EXPECT_GT(ankle, 0.0) << t;
    EXPECT_LT(ankle, 0.2) << t;
    EXPECT_GT(s.global[kHead].translation().z(), 1.3) << t;
  }
}

TEST(FileMotionSource, LoadsEveryHdm05ClipThroughTheRegistry) {
  BuildContext ctx;
  const auto source = Instantiate<MotionSource>(
      ParseYaml("name: asf_amc\ndir: " +
                    (testing::SharedDataDir() / "motion/hdm05_amc").string() +
                    "\nmax_frames_per_clip: 10\nval_fraction: "
                    "0.0\ntest_fraction: 0.0\n",
                "<test>"),
      ctx);
  Rng rng(0);
  const std::vector<PoseSequence> clips =
      source->Load(Body(), Split::kTrain, 30.0, rng);
  EXPECT_EQ(clips.size(), 22u);
  for (const PoseSequence& clip : clips) {
    EXPECT_EQ(clip.num_frames(), 10) << clip.name;
    EXPECT_EQ(clip.frame_rate, 30.0);
  }
}

TEST(FileMotionSource, MissingDirectoryIsAClearError) {
  BuildContext ctx;
  const auto source = Instantiate<MotionSource>(
      ParseYaml("name: bvh\ndir: /nonexistent/bvh\n", "<test>"), ctx);
  Rng rng(0);
  try {
    source->Load(Body(), Split::kTrain, 30.0, rng);
    FAIL();
  } catch (const IoError& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/bvh"),
              std::string::npos);
  }
}

}  // namespace
}  // namespace soma
