#include "framework/body/procedural_body.h"

#include "framework/core/error.h"
#include "framework/core/random.h"

#include <gtest/gtest.h>

#include "tests/body/body_test_util.h"
#include <algorithm>
#include <cmath>
#include <functional>
#include <map>
#include <set>
#include <tuple>

namespace soma {
namespace {

using ::soma::testing::PointInsideMesh;
using ::soma::testing::ProceduralBody;

struct EdgeStats {
  int64_t edges = 0;
  int64_t bad_edges = 0;  // not exactly two faces with opposite orientation
  int components = 0;
};

EdgeStats AnalyseEdges(int num_vertices, const Eigen::Matrix3Xi& faces) {
  std::map<std::pair<int, int>, int> directed;
  for (Eigen::Index f = 0; f < faces.cols(); ++f) {
    for (int e = 0; e < 3; ++e)
      ++directed[{faces(e, f), faces((e + 1) % 3, f)}];
  }
  EdgeStats stats;
  std::set<std::pair<int, int>> undirected;
  for (const auto& [edge, count] : directed) {
    const auto reverse = directed.find({edge.second, edge.first});
    if (count != 1 || reverse == directed.end() || reverse->second != 1)
      ++stats.bad_edges;
    undirected.insert(
        {std::min(edge.first, edge.second), std::max(edge.first, edge.second)});
  }
  stats.edges = static_cast<int64_t>(undirected.size());
  // Connected components (union-find).
  std::vector<int> parent(num_vertices);
  for (int i = 0; i < num_vertices; ++i) parent[i] = i;
  std::function<int(int)> find = [&](int x) {
    return parent[x] == x ? x : parent[x] = find(parent[x]);
  };
  for (const auto& [a, b] : undirected) parent[find(a)] = find(b);
  for (int i = 0; i < num_vertices; ++i) stats.components += find(i) == i;
  return stats;
}

double SignedVolume(const Eigen::Matrix3Xd& v, const Eigen::Matrix3Xi& f) {
  double volume = 0.0;
  for (Eigen::Index i = 0; i < f.cols(); ++i) {
    volume += v.col(f(0, i)).dot(v.col(f(1, i)).cross(v.col(f(2, i)))) / 6.0;
  }
  return volume;
}

double Stature(const Eigen::Matrix3Xd& v) {
  return v.row(2).maxCoeff() - v.row(2).minCoeff();
}

int ArgMaxJoint(const BodyModel& body, int vertex) {
  int best = -1;
  double best_w = -1.0;
  for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator it(
           body.skinning_weights, vertex);
       it;
       ++it) {
    if (it.value() > best_w) {
      best_w = it.value();
      best = static_cast<int>(it.col());
    }
  }
  return best;
}

TEST(ProceduralBody, HasTheDocumentedStructure) {
  const BodyModel& body = ProceduralBody();
  EXPECT_EQ(body.name, "procedural");
  EXPECT_EQ(body.num_joints(), kNumCoreJoints);
  EXPECT_EQ(body.joint_names, CoreJointNames());
  EXPECT_EQ(body.num_betas(), kNumProceduralShapeComponents);
  EXPECT_GE(body.num_betas(), 10);
  EXPECT_EQ(body.beta_stddev, Eigen::VectorXd::Ones(body.num_betas()));
  EXPECT_EQ(body.pose_dirs.size(), 0);
  EXPECT_GE(body.num_vertices(), 3000);
  EXPECT_LE(body.num_vertices(), 10000);
  EXPECT_NO_THROW(body.Validate());
  EXPECT_EQ(ProceduralShapeComponents().size(),
            static_cast<size_t>(kNumProceduralShapeComponents));
}

TEST(ProceduralBody, MeshIsClosedManifoldGenusZeroAndConnected) {
  const BodyModel& body = ProceduralBody();
  const EdgeStats stats = AnalyseEdges(body.num_vertices(), body.faces);
  EXPECT_EQ(stats.bad_edges, 0);
  EXPECT_EQ(stats.components, 1);
  const int64_t euler = body.num_vertices() - stats.edges + body.num_faces();
  EXPECT_EQ(euler, 2);  // genus 0
  EXPECT_EQ(2 * stats.edges, 3 * static_cast<int64_t>(body.num_faces()));
}

TEST(ProceduralBody, NoDegenerateFacesOrDuplicateVertices) {
  const BodyModel& body = ProceduralBody();
  const auto& v = body.template_vertices;
  for (int f = 0; f < body.num_faces(); ++f) {
    const int a = body.faces(0, f), b = body.faces(1, f), c = body.faces(2, f);
    ASSERT_TRUE(a != b && b != c && a != c) << f;
    const double area =
        0.5 * (v.col(b) - v.col(a)).cross(v.col(c) - v.col(a)).norm();
    EXPECT_GT(area, 1e-7) << "face " << f;  // > 0.1 mm^2
  }
  std::set<std::tuple<int64_t, int64_t, int64_t>> seen;
  for (int i = 0; i < body.num_vertices(); ++i) {
    seen.insert({std::llround(v(0, i) * 1e6),
                 std::llround(v(1, i) * 1e6),
                 std::llround(v(2, i) * 1e6)});
  }
  EXPECT_EQ(seen.size(), static_cast<size_t>(body.num_vertices()));
}

TEST(ProceduralBody, NormalsAreUnitAndOutward) {
  const BodyModel& body = ProceduralBody();
  const Eigen::Matrix3Xd n = VertexNormals(body.template_vertices, body.faces);
  for (int i = 0; i < body.num_vertices(); ++i)
    ASSERT_NEAR(n.col(i).norm(), 1.0, 1e-9);
  // Outward relative to the centroid of the vertex's body part.
  std::vector<Eigen::Vector3d> centroid(kNumCoreJoints,
                                        Eigen::Vector3d::Zero());
  std::vector<int> count(kNumCoreJoints, 0);
  std::vector<int> part(body.num_vertices());
  for (int i = 0; i < body.num_vertices(); ++i) {
    part[i] = ArgMaxJoint(body, i);
    centroid[part[i]] += body.template_vertices.col(i);
    ++count[part[i]];
  }
  for (int j = 0; j < kNumCoreJoints; ++j) {
    if (count[j] > 0) centroid[j] /= count[j];
  }
  int outward = 0;
  for (int i = 0; i < body.num_vertices(); ++i) {
    outward +=
        n.col(i).dot(body.template_vertices.col(i) - centroid[part[i]]) > 0.0;
  }
  EXPECT_GT(outward, 0.9 * body.num_vertices());
  // Closed CCW mesh: positive volume, about that of a 70 kg adult (~0.07 m^3).
  const double volume = SignedVolume(body.template_vertices, body.faces);
  EXPECT_GT(volume, 0.045);
  EXPECT_LT(volume, 0.10);
}

TEST(ProceduralBody, IsMirrorSymmetric) {
  const BodyModel& body = ProceduralBody();
  std::set<std::tuple<int64_t, int64_t, int64_t>> points;
  const auto key = [](double x, double y, double z) {
    return std::make_tuple(
        std::llround(x * 1e7), std::llround(y * 1e7), std::llround(z * 1e7));
  };
  for (int i = 0; i < body.num_vertices(); ++i) {
    const auto& v = body.template_vertices.col(i);
    points.insert(key(v.x(), v.y(), v.z()));
  }
  int missing = 0;
  for (int i = 0; i < body.num_vertices(); ++i) {
    const auto& v = body.template_vertices.col(i);
    missing += points.count(key(-v.x(), v.y(), v.z())) == 0;
  }
  EXPECT_EQ(missing, 0);
}

TEST(ProceduralBody, AnatomyOfTheMeanShape) {
  const BodyModel& body = ProceduralBody();
  const auto& v = body.template_vertices;
  const double stature = Stature(v);
  EXPECT_GT(stature, 1.70);
  EXPECT_LT(stature, 1.75);
  EXPECT_NEAR(v.row(2).minCoeff(), 0.0, 1e-3);  // feet on the floor
  const double span = v.row(0).maxCoeff() - v.row(0).minCoeff();
  EXPECT_GT(span / stature, 0.98);  // arm span ~ stature
  EXPECT_LT(span / stature, 1.08);
  // Faces -Y: the toes are in front, the heels behind the ankles.
  const Eigen::Matrix3Xd joints = body.RestJoints(v);
  EXPECT_LT(joints(1, kLeftFoot), joints(1, kLeftAnkle) - 0.05);
  EXPECT_GT(joints(0, kLeftShoulder), 0.1);  // left at +X
  EXPECT_LT(joints(0, kRightShoulder), -0.1);
  EXPECT_GT(joints(2, kHead), joints(2, kNeck));
  for (int j = 1; j < kNumCoreJoints; ++j) {
    const double bone = (joints.col(j) - joints.col(body.parents[j])).norm();
    EXPECT_GT(bone, 0.02) << CoreJointNames()[j];
    EXPECT_LT(bone, 0.5) << CoreJointNames()[j];
  }
  // Thigh and shank lengths ~0.245 H (Winter).
  EXPECT_NEAR((joints.col(kLeftHip) - joints.col(kLeftKnee)).norm() / stature,
              0.245,
              0.02);
  EXPECT_NEAR((joints.col(kLeftKnee) - joints.col(kLeftAnkle)).norm() / stature,
              0.246,
              0.02);
}

TEST(ProceduralBody, RegressedJointsMatchTheSkeletonAtTheMean) {
  const BodyModel& body = ProceduralBody();
  const Eigen::Matrix3Xd regressed = body.RestJoints(body.template_vertices);
  const Eigen::Matrix3Xd skeleton =
      ProceduralSkeletonJoints(ProceduralAnthropometry{});
  EXPECT_LT((regressed - skeleton).cwiseAbs().maxCoeff(), 1e-6);
  // Regressor rows: non-negative and sum to 1 (translation equivariant).
  for (int j = 0; j < kNumCoreJoints; ++j) {
    double sum = 0.0;
    int nonzero = 0;
    for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator it(
             body.joint_regressor, j);
         it;
         ++it) {
      EXPECT_GE(it.value(), 0.0);
      sum += it.value();
      ++nonzero;
    }
    EXPECT_NEAR(sum, 1.0, 1e-9) << CoreJointNames()[j];
    EXPECT_GE(nonzero, 4) << CoreJointNames()[j];
  }
}

TEST(ProceduralBody, JointsFollowShapeAndStayInside) {
  const BodyModel& body = ProceduralBody();
  Rng rng(11);
  for (int sample = 0; sample < 12; ++sample) {
    Eigen::VectorXd betas(body.num_betas());
    for (int k = 0; k < betas.size(); ++k)
      betas(k) = (sample < 6 ? 1.0 : 2.0) * rng.Normal();
    const Eigen::Matrix3Xd shaped = body.ShapedVertices(betas);
    const Eigen::Matrix3Xd joints = body.RestJoints(shaped);
    for (int j = 0; j < kNumCoreJoints; ++j) {
      EXPECT_TRUE(PointInsideMesh(shaped, body.faces, joints.col(j)))
          << "joint " << CoreJointNames()[j] << " outside the body for sample "
          << sample;
    }
    if (sample < 6) {
      // Close to the skeleton the anthropometry would build directly.
      const Eigen::Matrix3Xd direct =
          ProceduralSkeletonJoints(ProceduralAnthropometryFromBetas(betas));
      for (int j = 0; j < kNumCoreJoints; ++j) {
        EXPECT_LT((joints.col(j) - direct.col(j)).norm(), 0.02)
            << CoreJointNames()[j];
      }
    }
  }
}

TEST(ProceduralBody, SkinningWeightsAreAPartitionOfUnityWithLocalSupport) {
  const BodyModel& body = ProceduralBody();
  const auto& w = body.skinning_weights;
  const auto is_right_arm = [](int j) {
    return j == kRightCollar || j == kRightShoulder || j == kRightElbow ||
           j == kRightWrist || j == kRightHand;
  };
  const auto is_left_arm = [](int j) {
    return j == kLeftCollar || j == kLeftShoulder || j == kLeftElbow ||
           j == kLeftWrist || j == kLeftHand;
  };
  const auto is_right_leg = [](int j) {
    return j == kRightHip || j == kRightKnee || j == kRightAnkle ||
           j == kRightFoot;
  };
  for (int i = 0; i < body.num_vertices(); ++i) {
    double sum = 0.0;
    int influences = 0;
    const Eigen::Vector3d p = body.template_vertices.col(i);
    for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator it(w, i);
         it;
         ++it) {
      ASSERT_GE(it.value(), 0.0);
      sum += it.value();
      ++influences;
      const int j = static_cast<int>(it.col());
      if (p.x() > 0.30) {  // left arm
        EXPECT_FALSE(is_right_arm(j) || is_right_leg(j))
            << "vertex " << i << " joint " << j;
        EXPECT_FALSE(j == kHead || j == kPelvis)
            << "vertex " << i << " joint " << j;
      }
      if (p.x() < -0.30) {
        EXPECT_FALSE(is_left_arm(j)) << "vertex " << i << " joint " << j;
      }
      if (p.x() > 0.02 && p.z() < 0.7) {
        EXPECT_FALSE(is_right_leg(j)) << "vertex " << i;
      }
      if (p.z() > 1.58) {
        EXPECT_TRUE(j == kHead || j == kNeck) << "vertex " << i << " " << j;
      }
    }
    ASSERT_NEAR(sum, 1.0, 1e-9);
    ASSERT_GE(influences, 1);
    ASSERT_LE(influences, 4);
  }
}

TEST(ProceduralBody, SkinningIsSmoothAcrossTheElbow) {
  // Bending the elbow 90 degrees: no vertex of the arm jumps relative to its
  // neighbours (a torn or spiky elbow shows up as long posed edges).
  const BodyModel& body = ProceduralBody();
  BodyPose pose = BodyPose::Rest(body.num_joints());
  pose.rotations.col(kLeftElbow) = Eigen::Vector3d(0.0, 0.0, M_PI / 2);
  pose.rotations.col(kLeftKnee) = Eigen::Vector3d(M_PI / 2, 0.0, 0.0);
  const Eigen::Matrix3Xd posed = PoseVertices(body, Eigen::VectorXd(), pose);
  const auto& v = body.template_vertices;
  double worst_ratio = 0.0;
  for (int f = 0; f < body.num_faces(); ++f) {
    for (int e = 0; e < 3; ++e) {
      const int a = body.faces(e, f);
      const int b = body.faces((e + 1) % 3, f);
      const double rest = (v.col(a) - v.col(b)).norm();
      const double now = (posed.col(a) - posed.col(b)).norm();
      worst_ratio = std::max(worst_ratio, now / rest);
    }
  }
  EXPECT_LT(worst_ratio, 3.0);
}

TEST(ProceduralBody, StatureDistributionCoversAdults) {
  const BodyModel& body = ProceduralBody();
  Rng rng(2024);
  std::vector<double> statures;
  const Eigen::MatrixXd z_dirs = [&] {
    Eigen::MatrixXd d(body.num_vertices(), body.num_betas());
    for (int i = 0; i < body.num_vertices(); ++i)
      d.row(i) = body.shape_dirs.row(3 * i + 2);
    return d;
  }();
  const Eigen::VectorXd z0 = body.template_vertices.row(2).transpose();
  for (int s = 0; s < 1000; ++s) {
    Eigen::VectorXd betas(body.num_betas());
    for (int k = 0; k < betas.size(); ++k) betas(k) = rng.Normal();
    const Eigen::VectorXd z = z0 + z_dirs * betas;
    statures.push_back(z.maxCoeff() - z.minCoeff());
  }
  std::sort(statures.begin(), statures.end());
  const double p025 = statures[25];
  const double p975 = statures[974];
  EXPECT_GT(p025, 1.50);
  EXPECT_LT(p025, 1.60);
  EXPECT_GT(p975, 1.83);
  EXPECT_LT(p975, 1.95);
}

TEST(ProceduralBody, ShapeComponentsHaveTheirMeaning) {
  const BodyModel& body = ProceduralBody();
  const auto shaped = [&](int k, double value) {
    Eigen::VectorXd betas = Eigen::VectorXd::Zero(body.num_betas());
    betas(k) = value;
    return body.ShapedVertices(betas);
  };
  const double mean_volume = SignedVolume(body.template_vertices, body.faces);
  // 0: stature +1 SD = +9 cm.
  EXPECT_NEAR(
      Stature(shaped(0, 1.0)) - Stature(body.template_vertices), 0.090, 0.004);
  // 1: girth increases volume, keeps stature.
  EXPECT_GT(SignedVolume(shaped(1, 1.0), body.faces), 1.1 * mean_volume);
  EXPECT_NEAR(Stature(shaped(1, 1.0)), Stature(body.template_vertices), 0.004);
  // 2: longer legs at constant stature raise the hips.
  const Eigen::Matrix3Xd legs = shaped(2, 2.0);
  EXPECT_NEAR(Stature(legs), Stature(body.template_vertices), 0.004);
  EXPECT_GT(body.RestJoints(legs)(2, kLeftHip),
            body.RestJoints(body.template_vertices)(2, kLeftHip) + 0.02);
  // 3: longer arms widen the span.
  const auto span = [](const Eigen::Matrix3Xd& v) {
    return v.row(0).maxCoeff() - v.row(0).minCoeff();
  };
  EXPECT_GT(span(shaped(3, 1.0)), span(body.template_vertices) + 0.01);
  // 4: shoulder width moves the shoulders apart.
  const auto shoulder_width = [&](const Eigen::Matrix3Xd& v) {
    const Eigen::Matrix3Xd j = body.RestJoints(v);
    return j(0, kLeftShoulder) - j(0, kRightShoulder);
  };
  EXPECT_GT(shoulder_width(shaped(4, 1.0)),
            shoulder_width(body.template_vertices) + 0.008);
}

TEST(ProceduralBody, IsDeterministic) {
  ProceduralBodyOptions options;
  options.target_vertices = 4000;
  options.num_betas = 10;
  const BodyModel a = MakeProceduralBody(options);
  const BodyModel b = MakeProceduralBody(options);
  EXPECT_EQ(a.num_betas(), 10);
  EXPECT_LE(std::abs(a.num_vertices() - 4000), 2);
  ASSERT_EQ(a.num_vertices(), b.num_vertices());
  EXPECT_TRUE(a.template_vertices == b.template_vertices);
  EXPECT_TRUE(a.faces == b.faces);
  EXPECT_TRUE(a.shape_dirs == b.shape_dirs);
  const EdgeStats stats = AnalyseEdges(a.num_vertices(), a.faces);
  EXPECT_EQ(stats.bad_edges, 0);
  EXPECT_EQ(a.num_vertices() - stats.edges + a.num_faces(), 2);
}

TEST(ProceduralBody, OptionsAreValidated) {
  ProceduralBodyOptions options;
  options.target_vertices = 20000;
  EXPECT_THROW(MakeProceduralBody(options), ConfigError);
  options = {};
  options.num_betas = 9;
  EXPECT_THROW(options.Validate(), ConfigError);
  options = {};
  options.grid_spacing = 0.05;
  try {
    options.Validate();
    FAIL() << "expected ConfigError";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("grid_spacing"), std::string::npos);
  }
}

}  // namespace
}  // namespace soma
