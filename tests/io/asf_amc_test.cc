#include "framework/io/asf_amc.h"

#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/testing/rotations.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <functional>
#include <map>
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

// Line numbers matter for the error tests (see the comments there).
constexpr char kTinyAsf[] = R"(:version 1.10
:name tiny
:units
  mass 1.0
  length 0.5
  angle deg
:documentation
  a tiny test skeleton, with (parentheses)
:root
  order TX TY TZ RX RY RZ
  axis XYZ
  position 0 0 0
  orientation 0 0 0
:bonedata
  begin
    id 1
    name upper
    direction 0 -1 0
    length 4
    axis 0 0 30 XYZ
    dof rx ry rz
    limits (-90.0 90.0)
           (-45 45)
           (-180 180)
  end
  begin
    id 2
    name lower
    direction 0.6 -0.8 0
    length 5
    axis 10 20 -30 XYZ
    dof rx rz
    limits (-10.0 170.0)
           (-20 20)
  end
  begin
    id 3
    name side
    direction 1 0 0
    length 2
    axis 0 0 90 XYZ
    dof rx
  end
:hierarchy
  begin
    root upper side
    upper lower
  end
)";

constexpr char kTinyAmc[] = R"(#!OML:ASF tiny.asf
:FULLY-SPECIFIED
:DEGREES
1
root 1 2 3 10 20 30
upper 15 -25 35
lower 40 -10
side 90
2
root 0 0 0 0 0 0
upper 0 0 0
lower 0 0
side 90
3
root 0 0 0 0 0 0
upper 0 0 0
lower 0 0
side 0
)";

// Metres per unit for `length 0.5`: a value / 0.5 is in inches.
constexpr double kTinyScale = 0.0254 / 0.5;

std::string Replace(std::string text,
                    const std::string& from,
                    const std::string& to) {
  const size_t at = text.find(from);
  EXPECT_NE(at, std::string::npos) << from;
  if (at != std::string::npos) text.replace(at, from.size(), to);
  return text;
}

TEST(ReadAsfAmc, TinyFilesMatchExplicitForwardKinematics) {
  const auto dir = testing::CreateTestDir();
  testing::WriteTextFile(dir, "tiny.asf", kTinyAsf);
  testing::WriteTextFile(dir, "tiny_7.amc", kTinyAmc);
  const AsfSkeleton asf = ReadAsf(dir / "tiny.asf");
  EXPECT_EQ(asf.name, "tiny");
  EXPECT_DOUBLE_EQ(asf.length_to_metres, kTinyScale);
  const Skeleton& s = asf.skeleton;
  EXPECT_EQ(s.names,
            (std::vector<std::string>{
                "root", "upper", "lower", "lower_end", "side", "side_end"}));
  EXPECT_EQ(s.parents, (std::vector<int>{-1, 0, 1, 2, 0, 4}));
  ASSERT_EQ(s.channels[2].size(), 2u);
  EXPECT_NEAR(s.channels[2][0].lower, -10 * kPi / 180, kTol);
  EXPECT_NEAR(s.channels[2][1].upper, 20 * kPi / 180, kTol);
  EXPECT_TRUE(std::isinf(s.channels[4][0].upper));

  const MotionClip clip = ReadAmc(dir / "tiny_7.amc", asf);
  ASSERT_EQ(clip.num_frames(), 3);
  EXPECT_DOUBLE_EQ(clip.frame_rate, 120.0);  // not an HDM05 name: default
  EXPECT_EQ(clip.name, "tiny_7");

  // The Acclaim recursion, written out: C = Rz(az) Ry(ay) Rx(ax) for "XYZ",
  // M_b = M_parent C_b R_b C_b^T, tip_b = start_b + M_b dir_b length_b.
  const double u = kTinyScale;
  const Eigen::Matrix3d m_root = Rz(30) * Ry(20) * Rx(10);
  const Eigen::Vector3d root = Eigen::Vector3d(1, 2, 3) * u;
  const Eigen::Matrix3d c_upper = Rz(30);
  const Eigen::Matrix3d m_upper =
      m_root * c_upper * (Rz(35) * Ry(-25) * Rx(15)) * c_upper.transpose();
  const Eigen::Vector3d upper_tip =
      root + m_upper * Eigen::Vector3d(0, -1, 0) * 4 * u;
  const Eigen::Matrix3d c_lower = Rz(-30) * Ry(20) * Rx(10);
  const Eigen::Matrix3d m_lower =
      m_upper * c_lower * (Rz(-10) * Rx(40)) * c_lower.transpose();
  const Eigen::Vector3d lower_tip =
      upper_tip + m_lower * Eigen::Vector3d(0.6, -0.8, 0) * 5 * u;
  const Eigen::Matrix3d c_side = Rz(90);
  const Eigen::Matrix3d m_side = m_root * c_side * Rx(90) * c_side.transpose();
  const Eigen::Vector3d side_tip =
      root + m_side * Eigen::Vector3d(1, 0, 0) * 2 * u;

  const std::vector<Eigen::Isometry3d> pose = clip.GlobalPose(0);
  EXPECT_TRUE(pose[0].translation().isApprox(root, kTol));
  EXPECT_TRUE(
      pose[1].translation().isApprox(root, kTol));  // upper starts at root
  EXPECT_TRUE(pose[2].translation().isApprox(upper_tip, kTol));
  EXPECT_TRUE(pose[3].translation().isApprox(lower_tip, kTol));
  EXPECT_TRUE(pose[4].translation().isApprox(root, kTol));
  EXPECT_TRUE(pose[5].translation().isApprox(side_tip, kTol));
  EXPECT_TRUE(pose[2].linear().isApprox(m_lower, kTol));
  EXPECT_TRUE(pose[4].linear().isApprox(m_side, kTol));

  // Frame 2 by hand: `side` has axis (0 0 90), so its local x is world +Y;
  // rx = 90 turns the bone (1, 0, 0) about +Y to (0, 0, -1).
  const auto p1 = clip.JointPositions(1);
  EXPECT_TRUE(p1[5].isApprox(Eigen::Vector3d(0, 0, -2 * u), kTol));
  // Frame 3 is the rest pose: (0,-4,0) + 5 (0.6,-0.8,0) = (3, -8, 0) units.
  const auto p2 = clip.JointPositions(2);
  EXPECT_TRUE(p2[3].isApprox(Eigen::Vector3d(3 * u, -8 * u, 0), kTol));
  EXPECT_TRUE(p2[5].isApprox(Eigen::Vector3d(2 * u, 0, 0), kTol));
}

TEST(ReadAsfAmc, OptionsOverrideUnitsAndRate) {
  AsfAmcReadOptions options;
  options.length_to_metres = 1.0;
  options.frame_rate = 60.0;
  const AsfSkeleton asf = ParseAsf(kTinyAsf, "tiny.asf", options);
  EXPECT_TRUE(
      asf.skeleton.offsets[2].isApprox(Eigen::Vector3d(0, -4, 0), kTol));
  const MotionClip clip =
      ParseAmc(kTinyAmc, "HDM_xx_test_120.amc", asf, options);
  EXPECT_DOUBLE_EQ(clip.frame_rate, 60.0);
  EXPECT_DOUBLE_EQ(ParseAmc(kTinyAmc, "HDM_xx_test_100.amc", asf).frame_rate,
                   100.0);
  options.frame_rate = -1.0;
  EXPECT_THROW(ParseAmc(kTinyAmc, "x.amc", asf, options), ConfigError);
}

void ExpectIoError(const std::function<void()>& parse,
                   const std::vector<std::string>& fragments) {
  try {
    parse();
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

void ExpectAsfError(const std::string& asf,
                    const std::vector<std::string>& fragments) {
  ExpectIoError([&] { ParseAsf(asf, "/d/tiny.asf"); }, fragments);
}

void ExpectAmcError(const std::string& amc,
                    const std::vector<std::string>& fragments) {
  const AsfSkeleton asf = ParseAsf(kTinyAsf, "/d/tiny.asf");
  ExpectIoError([&] { ParseAmc(amc, "/d/tiny.amc", asf); }, fragments);
}

TEST(ReadAsf, MalformedBoneDataNamesFileAndLine) {
  // Line 18: "direction 0 -1 0".
  ExpectAsfError(Replace(kTinyAsf, "direction 0 -1 0", "direction 0 -1"),
                 {"/d/tiny.asf:18:", "'direction' needs 3 numbers, got 2"});
  // Line 19: "length 4".
  ExpectAsfError(Replace(kTinyAsf, "length 4", "length four"),
                 {"/d/tiny.asf:19:", "not a number: 'four'"});
  // Line 20: the axis without its rotation order.
  ExpectAsfError(Replace(kTinyAsf, "axis 0 0 30 XYZ", "axis 0 0 30"),
                 {"/d/tiny.asf:20:", "axis"});
  // Lines 22-24: three dofs but two limit pairs (the next line is `end`).
  ExpectAsfError(Replace(kTinyAsf, "           (-180 180)\n", ""),
                 {"/d/tiny.asf:23:", "needs 3 limit pairs"});
  // Line 17: no name -> reported at the `begin` of the bone (line 15).
  ExpectAsfError(Replace(kTinyAsf, "    name upper\n", ""),
                 {"/d/tiny.asf:15:", "bone without a name"});
  // Line 42: translational dofs are not supported.
  ExpectAsfError(Replace(kTinyAsf, "dof rx\n", "dof tx\n"),
                 {"/d/tiny.asf:42:", "translational dof 'tx'"});
  ExpectAsfError(Replace(kTinyAsf, "    id 3\n", "    idd 3\n"),
                 {"/d/tiny.asf:37:", "unknown :bonedata keyword 'idd'"});
  // A missing `end`: the next `begin` (line 26) is not a bone keyword.
  ExpectAsfError(Replace(kTinyAsf,
                         "           (-180 180)\n  end\n",
                         "           (-180 180)\n"),
                 {"/d/tiny.asf:25:", "'begin'"});
}

TEST(ReadAsf, MalformedHierarchyAndSections) {
  ExpectAsfError(Replace(kTinyAsf, "upper lower\n", "upper lowr\n"),
                 {"/d/tiny.asf:47:", "unknown bone 'lowr'"});
  // `side` defined (line 36) but not connected.
  ExpectAsfError(Replace(kTinyAsf, "root upper side", "root upper"),
                 {"/d/tiny.asf:36:", "bone 'side' is not connected"});
  ExpectAsfError(
      Replace(kTinyAsf, "upper lower\n", "upper lower\n    side lower\n"),
      {"/d/tiny.asf:48:", "second parent"});
  ExpectAsfError(Replace(kTinyAsf, "angle deg", "angle grad"),
                 {"/d/tiny.asf:6:", "angle unit 'grad'"});
  ExpectAsfError(Replace(kTinyAsf, ":hierarchy", ":hierarchie"),
                 {"/d/tiny.asf:", "missing :hierarchy"});
  // A bone called like the generated tip joint of the leaf `lower`.
  ExpectAsfError(Replace(Replace(kTinyAsf, "name side", "name lower_end"),
                         "root upper side",
                         "root upper lower_end"),
                 {"/d/tiny.asf:36:", "clashes with the tip joint"});
  ExpectAsfError("", {"/d/tiny.asf:1:", "missing :bonedata"});
  ExpectAsfError("begin\n", {"/d/tiny.asf:1:", "':section'"});
  ExpectIoError([] { ReadAsf("/nonexistent/dir/x.asf"); },
                {"/nonexistent/dir/x.asf"});
}

TEST(ReadAmc, BadInputNamesFileAndLine) {
  // Line 8: "side 90" of frame 1.
  ExpectAmcError(Replace(kTinyAmc, "side 90\n2", "elbow 90\n2"),
                 {"/d/tiny.amc:8:", "unknown bone 'elbow'"});
  // Line 7: one value for two dofs.
  ExpectAmcError(Replace(kTinyAmc, "lower 40 -10", "lower 40"),
                 {"/d/tiny.amc:7:", "has 1 values, expected 2"});
  ExpectAmcError(Replace(kTinyAmc, "lower 40 -10", "lower 40 -1O"),
                 {"/d/tiny.amc:7:", "not a number: '-1O'"});
  // Line 9: frame 5 after frame 1.
  ExpectAmcError(Replace(kTinyAmc, "side 90\n2\n", "side 90\n5\n"),
                 {"/d/tiny.amc:9:", "frame number 5 follows 1"});
  // :FULLY-SPECIFIED, and frame 1 (line 4) lacks `side`.
  ExpectAmcError(Replace(kTinyAmc, "side 90\n2", "2"),
                 {"/d/tiny.amc:4:", "frame 1 lacks bone 'side'"});
  ExpectAmcError(Replace(kTinyAmc, "side 90\n2", "side 90\nside 90\n2"),
                 {"/d/tiny.amc:9:", "appears twice"});
  ExpectAmcError(Replace(kTinyAmc, "1\nroot", "root 0 0 0 0 0 0\n1\nroot"),
                 {"/d/tiny.amc:4:", "before the first frame number"});
  ExpectAmcError(Replace(kTinyAmc, ":DEGREES", ":DEGREEZ"),
                 {"/d/tiny.amc:3:", "unknown AMC header"});
  const AsfSkeleton asf = ParseAsf(kTinyAsf, "/d/tiny.asf");
  ExpectIoError([&] { ReadAmc("/nonexistent/x.amc", asf); },
                {"/nonexistent/x.amc"});
}

TEST(ReadAmc, NotFullySpecifiedDefaultsMissingBonesToRest) {
  const AsfSkeleton asf = ParseAsf(kTinyAsf, "tiny.asf");
  const std::string amc =
      Replace(Replace(kTinyAmc, ":FULLY-SPECIFIED\n", ""), "side 90\n2", "2");
  const MotionClip clip = ParseAmc(amc, "tiny.amc", asf);
  ASSERT_EQ(clip.num_frames(), 3);
  EXPECT_TRUE(clip.local_rotations[0][4].isApprox(
      Eigen::Quaterniond::Identity(), kTol));
}

// ---------------------------------------------------------------------------
// Real HDM05 files (actors bd, bk, dg, mm, tr; 120 Hz).

std::filesystem::path Hdm05Dir() {
  return testing::SharedDataDir() / "motion" / "hdm05_amc";
}

std::vector<std::filesystem::path> Hdm05Files(const std::string& extension) {
  std::vector<std::filesystem::path> files;
  if (!std::filesystem::exists(Hdm05Dir())) return files;
  for (const auto& entry : std::filesystem::directory_iterator(Hdm05Dir())) {
    if (entry.path().extension() == extension) files.push_back(entry.path());
  }
  std::sort(files.begin(), files.end());
  return files;
}

// "HDM_bd_squat1Reps_003_120.amc" -> "HDM_bd.asf".
std::filesystem::path AsfFor(const std::filesystem::path& amc) {
  return amc.parent_path() / (amc.stem().string().substr(0, 6) + ".asf");
}

// Frame count from the text, independent of the reader: lines that hold a
// single integer.
int CountFrameLines(const std::string& text) {
  std::istringstream in(text);
  std::string line;
  int count = 0;
  while (std::getline(in, line)) {
    while (!line.empty() &&
           std::isspace(static_cast<unsigned char>(line.back()))) {
      line.pop_back();
    }
    if (!line.empty() && std::all_of(line.begin(), line.end(), [](char c) {
          return std::isdigit(static_cast<unsigned char>(c));
        })) {
      ++count;
    }
  }
  return count;
}

double BoneLength(const Skeleton& s, const std::string& bone) {
  return s.offsets[s.Children(s.Find(bone))[0]].norm();
}

TEST(ReadAsf, RealHdm05SkeletonsArePlausible) {
  const auto files = Hdm05Files(".asf");
  if (files.empty()) GTEST_SKIP() << "no shared HDM05 data";
  ASSERT_EQ(files.size(), 5u);
  for (const auto& path : files) {
    SCOPED_TRACE(path.string());
    const AsfSkeleton asf = ReadAsf(path);
    const Skeleton& s = asf.skeleton;
    EXPECT_NEAR(asf.length_to_metres, 0.0254 / 0.45, 1e-12);
    EXPECT_EQ(s.num_joints(), 38);  // root + 30 bones + 7 bone tips
    const auto rest = s.RestPositions();
    double lo = 1e9, hi = -1e9;
    for (const auto& p : rest) {
      lo = std::min(lo, p.y());
      hi = std::max(hi, p.y());
    }
    EXPECT_GT(hi - lo, 1.4);
    EXPECT_LT(hi - lo, 2.1);
    // Head up, feet down, T-pose arms left (+X) and right (-X).
    EXPECT_GT(rest[s.Find("head_end")].y(), 0.5);
    EXPECT_LT(rest[s.Find("ltoes")].y(), -0.8);
    EXPECT_GT(rest[s.Find("lwrist")].x(), 0.5);
    EXPECT_LT(rest[s.Find("rwrist")].x(), -0.5);
    EXPECT_NEAR(rest[s.Find("lwrist")].y(), rest[s.Find("rwrist")].y(), 0.03);
    EXPECT_NEAR(
        rest[s.Find("lhumerus")].x(), -rest[s.Find("rhumerus")].x(), 0.03);
    const double thigh = BoneLength(s, "lfemur");
    EXPECT_GT(thigh, 0.3);
    EXPECT_LT(thigh, 0.6);
    // Long bones left vs right: the HDM05 calibrations differ by up to 4.8%
    // here (bd humerus); forearms, hands and clavicles by up to 15% (bk
    // radius 1.13, dg clavicle 1.15), which is not tested.
    for (const std::string bone : {"hipjoint", "femur", "tibia", "humerus"}) {
      EXPECT_NEAR(
          BoneLength(s, "l" + bone) / BoneLength(s, "r" + bone), 1.0, 0.06)
          << bone;
    }
  }
}

TEST(ReadAmc, RealHdm05TakesParseWithPlausibleMotion) {
  const auto files = Hdm05Files(".amc");
  if (files.empty()) GTEST_SKIP() << "no shared HDM05 data";
  ASSERT_EQ(files.size(), 22u);
  std::map<std::string, AsfSkeleton> skeletons;
  for (const auto& path : files) {
    SCOPED_TRACE(path.string());
    const std::string asf_path = AsfFor(path).string();
    if (!skeletons.count(asf_path))
      skeletons.emplace(asf_path, ReadAsf(asf_path));
    const MotionClip clip = ReadAmc(path, skeletons.at(asf_path));
    EXPECT_EQ(clip.num_frames(), CountFrameLines(ReadFile(path)));
    EXPECT_GT(clip.num_frames(), 50);
    EXPECT_DOUBLE_EQ(clip.frame_rate, 120.0);
    const Skeleton& s = clip.skeleton;
    const int head = s.Find("head");
    const std::vector<int> feet = {s.Find("lfoot"),
                                   s.Find("ltoes"),
                                   s.Find("ltoes_end"),
                                   s.Find("rfoot"),
                                   s.Find("rtoes"),
                                   s.Find("rtoes_end")};
    // Every take starts upright.
    const auto p0 = clip.JointPositions(0);
    EXPECT_GT(p0[head].y(), p0[0].y() + 0.3);
    for (int f : feet) EXPECT_LT(p0[f].y(), p0[0].y() - 0.6);

    const std::string name = clip.name;
    const bool on_floor = name.find("lieDown") != std::string::npos ||
                          name.find("depositFloor") != std::string::npos;
    if (on_floor) continue;
    // Upright takes: the lowest joint of every frame is a foot joint, and
    // (except for hops, mostly airborne) the feet are on the floor, y = 0,
    // most of the time.
    std::vector<double> lowest_feet;
    for (int t = 0; t < clip.num_frames(); ++t) {
      const auto p = clip.JointPositions(t);
      double lowest = 1e9, lowest_foot = 1e9;
      for (const auto& q : p) lowest = std::min(lowest, q.y());
      for (int f : feet) lowest_foot = std::min(lowest_foot, p[f].y());
      EXPECT_LT(lowest_foot, lowest + 0.03) << "frame " << t;
      lowest_feet.push_back(lowest_foot);
    }
    if (name.find("hop") != std::string::npos) continue;
    std::nth_element(lowest_feet.begin(),
                     lowest_feet.begin() + lowest_feet.size() / 2,
                     lowest_feet.end());
    EXPECT_NEAR(lowest_feet[lowest_feet.size() / 2], 0.0, 0.07);
  }
}

MotionClip ReadTake(const std::string& name) {
  const auto path = Hdm05Dir() / name;
  return ReadAsfAmc(AsfFor(path), path);
}

TEST(ReadAmc, RealHdm05PlantedFeetDoNotSlide) {
  if (!std::filesystem::exists(Hdm05Dir()))
    GTEST_SKIP() << "no shared HDM05 data";
  // Wrong rotation conventions swing the legs; planted ankles stay within
  // a few centimetres over the whole take.
  for (const char* name : {"HDM_mm_rotateArmsBothBackward1Reps_013_120.amc",
                           "HDM_dg_rotateArmsBothBackward1Reps_010_120.amc",
                           "HDM_dg_grabHighR_016_120.amc",
                           "HDM_tr_squat1Reps_044_120.amc"}) {
    SCOPED_TRACE(name);
    const MotionClip clip = ReadTake(name);
    const std::vector<int> ankles = {clip.skeleton.Find("lfoot"),
                                     clip.skeleton.Find("rfoot")};
    const auto p0 = clip.JointPositions(0);
    double slide = 0.0;
    for (int t = 0; t < clip.num_frames(); ++t) {
      const auto p = clip.JointPositions(t);
      for (int a : ankles) {
        Eigen::Vector3d moved = p[a] - p0[a];
        moved.y() = 0.0;  // horizontal: heels may lift a little
        slide = std::max(slide, moved.norm());
      }
    }
    EXPECT_LT(slide, 0.05);
  }
}

TEST(ReadAmc, RealHdm05SquatDipsAndLieDownReachesFloor) {
  if (!std::filesystem::exists(Hdm05Dir()))
    GTEST_SKIP() << "no shared HDM05 data";
  for (const char* name :
       {"HDM_bd_squat1Reps_003_120.amc", "HDM_tr_squat1Reps_044_120.amc"}) {
    SCOPED_TRACE(name);
    const MotionClip squat = ReadTake(name);
    const double start = squat.root_translation[0].y();
    int lowest = 0;
    for (int t = 0; t < squat.num_frames(); ++t) {
      if (squat.root_translation[t].y() < squat.root_translation[lowest].y())
        lowest = t;
    }
    EXPECT_LT(squat.root_translation[lowest].y(), 0.7 * start);
    EXPECT_GT(lowest, squat.num_frames() / 5);  // mid-clip
    EXPECT_LT(lowest, squat.num_frames() * 4 / 5);
  }
  for (const char* name :
       {"HDM_bk_lieDownFloor_008_120.amc", "HDM_dg_lieDownFloor_013_120.amc"}) {
    SCOPED_TRACE(name);
    const MotionClip lie = ReadTake(name);
    const int head = lie.skeleton.Find("head");
    double lowest_head = 1e9;
    for (int t = 0; t < lie.num_frames(); ++t) {
      lowest_head = std::min(lowest_head, lie.JointPositions(t)[head].y());
    }
    EXPECT_GT(lie.JointPositions(0)[head].y(), 1.3);
    EXPECT_LT(lowest_head, 0.6);
  }
}

TEST(ReadAmc, TruncatedRealFilesNeverCrash) {
  if (!std::filesystem::exists(Hdm05Dir()))
    GTEST_SKIP() << "no shared HDM05 data";
  const auto asf_path = Hdm05Dir() / "HDM_bd.asf";
  const std::string asf_text = ReadFile(asf_path);
  const std::string_view asf_view = asf_text;
  for (size_t cut = 0; cut < asf_text.size(); cut += 37) {
    try {
      ParseAsf(asf_view.substr(0, cut), asf_path);
    } catch (const IoError&) {
    }
  }
  const AsfSkeleton asf = ReadAsf(asf_path);
  const auto amc_path = Hdm05Dir() / "HDM_bd_squat1Reps_003_120.amc";
  const std::string amc_text = ReadFile(amc_path);
  const std::string_view amc_view = amc_text;
  int errors = 0, cuts = 0;
  for (size_t cut = 0; cut < amc_text.size(); cut += amc_text.size() / 61 + 1) {
    ++cuts;
    try {
      ParseAmc(amc_view.substr(0, cut), amc_path, asf);
    } catch (const IoError&) {
      ++errors;
    }
  }
  // A cut inside a frame drops values or whole bones of a :FULLY-SPECIFIED
  // frame (errors); only cuts in the header, between frames or inside the
  // last number of a frame parse.
  EXPECT_GT(errors, cuts * 3 / 4);
}

}  // namespace
}  // namespace soma
