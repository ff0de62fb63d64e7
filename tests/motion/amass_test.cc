#include "framework/motion/amass.h"

#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/io/npz.h"
#include "framework/motion/motion_source.h"
#include "framework/registry/registry.h"
#include "framework/testing/body_fixture.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include <cmath>

namespace soma {
namespace {

const BodyModel& Body() { return testing::ProceduralBody(); }

/// Writes an AMASS-style npz: `frames` frames at `rate` Hz, SMPL+H sized
/// poses (52 joints) with the left knee flexed by `knee_rad` about SMPL's +X
/// (shank backwards in SMPL's frame) and a root walking along SMPL's +Z
/// (forward) at 1 m/s.
void WriteFixture(const std::filesystem::path& path,
                  int frames,
                  double rate,
                  double knee_rad) {
  std::vector<double> poses(frames * 156, 0.0), trans(frames * 3, 0.0);
  for (int t = 0; t < frames; ++t) {
    poses[t * 156 + 3 * 4 + 0] = knee_rad;  // joint 4 = left knee, x component
    trans[t * 3 + 1] = 0.9;                 // SMPL y (up)
    trans[t * 3 + 2] = t / rate;            // SMPL z (forward)
  }
  WriteNpz(path,
           {{"poses", NpyArray::FromDoubles({frames, 156}, poses)},
            {"trans", NpyArray::FromDoubles({frames, 3}, trans)},
            {"mocap_framerate", NpyArray::FromDoubles({}, {rate})},
            {"gender", NpyArray::FromStrings({}, {"neutral"})}});
}

TEST(Amass, ConvertsRotationsAndTrajectoryToOurFrame) {
  const auto dir = testing::CreateTestDir();
  WriteFixture(dir / "walk_poses.npz", 120, 120.0, 0.5);
  const PoseSequence seq = LoadAmassNpz(dir / "walk_poses.npz", Body());
  ASSERT_EQ(seq.num_frames(), 120);
  EXPECT_EQ(seq.frame_rate, 120.0);
  // SMPL +X stays our +X: knee flexion about +X.
  EXPECT_NEAR(seq.frames[0].rotations(0, kLeftKnee), 0.5, 1e-12);
  EXPECT_NEAR(
      seq.frames[0].rotations.col(kLeftKnee).tail<2>().norm(), 0.0, 1e-12);
  // SMPL forward (+Z) is our forward (-Y).
  EXPECT_NEAR(seq.frames[119].translation.y() - seq.frames[0].translation.y(),
              -119 / 120.0,
              1e-9);
  // The flexed knee moves the left ankle backwards (+Y): the body faces -Y.
  const PosedSkeleton s = PoseSkeleton(
      Body(), Body().RestJoints(Body().template_vertices), seq.frames[0]);
  EXPECT_GT(s.global[kLeftAnkle].translation().y(),
            s.global[kLeftKnee].translation().y() + 0.05);
  EXPECT_NEAR(std::min(s.global[kLeftFoot].translation().z(),
                       s.global[kRightFoot].translation().z()),
              0.03,
              0.02);
}

TEST(Amass, ResamplesTo30HzThroughTheMotionSource) {
  const auto dir = testing::CreateTestDir();
  WriteFixture(dir / "a.npz", 121, 120.0, 0.2);
  WriteFixture(dir / "b.npz", 61, 60.0, 0.4);
  BuildContext ctx;
  const auto source = Instantiate<MotionSource>(
      ParseYaml("name: amass\ndir: " + dir.string() +
                    "\nval_fraction: 0\ntest_fraction: 0\n",
                "<test>"),
      ctx);
  Rng rng(0);
  const std::vector<PoseSequence> clips =
      source->Load(Body(), Split::kTrain, 30.0, rng);
  ASSERT_EQ(clips.size(), 2u);
  for (const PoseSequence& clip : clips) {
    EXPECT_EQ(clip.frame_rate, 30.0);
    EXPECT_EQ(clip.num_frames(), 31) << clip.name;  // 1 s at 30 Hz, both ends
  }
}

TEST(Amass, WrongShapesAndMissingKeysAreClearErrors) {
  const auto dir = testing::CreateTestDir();
  WriteNpz(dir / "bad.npz",
           {{"poses", NpyArray::FromDoubles({2, 30}, std::vector<double>(60))},
            {"trans", NpyArray::FromDoubles({2, 3}, std::vector<double>(6))},
            {"mocap_framerate", NpyArray::FromDoubles({}, {120.0})}});
  const std::string message = testing::ErrorMessage<IoError>(
      [&] { LoadAmassNpz(dir / "bad.npz", Body()); });
  EXPECT_NE(message.find("'poses' must be T x 3J"), std::string::npos)
      << message;
  WriteNpz(
      dir / "nokey.npz",
      {{"poses", NpyArray::FromDoubles({1, 66}, std::vector<double>(66))}});
  EXPECT_NE(testing::ErrorMessage<IoError>([&] {
              LoadAmassNpz(dir / "nokey.npz", Body());
            }).find("missing key 'trans'"),
            std::string::npos);
}

}  // namespace
}  // namespace soma
