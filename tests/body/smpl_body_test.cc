#include "framework/body/smpl_body.h"

#include "framework/body/body_model.h"
#include "framework/core/error.h"
#include "framework/io/npz.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <random>
#include <string>
#include <vector>

namespace soma {
namespace {

constexpr double kTol = 1e-9;

// Standard kinematic trees in file order.
std::vector<int> FileParents(SmplFamily family) {
  std::vector<int> parents = {-1, 0, 0, 0, 1,  2,  3,  4,  5,  6,  7,
                              8,  9, 9, 9, 12, 13, 14, 16, 17, 18, 19};
  if (family == SmplFamily::kSmpl) {
    parents.insert(parents.end(), {20, 21});
    return parents;
  }
  if (family == SmplFamily::kSmplX)
    parents.insert(parents.end(), {15, 15, 15});  // jaw, eyes
  for (const int wrist : {20, 21}) {
    for (int finger = 0; finger < 5; ++finger) {
      const int base = static_cast<int>(parents.size());
      parents.push_back(wrist);
      parents.push_back(base);
      parents.push_back(base + 1);
    }
  }
  return parents;
}

// A tiny random model in the SMPL-family .npz layout, in SMPL's frame.
struct RawSmpl {
  SmplFamily family = SmplFamily::kSmpl;
  int num_vertices = 0;
  int num_joints = 0;
  int num_dirs = 0;
  std::vector<double> v_template;  // V x 3
  std::vector<double>
      shapedirs;  // V x 3 x B (values exactly representable in float)
  std::vector<double> posedirs;   // V x 3 x 9(J-1)
  std::vector<double> regressor;  // J x V
  std::vector<double> weights;    // V x J
  std::vector<int> parents;       // file order
  std::vector<uint32_t> faces;    // F x 3
};

RawSmpl MakeRawSmpl(SmplFamily family,
                    int num_vertices,
                    int num_dirs,
                    uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  std::uniform_real_distribution<double> positive(0.1, 1.0);
  RawSmpl raw;
  raw.family = family;
  raw.parents = FileParents(family);
  raw.num_joints = static_cast<int>(raw.parents.size());
  raw.num_vertices = num_vertices;
  raw.num_dirs = num_dirs;
  const int64_t v_count = num_vertices;
  const int64_t j_count = raw.num_joints;
  raw.v_template.resize(3 * v_count);
  for (int64_t v = 0; v < v_count; ++v) {
    raw.v_template[3 * v] = 0.4 * unit(rng);
    raw.v_template[3 * v + 1] =
        0.2 + 0.6 * unit(rng);  // SMPL up: y in [-0.4, 0.8]
    raw.v_template[3 * v + 2] = 0.15 * unit(rng);
  }
  // Vertex 0 straight up, vertex 1 in front (+Z in SMPL).
  raw.v_template[0] = 0.0;
  raw.v_template[1] = 1.0;
  raw.v_template[2] = 0.0;
  raw.v_template[3] = 0.0;
  raw.v_template[4] = 0.0;
  raw.v_template[5] = 1.0;
  raw.shapedirs.resize(3 * v_count * num_dirs);
  for (double& d : raw.shapedirs) d = static_cast<float>(0.02 * unit(rng));
  // Shape direction 0 of vertex 0 points up in SMPL.
  raw.shapedirs[0 * num_dirs + 0] = 0.0;
  raw.shapedirs[1 * num_dirs + 0] = 0.25;
  raw.shapedirs[2 * num_dirs + 0] = 0.0;
  const int64_t p_count = 9 * (j_count - 1);
  raw.posedirs.resize(3 * v_count * p_count);
  for (double& d : raw.posedirs) d = 0.05 * unit(rng);
  raw.regressor.assign(static_cast<size_t>(j_count) * v_count, 0.0);
  std::uniform_int_distribution<int> pick_vertex(0, v_count - 1);
  for (int j = 0; j < j_count; ++j) {
    double sum = 0.0;
    std::vector<std::pair<int, double>> entries;
    for (int k = 0; k < 5; ++k) {
      entries.emplace_back(pick_vertex(rng), positive(rng));
      sum += entries.back().second;
    }
    for (const auto& [v, w] : entries)
      raw.regressor[j * v_count + v] += w / sum;
  }
  raw.weights.assign(static_cast<size_t>(v_count) * j_count, 0.0);
  std::uniform_int_distribution<int> pick_joint(0, j_count - 1);
  for (int v = 0; v < v_count; ++v) {
    double sum = 0.0;
    std::vector<std::pair<int, double>> entries;
    for (int k = 0; k < 3; ++k) {
      entries.emplace_back(pick_joint(rng), positive(rng));
      sum += entries.back().second;
    }
    for (const auto& [j, w] : entries) raw.weights[v * j_count + j] += w / sum;
  }
  for (int f = 0; f < 2 * v_count; ++f) {
    const int a = pick_vertex(rng);
    raw.faces.push_back(a);
    raw.faces.push_back((a + 1) % v_count);
    raw.faces.push_back((a + 2) % v_count);
  }
  return raw;
}

std::map<std::string, NpyArray> ToNpz(const RawSmpl& raw) {
  const int64_t v = raw.num_vertices;
  const int64_t j = raw.num_joints;
  std::map<std::string, NpyArray> arrays;
  arrays["v_template"] = NpyArray::FromDoubles({v, 3}, raw.v_template);
  std::vector<float> shapedirs(raw.shapedirs.begin(), raw.shapedirs.end());
  arrays["shapedirs"] = NpyArray::FromFloats({v, 3, raw.num_dirs}, shapedirs);
  arrays["posedirs"] = NpyArray::FromDoubles({v, 3, 9 * (j - 1)}, raw.posedirs);
  arrays["J_regressor"] = NpyArray::FromDoubles({j, v}, raw.regressor);
  arrays["weights"] = NpyArray::FromDoubles({v, j}, raw.weights);
  std::vector<uint32_t> tree(2 * j);
  for (int64_t k = 0; k < j; ++k) {
    tree[k] = raw.parents[k] < 0 ? 4294967295u
                                 : static_cast<uint32_t>(raw.parents[k]);
    tree[j + k] = static_cast<uint32_t>(k);
  }
  arrays["kintree_table"] = NpyArray::FromUInt32({2, j}, tree);
  arrays["f"] = NpyArray::FromUInt32(
      {static_cast<int64_t>(raw.faces.size() / 3), 3}, raw.faces);
  // SMPL-X files carry extra members, some of them strings.
  arrays["gender"] = NpyArray::FromStrings({}, {"neutral"});
  return arrays;
}

std::filesystem::path WriteRaw(
    const RawSmpl& raw,
    const std::string& name,
    const std::function<void(std::map<std::string, NpyArray>&)>& edit =
        nullptr) {
  auto arrays = ToNpz(raw);
  if (edit) edit(arrays);
  std::filesystem::path path = testing::CreateTestDir() / name;
  WriteNpz(path, arrays, {.compress = true});
  return path;
}

Eigen::Matrix3d Rodrigues(const Eigen::Vector3d& w) {
  const double angle = w.norm();
  if (angle < 1e-15) return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(angle, w / angle).toRotationMatrix();
}

// SMPL's forward pass (smplx.lbs) written directly on the raw arrays, in
// SMPL's frame and joint order.
Eigen::Matrix3Xd ReferenceLbs(const RawSmpl& raw,
                              const Eigen::VectorXd& betas,
                              const Eigen::Matrix3Xd& pose,
                              const Eigen::Vector3d& transl) {
  const int v_count = raw.num_vertices;
  const int j_count = raw.num_joints;
  Eigen::Matrix3Xd shaped(3, v_count);
  for (int v = 0; v < v_count; ++v) {
    for (int a = 0; a < 3; ++a) {
      double x = raw.v_template[3 * v + a];
      for (int b = 0; b < betas.size(); ++b)
        x += raw.shapedirs[(3 * v + a) * raw.num_dirs + b] * betas(b);
      shaped(a, v) = x;
    }
  }
  Eigen::Matrix3Xd joints = Eigen::Matrix3Xd::Zero(3, j_count);
  for (int j = 0; j < j_count; ++j) {
    for (int v = 0; v < v_count; ++v)
      joints.col(j) += raw.regressor[j * v_count + v] * shaped.col(v);
  }
  std::vector<Eigen::Matrix3d> rotations(j_count);
  for (int j = 0; j < j_count; ++j) rotations[j] = Rodrigues(pose.col(j));
  const int p_count = 9 * (j_count - 1);
  Eigen::VectorXd features(p_count);
  for (int j = 1; j < j_count; ++j) {
    for (int a = 0; a < 3; ++a) {
      for (int b = 0; b < 3; ++b)
        features(9 * (j - 1) + 3 * a + b) = rotations[j](a, b) - (a == b);
    }
  }
  Eigen::Matrix3Xd posed_rest = shaped;
  for (int v = 0; v < v_count; ++v) {
    for (int a = 0; a < 3; ++a) {
      for (int p = 0; p < p_count; ++p)
        posed_rest(a, v) +=
            raw.posedirs[(3 * v + a) * p_count + p] * features(p);
    }
  }
  std::vector<Eigen::Matrix4d> global(j_count);
  for (int j = 0; j < j_count; ++j) {
    Eigen::Matrix4d local = Eigen::Matrix4d::Identity();
    local.topLeftCorner<3, 3>() = rotations[j];
    const int parent = raw.parents[j];
    local.topRightCorner<3, 1>() =
        parent < 0 ? Eigen::Vector3d(joints.col(j))
                   : Eigen::Vector3d(joints.col(j) - joints.col(parent));
    global[j] = parent < 0 ? local : Eigen::Matrix4d(global[parent] * local);
  }
  Eigen::Matrix3Xd out(3, v_count);
  for (int v = 0; v < v_count; ++v) {
    Eigen::Matrix4d blended = Eigen::Matrix4d::Zero();
    for (int j = 0; j < j_count; ++j) {
      Eigen::Matrix4d a = global[j];
      a.topRightCorner<3, 1>() -=
          global[j].topLeftCorner<3, 3>() * joints.col(j);
      blended += raw.weights[v * j_count + j] * a;
    }
    out.col(v) = blended.topLeftCorner<3, 3>() * posed_rest.col(v) +
                 blended.topRightCorner<3, 1>() + transl;
  }
  return out;
}

class SmplFamilyTest : public ::testing::TestWithParam<SmplFamily> {};

TEST_P(SmplFamilyTest, LbsMatchesDirectComputationOnRawArrays) {
  const SmplFamily family = GetParam();
  const int num_dirs = family == SmplFamily::kSmplX ? 20 : 12;
  const RawSmpl raw = MakeRawSmpl(family, 240, num_dirs, 7);
  const std::filesystem::path path = WriteRaw(raw, "model.npz");
  SmplLoadOptions options;
  options.num_betas = 10;
  const BodyModel body = LoadSmplNpz(path, options);
  EXPECT_NO_THROW(body.Validate());
  EXPECT_EQ(body.name, ToString(family));
  EXPECT_EQ(body.num_vertices(), 240);
  EXPECT_EQ(body.num_faces(), 480);
  EXPECT_EQ(body.num_joints(), raw.num_joints);
  EXPECT_EQ(body.num_betas(), 10);
  EXPECT_EQ(body.pose_dirs.rows(), 3 * 240);
  EXPECT_EQ(body.pose_dirs.cols(), 9 * (raw.num_joints - 1));
  for (int j = 0; j < kNumCoreJoints; ++j)
    EXPECT_EQ(body.joint_names[j], CoreJointNames()[j]);

  // A pose with sizeable rotations everywhere.
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  Eigen::Matrix3Xd pose(3, raw.num_joints);
  for (int j = 0; j < raw.num_joints; ++j)
    pose.col(j) = 0.6 * Eigen::Vector3d(unit(rng), unit(rng), unit(rng));
  Eigen::VectorXd betas(10);
  for (int b = 0; b < 10; ++b) betas(b) = 1.5 * unit(rng);
  const Eigen::Vector3d transl(0.3, -0.2, 1.1);
  const Eigen::Matrix3Xd reference_smpl =
      ReferenceLbs(raw, betas, pose, transl);

  // Convert the reference and the pose to our frame and joint order.
  const Eigen::Matrix3d c = SmplToBodyFrame();
  double min_up = 1e9;
  for (int v = 0; v < raw.num_vertices; ++v)
    min_up = std::min(min_up, raw.v_template[3 * v + 1]);
  const Eigen::Vector3d shift(0, 0, -min_up);
  const Eigen::Matrix3Xd reference = (c * reference_smpl).colwise() + shift;
  const std::vector<int> order = SmplJointOrder(family);
  BodyPose our_pose = BodyPose::Rest(raw.num_joints);
  for (int j = 0; j < raw.num_joints; ++j)
    our_pose.rotations.col(j) = c * pose.col(order[j]);
  our_pose.translation = c * transl;
  const Eigen::Matrix3Xd posed = PoseVertices(body, betas, our_pose);
  EXPECT_LT((posed - reference).cwiseAbs().maxCoeff(), kTol);

  // The correctives matter: without them the result is clearly different.
  SmplLoadOptions no_correctives = options;
  no_correctives.load_pose_correctives = false;
  const BodyModel plain = LoadSmplNpz(path, no_correctives);
  EXPECT_EQ(plain.pose_dirs.size(), 0);
  EXPECT_GT(
      (PoseVertices(plain, betas, our_pose) - reference).cwiseAbs().maxCoeff(),
      1e-3);

  // Rest joints are the file's regressed joints, reordered and converted.
  const Eigen::Matrix3Xd joints = body.RestJoints(body.template_vertices);
  for (int j = 0; j < raw.num_joints; ++j) {
    Eigen::Vector3d expected = Eigen::Vector3d::Zero();
    for (int64_t v = 0; v < raw.num_vertices; ++v) {
      expected +=
          raw.regressor[static_cast<int64_t>(order[j]) * raw.num_vertices + v] *
          Eigen::Vector3d(raw.v_template[3 * v],
                          raw.v_template[3 * v + 1],
                          raw.v_template[3 * v + 2]);
    }
    EXPECT_LT((joints.col(j) - (c * expected + shift)).norm(), kTol) << j;
  }
}

INSTANTIATE_TEST_SUITE_P(AllFamilies,
                         SmplFamilyTest,
                         ::testing::Values(SmplFamily::kSmpl,
                                           SmplFamily::kSmplH,
                                           SmplFamily::kSmplX),
                         [](const auto& info) {
                           return std::string(ToString(info.param));
                         });

TEST(SmplBody, FrameConversionUpAndFront) {
  const RawSmpl raw = MakeRawSmpl(SmplFamily::kSmpl, 100, 10, 3);
  const BodyModel body = LoadSmplNpz(WriteRaw(raw, "smpl.npz"));
  double min_up = 1e9;
  for (int v = 0; v < raw.num_vertices; ++v)
    min_up = std::min(min_up, raw.v_template[3 * v + 1]);
  // Lowest vertex on the floor.
  EXPECT_NEAR(body.template_vertices.row(2).minCoeff(), 0.0, kTol);
  // SMPL (0, 1, 0) (up) -> our +Z.
  EXPECT_LT(
      (body.template_vertices.col(0) - Eigen::Vector3d(0, 0, 1.0 - min_up))
          .norm(),
      kTol);
  // SMPL (0, 0, 1) (front) -> our -Y.
  EXPECT_LT((body.template_vertices.col(1) - Eigen::Vector3d(0, -1.0, -min_up))
                .norm(),
            kTol);
  // Shape direction: SMPL up -> our +Z, no floor shift on displacements.
  EXPECT_LT(
      (body.shape_dirs.block<3, 1>(0, 0) - Eigen::Vector3d(0, 0, 0.25)).norm(),
      1e-7);
  EXPECT_EQ(SmplToBodyFrame().determinant(), 1.0);
}

TEST(SmplBody, SmplXJointsAreReorderedWithHandRootsAsCoreHands) {
  const RawSmpl raw = MakeRawSmpl(SmplFamily::kSmplX, 150, 400, 5);
  SmplLoadOptions options;
  options.num_betas = 300;
  const BodyModel body = LoadSmplNpz(WriteRaw(raw, "smplx.npz"), options);
  ASSERT_EQ(body.num_joints(), 55);
  EXPECT_EQ(body.num_betas(), 300);
  const std::vector<int> order = SmplJointOrder(SmplFamily::kSmplX);
  EXPECT_EQ(order[22], 28);  // left_middle1
  EXPECT_EQ(order[23], 43);  // right_middle1
  EXPECT_EQ(body.joint_names[22], "left_hand");
  EXPECT_EQ(body.joint_names[23], "right_hand");
  EXPECT_EQ(body.joint_names[24], "jaw");
  EXPECT_EQ(body.joint_names[25], "left_eye_smplhf");
  EXPECT_EQ(body.joint_names[27], "left_index1");
  EXPECT_EQ(body.parents[22], kLeftWrist);
  EXPECT_EQ(body.parents[23], kRightWrist);
  EXPECT_EQ(body.parents[24], kHead);
  const int left_middle2 = body.FindJoint("left_middle2");
  const int right_middle2 = body.FindJoint("right_middle2");
  ASSERT_GT(left_middle2, 23);
  EXPECT_EQ(body.parents[left_middle2], kLeftHand);
  EXPECT_EQ(body.parents[right_middle2], kRightHand);
  EXPECT_EQ(body.FindJoint("left_middle1"), -1);
  std::vector<std::string> sorted = body.joint_names;
  std::sort(sorted.begin(), sorted.end());
  EXPECT_EQ(std::unique(sorted.begin(), sorted.end()), sorted.end());
  for (int j = 1; j < body.num_joints(); ++j) EXPECT_LT(body.parents[j], j);
  // Weights columns follow the joints: our column 22 is the file's column 28.
  for (int v = 0; v < raw.num_vertices; ++v) {
    EXPECT_NEAR(
        body.skinning_weights.coeff(v, 22), raw.weights[v * 55 + 28], 1e-12);
  }
  // Too many betas: SMPL-X's columns beyond 300 are expressions.
  options.num_betas = 301;
  EXPECT_THROW(LoadSmplNpz(WriteRaw(raw, "smplx.npz"), options), IoError);
}

TEST(SmplBody, SmplHHandRoots) {
  const std::vector<int> order = SmplJointOrder(SmplFamily::kSmplH);
  ASSERT_EQ(order.size(), 52u);
  EXPECT_EQ(SmplFileJointNames(SmplFamily::kSmplH)[order[22]], "left_middle1");
  EXPECT_EQ(SmplFileJointNames(SmplFamily::kSmplH)[order[23]], "right_middle1");
  EXPECT_EQ(SmplBodyJointNames(SmplFamily::kSmplH)[24], "left_index1");
}

std::string IoErrorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const IoError& e) {
    return e.what();
  }
  return "<no IoError>";
}

TEST(SmplBodyErrors, MissingKeyIsNamed) {
  const RawSmpl raw = MakeRawSmpl(SmplFamily::kSmpl, 60, 10, 1);
  const auto path =
      WriteRaw(raw, "no_posedirs.npz", [](auto& a) { a.erase("posedirs"); });
  const std::string message = IoErrorOf([&] { LoadSmplNpz(path); });
  EXPECT_NE(message.find("no_posedirs.npz"), std::string::npos) << message;
  EXPECT_NE(message.find("missing key 'posedirs'"), std::string::npos)
      << message;
  // Without pose correctives the key is not needed.
  SmplLoadOptions options;
  options.load_pose_correctives = false;
  EXPECT_NO_THROW(LoadSmplNpz(path, options));
}

TEST(SmplBodyErrors, WrongShapesNameKeyAndExpectedShape) {
  const RawSmpl raw = MakeRawSmpl(SmplFamily::kSmpl, 60, 10, 2);
  const auto path = WriteRaw(raw, "bad_shapedirs.npz", [](auto& a) {
    std::vector<double> values(size_t{59} * 3 * 10, 0.0);
    a["shapedirs"] = NpyArray::FromDoubles({59, 3, 10}, values);
  });
  std::string message = IoErrorOf([&] { LoadSmplNpz(path); });
  EXPECT_NE(
      message.find("'shapedirs' has shape (59, 3, 10), expected (60, 3, B)"),
      std::string::npos)
      << message;

  const auto path2 = WriteRaw(raw, "bad_weights.npz", [](auto& a) {
    a["weights"] = NpyArray::FromDoubles(
        {60, 23}, std::vector<double>(size_t{60} * 23, 1.0 / 23));
  });
  message = IoErrorOf([&] { LoadSmplNpz(path2); });
  EXPECT_NE(message.find("'weights' has shape (60, 23), expected (60, 24)"),
            std::string::npos)
      << message;

  const auto path3 = WriteRaw(raw, "bad_joints.npz", [](auto& a) {
    a["kintree_table"] = NpyArray::FromInt64({2, 3}, {-1, 0, 1, 0, 1, 2});
  });
  message = IoErrorOf([&] { LoadSmplNpz(path3); });
  EXPECT_NE(message.find("expected 24 (SMPL), 52 (SMPL+H) or 55 (SMPL-X)"),
            std::string::npos)
      << message;

  SmplLoadOptions options;
  options.num_betas = 11;
  message = IoErrorOf([&] { LoadSmplNpz(WriteRaw(raw, "ten.npz"), options); });
  EXPECT_NE(message.find("11 betas requested"), std::string::npos) << message;
}

TEST(SmplBodyErrors, BadTreeAndValues) {
  const RawSmpl raw = MakeRawSmpl(SmplFamily::kSmpl, 60, 10, 4);
  const auto two_roots = WriteRaw(raw, "two_roots.npz", [](auto& a) {
    std::vector<int64_t> tree = a["kintree_table"].AsInt64();
    tree[5] = 4294967295LL;
    a["kintree_table"] = NpyArray::FromInt64({2, 24}, tree);
  });
  EXPECT_NE(IoErrorOf([&] {
              LoadSmplNpz(two_roots);
            }).find("only joint 0 may be the root"),
            std::string::npos);
  const auto nan = WriteRaw(raw, "nan.npz", [](auto& a) {
    std::vector<double> v = a["v_template"].AsDoubles();
    v[7] = std::nan("");
    a["v_template"] = NpyArray::FromDoubles({60, 3}, v);
  });
  EXPECT_NE(
      IoErrorOf([&] { LoadSmplNpz(nan); }).find("'v_template' contains NaN"),
      std::string::npos);
  EXPECT_NE(IoErrorOf([&] {
              LoadSmplNpz(testing::CreateTestDir() / "absent.npz");
            }).find("absent.npz"),
            std::string::npos);
}

}  // namespace
}  // namespace soma
