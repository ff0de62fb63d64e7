#include "framework/io/bvh.h"

#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/testing/rotations.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

namespace soma {
namespace {

constexpr double kTol = 1e-12;
using testing::kPi;
using testing::Rx;
using testing::Ry;
using testing::Rz;

// Three joints with unusual channel orders and an End Site; centimetres.
// Line numbers matter for the error tests below (frame lines are 24-26).
constexpr char kTinyHierarchy[] = R"(HIERARCHY
ROOT Hips
{
  OFFSET 1 2 3
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Knee
  {
    OFFSET 0 -10 0
    CHANNELS 3 Yrotation Xrotation Zrotation
    JOINT Ankle
    {
      OFFSET 0 -8 2
      CHANNELS 2 Xrotation Zrotation
      End Site
      {
        OFFSET 0 0 3
      }
    }
  }
}
MOTION
)";

std::string TinyBvh(const std::string& frames_header,
                    const std::string& frames) {
  return std::string(kTinyHierarchy) + frames_header + frames;
}

const std::string kTinyFrames =
    "10 20 30 30 -20 45 10 20 30 -40 25\n"
    "0 0 0 90 0 0 0 0 0 0 0\n"
    "0 0 0 0 0 0 0 0 0 0 0\n";

BvhReadOptions Centimetres() {
  BvhReadOptions options;
  options.length_to_metres = 0.01;
  return options;
}

TEST(ReadBvh, TinyFileMatchesExplicitForwardKinematics) {
  const auto dir = testing::CreateTestDir();
  testing::WriteTextFile(
      dir, "tiny.bvh", TinyBvh("Frames: 3\nFrame Time: 0.5\n", kTinyFrames));
  const MotionClip clip = ReadBvh(dir / "tiny.bvh", Centimetres());
  ASSERT_EQ(clip.num_frames(), 3);
  EXPECT_EQ(clip.name, "tiny");
  EXPECT_DOUBLE_EQ(clip.frame_rate, 2.0);
  EXPECT_EQ(clip.up_axis, UpAxis::kY);
  EXPECT_EQ(clip.skeleton.names,
            (std::vector<std::string>{"Hips", "Knee", "Ankle", "Ankle_end"}));
  EXPECT_EQ(clip.skeleton.parents, (std::vector<int>{-1, 0, 1, 2}));
  EXPECT_TRUE(clip.skeleton.IsEndSite(3));

  // Frame 0 by explicit products: G = G_parent * R(c1) R(c2) R(c3).
  const double s = 0.01;
  const Eigen::Vector3d root = Eigen::Vector3d(1 + 10, 2 + 20, 3 + 30) * s;
  const Eigen::Matrix3d g0 = Rz(30) * Rx(-20) * Ry(45);
  const Eigen::Matrix3d g1 = g0 * Ry(10) * Rx(20) * Rz(30);
  const Eigen::Matrix3d g2 = g1 * Rx(-40) * Rz(25);
  const Eigen::Vector3d knee = root + g0 * Eigen::Vector3d(0, -10, 0) * s;
  const Eigen::Vector3d ankle = knee + g1 * Eigen::Vector3d(0, -8, 2) * s;
  const Eigen::Vector3d tip = ankle + g2 * Eigen::Vector3d(0, 0, 3) * s;
  const std::vector<Eigen::Isometry3d> pose = clip.GlobalPose(0);
  EXPECT_TRUE(pose[0].translation().isApprox(root, kTol));
  EXPECT_TRUE(pose[1].translation().isApprox(knee, kTol));
  EXPECT_TRUE(pose[2].translation().isApprox(ankle, kTol));
  EXPECT_TRUE(pose[3].translation().isApprox(tip, kTol));
  EXPECT_TRUE(pose[2].linear().isApprox(g2, kTol));

  // Frame 1, worked by hand: root at the OFFSET (1, 2, 3) cm, yawed +90
  // degrees about Z, so the knee offset (0, -10, 0) becomes (10, 0, 0).
  const auto p1 = clip.JointPositions(1);
  EXPECT_TRUE(p1[0].isApprox(Eigen::Vector3d(0.01, 0.02, 0.03), kTol));
  EXPECT_TRUE(p1[1].isApprox(Eigen::Vector3d(0.11, 0.02, 0.03), kTol));
  // Frame 2 is the rest pose: offsets add up.
  const auto p2 = clip.JointPositions(2);
  EXPECT_TRUE(
      p2[3].isApprox(Eigen::Vector3d(0.01, 0.02 - 0.18, 0.03 + 0.05), kTol));
}

TEST(ReadBvh, DefaultUnitsAreCmu) {
  EXPECT_NEAR(kCmuLengthUnitToMetres, 0.056444, 1e-6);
  const MotionClip clip = ParseBvh(
      TinyBvh("Frames: 3\nFrame Time: .0083333\n", kTinyFrames), "x.bvh");
  EXPECT_DOUBLE_EQ(clip.frame_rate, 120.0);  // 1 / .0083333 rounded
  EXPECT_NEAR(clip.skeleton.offsets[1].y(), -10 * kCmuLengthUnitToMetres, kTol);
}

// Expects an IoError whose message contains every fragment.
void ExpectIoError(const std::string& text,
                   const std::vector<std::string>& fragments) {
  try {
    ParseBvh(text, "/data/bad.bvh");
    ADD_FAILURE() << "no IoError; expected " << fragments[0];
  } catch (const IoError& error) {
    const std::string message = error.what();
    EXPECT_EQ(message.find('\n'), std::string::npos) << message;
    for (const std::string& fragment : fragments) {
      EXPECT_NE(message.find(fragment), std::string::npos)
          << "'" << message << "' lacks '" << fragment << "'";
    }
  }
}

TEST(ReadBvh, TruncatedFrameLineNamesFileAndLine) {
  ExpectIoError(TinyBvh("Frames: 2\nFrame Time: 0.5\n",
                        "1 2 3 4 5 6 7 8 9 10 11\n1 2 3 4 5 6 7 8 9\n"),
                {"/data/bad.bvh:25:", "frame 1 has 9 values, expected 11"});
}

TEST(ReadBvh, FewerFramesThanAnnouncedIsAnError) {
  ExpectIoError(TinyBvh("Frames: 5\nFrame Time: 0.5\n", kTinyFrames),
                {"/data/bad.bvh:", "file ends after 3 of 5 frames", "line 22"});
}

TEST(ReadBvh, MoreFramesThanAnnouncedIsAnError) {
  ExpectIoError(TinyBvh("Frames: 2\nFrame Time: 0.5\n", kTinyFrames),
                {"/data/bad.bvh:26:", "more frame lines than 'Frames: 2'"});
}

TEST(ReadBvh, MalformedInputsThrowIoError) {
  ExpectIoError("", {"bad.bvh:1:", "expected HIERARCHY"});
  ExpectIoError(
      TinyBvh("Frames: 1\nFrame Time: 0.5\n", "1 2 3 4 5 6 7 8 9 10 x\n"),
      {"bad.bvh:24:", "not a number: 'x'"});
  ExpectIoError(TinyBvh("Frames: -1\nFrame Time: 0.5\n", ""), {"bad.bvh:22:"});
  ExpectIoError(TinyBvh("Frames: 1\nFrame Time: 0\n", kTinyFrames),
                {"bad.bvh:23:"});
  ExpectIoError(TinyBvh("Frames: 1\n", ""), {"bad.bvh:22:", "Frame Time"});
  std::string no_close = kTinyHierarchy;
  no_close.erase(no_close.rfind('}'));
  ExpectIoError(no_close, {"bad.bvh:", "expected '}'"});
  std::string bad_channel = kTinyHierarchy;
  bad_channel.replace(
      bad_channel.find("Yrotation Xrotation Zrotation"), 9, "Wrotation");
  ExpectIoError(bad_channel, {"bad.bvh:9:", "unknown channel 'Wrotation'"});
  std::string translating_joint = kTinyHierarchy;
  translating_joint.replace(translating_joint.find("CHANNELS 2 Xrotation"),
                            20,
                            "CHANNELS 2 Xposition");
  ExpectIoError(translating_joint,
                {"bad.bvh:13:", "only the ROOT may translate"});
  std::string keyword = kTinyHierarchy;
  keyword.replace(keyword.find("OFFSET 0 -8 2"), 6, "OFFSTE");
  ExpectIoError(keyword, {"bad.bvh:12:", "unexpected 'OFFSTE'"});
  std::string no_motion = kTinyHierarchy;
  no_motion.erase(no_motion.find("MOTION"));
  ExpectIoError(no_motion, {"bad.bvh:", "missing MOTION"});
}

TEST(ReadBvh, MissingFileThrowsIoErrorNamingIt) {
  const auto path = testing::CreateTestDir() / "does_not_exist.bvh";
  try {
    ReadBvh(path);
    ADD_FAILURE() << "no IoError";
  } catch (const IoError& error) {
    EXPECT_NE(std::string(error.what()).find("does_not_exist.bvh"),
              std::string::npos);
  }
}

TEST(ReadBvh, BadOptionsThrowConfigError) {
  BvhReadOptions options;
  options.length_to_metres = -1.0;
  EXPECT_THROW(ParseBvh(kTinyHierarchy, "x.bvh", options), ConfigError);
}

// ---------------------------------------------------------------------------
// Real CMU files (cgspeed conversion, 120 Hz).

std::vector<std::filesystem::path> CmuFiles() {
  std::vector<std::filesystem::path> files;
  const auto dir = testing::SharedDataDir() / "motion" / "cmu_bvh";
  if (!std::filesystem::exists(dir)) return files;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    if (entry.path().extension() == ".bvh") files.push_back(entry.path());
  }
  std::sort(files.begin(), files.end());
  return files;
}

// Frame count from the text, independent of the reader: the value after
// "Frames:" and the number of non-empty lines after "Frame Time:".
std::pair<int, int> CountFrames(const std::string& text) {
  std::istringstream in(text);
  std::string line;
  int announced = -1, lines = 0;
  bool data = false;
  while (std::getline(in, line)) {
    if (data) {
      if (line.find_first_not_of(" \t\r") != std::string::npos) ++lines;
    } else if (line.rfind("Frames:", 0) == 0) {
      announced = std::stoi(line.substr(7));
    } else if (line.rfind("Frame Time:", 0) == 0) {
      data = true;
    }
  }
  return {announced, lines};
}

double VerticalExtent(const std::vector<Eigen::Vector3d>& points) {
  double lo = points[0].y(), hi = points[0].y();
  for (const auto& p : points) {
    lo = std::min(lo, p.y());
    hi = std::max(hi, p.y());
  }
  return hi - lo;
}

TEST(ReadBvh, RealCmuFilesParseWithPlausibleAnatomy) {
  const auto files = CmuFiles();
  if (files.empty()) GTEST_SKIP() << "no shared CMU BVH data";
  ASSERT_EQ(files.size(), 3u);
  for (const auto& path : files) {
    SCOPED_TRACE(path.string());
    const MotionClip clip = ReadBvh(path);
    const auto [announced, lines] = CountFrames(ReadFile(path));
    EXPECT_EQ(clip.num_frames(), announced);
    EXPECT_EQ(clip.num_frames(), lines);
    EXPECT_GT(clip.num_frames(), 900);
    EXPECT_DOUBLE_EQ(clip.frame_rate, 120.0);
    const Skeleton& s = clip.skeleton;
    EXPECT_EQ(s.num_joints(), 38);  // 31 joints + 7 End Sites
    for (const char* name :
         {"Hips", "LeftKnee", "RightToe_end", "Head_end", "LThumb_end"}) {
      EXPECT_GE(s.Find(name), 0) << name;
    }
    // Rest pose: legs splayed 20 degrees outwards (CMU ASF femur axis) and
    // chains ending at the head joint, hence a bit below standing height.
    const double rest_height = VerticalExtent(s.RestPositions());
    EXPECT_GT(rest_height, 1.3);
    EXPECT_LT(rest_height, 2.1);
    // Standing at the first frame.
    const auto p0 = clip.JointPositions(0);
    EXPECT_GT(VerticalExtent(p0), 1.3);
    EXPECT_LT(VerticalExtent(p0), 2.1);
    EXPECT_GT(p0[s.Find("Head")].y(), p0[s.Find("Hips")].y() + 0.3);
    EXPECT_GT(p0[s.Find("Hips")].y(), p0[s.Find("LeftAnkle")].y() + 0.6);
    // Thigh (hip to knee) and left/right symmetry of the limbs.
    const double thigh = s.offsets[s.Find("LeftKnee")].norm();
    EXPECT_GT(thigh, 0.3);
    EXPECT_LT(thigh, 0.6);
    for (const auto& [left, right] :
         std::vector<std::pair<std::string, std::string>>{
             {"LeftKnee", "RightKnee"},
             {"LeftAnkle", "RightAnkle"},
             {"LeftToe", "RightToe"},
             {"LeftElbow", "RightElbow"},
             {"LeftWrist", "RightWrist"}}) {
      const double l = s.offsets[s.Find(left)].norm();
      const double r = s.offsets[s.Find(right)].norm();
      // Subject 131's calibration is asymmetric by up to 8% (feet 2.26 vs
      // 2.09 units, humeri 4.25 vs 4.46); a swapped or mis-scaled bone is
      // far outside this.
      EXPECT_NEAR(l / r, 1.0, 0.1) << left;
    }
    // Upright walking/hopping: the lowest joint of every frame is a foot
    // joint (ankle, toe or toe tip), near the floor y = 0.
    const std::vector<int> feet = {s.Find("LeftAnkle"),
                                   s.Find("LeftToe"),
                                   s.Find("LeftToe_end"),
                                   s.Find("RightAnkle"),
                                   s.Find("RightToe"),
                                   s.Find("RightToe_end")};
    double lowest_foot_overall = 1e9;
    for (int t = 0; t < clip.num_frames(); t += 3) {
      const auto p = clip.JointPositions(t);
      double lowest = 1e9, lowest_foot = 1e9;
      for (const auto& q : p) lowest = std::min(lowest, q.y());
      for (int f : feet) lowest_foot = std::min(lowest_foot, p[f].y());
      EXPECT_LT(lowest_foot, lowest + 0.03) << "frame " << t;
      lowest_foot_overall = std::min(lowest_foot_overall, lowest_foot);
    }
    EXPECT_NEAR(lowest_foot_overall, 0.0, 0.07);
  }
}

TEST(ResampleClip, RealBvhKeepsEveryFourthFrame) {
  const auto files = CmuFiles();
  if (files.empty()) GTEST_SKIP() << "no shared CMU BVH data";
  const MotionClip clip = ReadBvh(files[0]);
  const MotionClip out = ResampleClip(clip, 30.0);
  EXPECT_EQ(out.num_frames(), (clip.num_frames() - 1) / 4 + 1);
  for (int k = 0; k < out.num_frames(); ++k) {
    const size_t source = 4 * static_cast<size_t>(k);
    ASSERT_EQ(out.root_translation[k], clip.root_translation[source]);
    for (int j = 0; j < clip.num_joints(); ++j) {
      ASSERT_EQ(out.local_rotations[k][j].coeffs(),
                clip.local_rotations[source][j].coeffs());
    }
  }
}

TEST(ReadBvh, TruncatedRealFileNeverCrashes) {
  const auto files = CmuFiles();
  if (files.empty()) GTEST_SKIP() << "no shared CMU BVH data";
  const std::string text = ReadFile(files[0]);
  const std::string_view view = text;
  int errors = 0;
  for (size_t cut = 0; cut < text.size(); cut += text.size() / 97 + 1) {
    try {
      ParseBvh(view.substr(0, cut), files[0]);
    } catch (const IoError&) {
      ++errors;
    }
  }
  EXPECT_GT(errors, 90);  // every cut loses frames or hierarchy
}

}  // namespace
}  // namespace soma
