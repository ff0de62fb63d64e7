#include "framework/body/body_model.h"

#include "framework/core/error.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

namespace soma {
namespace {

// Tolerance on skinning-weight row sums (weights are stored in double but may
// come from float32 .npz files).
constexpr double kWeightSumTolerance = 1e-4;

/// Rodrigues' formula for an axis-angle vector (radians), stable near 0.
Eigen::Matrix3d AxisAngleToMatrix(const Eigen::Vector3d& axis_angle) {
  const double angle = axis_angle.norm();
  if (angle < 1e-12) {
    // First-order expansion: I + [w]_x.
    Eigen::Matrix3d r = Eigen::Matrix3d::Identity();
    r(0, 1) = -axis_angle.z();
    r(0, 2) = axis_angle.y();
    r(1, 0) = axis_angle.z();
    r(1, 2) = -axis_angle.x();
    r(2, 0) = -axis_angle.y();
    r(2, 1) = axis_angle.x();
    return r;
  }
  return Eigen::AngleAxisd(angle, axis_angle / angle).toRotationMatrix();
}

}  // namespace

const std::vector<std::string>& CoreJointNames() {
  static const std::vector<std::string>* const kNames =
      new std::vector<std::string>{
          "pelvis",        "left_hip",       "right_hip",    "spine1",
          "left_knee",     "right_knee",     "spine2",       "left_ankle",
          "right_ankle",   "spine3",         "left_foot",    "right_foot",
          "neck",          "left_collar",    "right_collar", "head",
          "left_shoulder", "right_shoulder", "left_elbow",   "right_elbow",
          "left_wrist",    "right_wrist",    "left_hand",    "right_hand"};
  return *kNames;
}

BodyPose BodyPose::Rest(int num_joints) {
  SOMA_CHECK_GE(num_joints, 0);
  BodyPose pose;
  pose.rotations = Eigen::Matrix3Xd::Zero(3, num_joints);
  return pose;
}

int BodyModel::FindJoint(const std::string& joint_name) const {
  for (size_t j = 0; j < joint_names.size(); ++j) {
    if (joint_names[j] == joint_name) return static_cast<int>(j);
  }
  return -1;
}

void BodyModel::Validate() const {
  const std::string who = fmt::format("BodyModel '{}'", name);
  const int v = num_vertices();
  const int j = num_joints();
  if (template_vertices.rows() != 3 || v == 0) {
    throw ShapeError(fmt::format(
        "{}: template_vertices must be 3 x V with V > 0, got {} x {}",
        who,
        template_vertices.rows(),
        template_vertices.cols()));
  }
  if (!template_vertices.allFinite()) {
    throw IoError(fmt::format("{}: template_vertices contain NaN or Inf", who));
  }
  if (faces.rows() != 3 || faces.cols() == 0) {
    throw ShapeError(
        fmt::format("{}: faces must be 3 x F with F > 0, got {} x {}",
                    who,
                    faces.rows(),
                    faces.cols()));
  }
  if (faces.minCoeff() < 0 || faces.maxCoeff() >= v) {
    throw IoError(fmt::format(
        "{}: face indices must lie in [0, {}), found range [{}, {}]",
        who,
        v,
        faces.minCoeff(),
        faces.maxCoeff()));
  }
  if (shape_dirs.cols() > 0 &&
      shape_dirs.rows() != 3 * static_cast<Eigen::Index>(v)) {
    throw ShapeError(
        fmt::format("{}: shape_dirs must be (3V = {}) x B, got {} x {}",
                    who,
                    3 * v,
                    shape_dirs.rows(),
                    shape_dirs.cols()));
  }
  if (beta_stddev.size() != 0 && beta_stddev.size() != shape_dirs.cols()) {
    throw ShapeError(
        fmt::format("{}: beta_stddev has {} entries for {} shape directions",
                    who,
                    beta_stddev.size(),
                    shape_dirs.cols()));
  }
  if (j < kNumCoreJoints) {
    throw ShapeError(
        fmt::format("{}: {} joints, a body needs at least the {} core joints",
                    who,
                    j,
                    static_cast<int>(kNumCoreJoints)));
  }
  if (static_cast<int>(joint_names.size()) != j) {
    throw ShapeError(fmt::format(
        "{}: {} joint names for {} joints", who, joint_names.size(), j));
  }
  if (parents[0] != -1) {
    throw IoError(fmt::format(
        "{}: parents[0] must be -1 (root), got {}", who, parents[0]));
  }
  for (int k = 1; k < j; ++k) {
    if (parents[k] < 0 || parents[k] >= k) {
      throw IoError(fmt::format(
          "{}: parents[{}] = {} must lie in [0, {})", who, k, parents[k], k));
    }
  }
  if (joint_regressor.rows() != j || joint_regressor.cols() != v) {
    throw ShapeError(
        fmt::format("{}: joint_regressor must be J x V = {} x {}, got {} x {}",
                    who,
                    j,
                    v,
                    joint_regressor.rows(),
                    joint_regressor.cols()));
  }
  if (skinning_weights.rows() != v || skinning_weights.cols() != j) {
    throw ShapeError(
        fmt::format("{}: skinning_weights must be V x J = {} x {}, got {} x {}",
                    who,
                    v,
                    j,
                    skinning_weights.rows(),
                    skinning_weights.cols()));
  }
  for (int i = 0; i < v; ++i) {
    double sum = 0.0;
    for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator it(
             skinning_weights, i);
         it;
         ++it) {
      if (!(it.value() >= 0.0) || !std::isfinite(it.value())) {
        throw IoError(fmt::format(
            "{}: skinning weight ({}, {}) = {} must be finite and >= 0",
            who,
            i,
            it.col(),
            it.value()));
      }
      sum += it.value();
    }
    if (std::abs(sum - 1.0) > kWeightSumTolerance) {
      throw IoError(
          fmt::format("{}: skinning weights of vertex {} sum to {}, expected 1",
                      who,
                      i,
                      sum));
    }
  }
  const Eigen::Index pose_features = 9 * static_cast<Eigen::Index>(j - 1);
  if (pose_dirs.size() != 0 &&
      (pose_dirs.rows() != 3 * static_cast<Eigen::Index>(v) ||
       pose_dirs.cols() != pose_features)) {
    throw ShapeError(fmt::format(
        "{}: pose_dirs must be empty or (3V = {}) x (9(J-1) = {}), got "
        "{} x {}",
        who,
        3 * v,
        pose_features,
        pose_dirs.rows(),
        pose_dirs.cols()));
  }
}

Eigen::Matrix3Xd BodyModel::ShapedVertices(const Eigen::VectorXd& betas) const {
  if (betas.size() > num_betas()) {
    throw ShapeError(
        fmt::format("BodyModel '{}': {} betas given, the body has {}",
                    name,
                    betas.size(),
                    num_betas()));
  }
  Eigen::Matrix3Xd shaped = template_vertices;
  if (betas.size() > 0) {
    const Eigen::VectorXd offsets = shape_dirs.leftCols(betas.size()) * betas;
    shaped +=
        Eigen::Map<const Eigen::Matrix3Xd>(offsets.data(), 3, num_vertices());
  }
  return shaped;
}

Eigen::Matrix3Xd BodyModel::RestJoints(
    const Eigen::Matrix3Xd& shaped_vertices) const {
  if (shaped_vertices.cols() != num_vertices()) {
    throw ShapeError(
        fmt::format("BodyModel '{}': RestJoints got {} vertices, expected {}",
                    name,
                    shaped_vertices.cols(),
                    num_vertices()));
  }
  // (J x V) * (V x 3) -> J x 3.
  const Eigen::MatrixXd joints = joint_regressor * shaped_vertices.transpose();
  return joints.transpose();
}

PosedSkeleton PoseSkeleton(const BodyModel& body,
                           const Eigen::Matrix3Xd& rest_joints,
                           const BodyPose& pose) {
  const int num_joints = body.num_joints();
  if (rest_joints.cols() != num_joints) {
    throw ShapeError(
        fmt::format("PoseSkeleton: {} rest joints for a body with {} joints",
                    rest_joints.cols(),
                    num_joints));
  }
  if (pose.rotations.cols() != num_joints) {
    throw ShapeError(fmt::format(
        "PoseSkeleton: pose has {} joint rotations, the body has {}",
        pose.rotations.cols(),
        num_joints));
  }
  PosedSkeleton skeleton;
  skeleton.global.resize(num_joints);
  skeleton.skinning.resize(num_joints);
  for (int j = 0; j < num_joints; ++j) {
    Eigen::Isometry3d local = Eigen::Isometry3d::Identity();
    local.linear() = AxisAngleToMatrix(pose.rotations.col(j));
    const int parent = body.parents[j];
    if (parent < 0) {
      local.translation() = rest_joints.col(j) + pose.translation;
      skeleton.global[j] = local;
    } else {
      local.translation() = rest_joints.col(j) - rest_joints.col(parent);
      skeleton.global[j] = skeleton.global[parent] * local;
    }
    skeleton.skinning[j] =
        skeleton.global[j] * Eigen::Translation3d(-rest_joints.col(j));
  }
  return skeleton;
}

Eigen::Matrix3Xd PoseVertices(const BodyModel& body,
                              const Eigen::VectorXd& betas,
                              const BodyPose& pose) {
  Eigen::Matrix3Xd shaped = body.ShapedVertices(betas);
  const Eigen::Matrix3Xd joints = body.RestJoints(shaped);
  const PosedSkeleton skeleton = PoseSkeleton(body, joints, pose);
  const int num_joints = body.num_joints();
  if (body.pose_dirs.size() != 0) {
    // SMPL pose blend shapes: features (R_j - I), j >= 1, row-major flattened.
    Eigen::VectorXd features(9 * (num_joints - 1));
    for (int j = 1; j < num_joints; ++j) {
      const Eigen::Matrix3d r = AxisAngleToMatrix(pose.rotations.col(j));
      for (int a = 0; a < 3; ++a) {
        for (int b = 0; b < 3; ++b) {
          features(9 * (j - 1) + 3 * a + b) = r(a, b) - (a == b ? 1.0 : 0.0);
        }
      }
    }
    const Eigen::VectorXd offsets = body.pose_dirs * features;
    shaped += Eigen::Map<const Eigen::Matrix3Xd>(
        offsets.data(), 3, body.num_vertices());
  }
  Eigen::Matrix3Xd posed(3, body.num_vertices());
  for (int i = 0; i < body.num_vertices(); ++i) {
    Eigen::Matrix<double, 3, 4> blended = Eigen::Matrix<double, 3, 4>::Zero();
    for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator it(
             body.skinning_weights, i);
         it;
         ++it) {
      blended += it.value() * skeleton.skinning[it.col()].matrix().topRows<3>();
    }
    posed.col(i) = blended.leftCols<3>() * shaped.col(i) + blended.col(3);
  }
  return posed;
}

Eigen::Matrix3Xd VertexNormals(const Eigen::Matrix3Xd& vertices,
                               const Eigen::Matrix3Xi& faces) {
  Eigen::Matrix3Xd normals = Eigen::Matrix3Xd::Zero(3, vertices.cols());
  for (Eigen::Index f = 0; f < faces.cols(); ++f) {
    const int a = faces(0, f);
    const int b = faces(1, f);
    const int c = faces(2, f);
    if (a < 0 || b < 0 || c < 0 || a >= vertices.cols() ||
        b >= vertices.cols() || c >= vertices.cols()) {
      throw ShapeError(fmt::format(
          "VertexNormals: face {} = ({}, {}, {}) out of range [0, {})",
          f,
          a,
          b,
          c,
          vertices.cols()));
    }
    // |cross| = 2 * area: area weighting comes for free.
    const Eigen::Vector3d n = (vertices.col(b) - vertices.col(a))
                                  .cross(vertices.col(c) - vertices.col(a));
    normals.col(a) += n;
    normals.col(b) += n;
    normals.col(c) += n;
  }
  for (Eigen::Index i = 0; i < normals.cols(); ++i) {
    const double norm = normals.col(i).norm();
    if (norm > 0.0) normals.col(i) /= norm;
  }
  return normals;
}

std::vector<std::vector<int>> VertexNeighbours(int num_vertices,
                                               const Eigen::Matrix3Xi& faces) {
  std::vector<std::vector<int>> neighbours(num_vertices);
  for (Eigen::Index f = 0; f < faces.cols(); ++f) {
    for (int k = 0; k < 3; ++k) {
      const int a = faces(k, f);
      const int b = faces((k + 1) % 3, f);
      if (a < 0 || b < 0 || a >= num_vertices || b >= num_vertices) {
        throw ShapeError(fmt::format(
            "VertexNeighbours: face {} has a vertex outside [0, {})",
            f,
            num_vertices));
      }
      if (a == b) continue;
      neighbours[a].push_back(b);
      neighbours[b].push_back(a);
    }
  }
  for (auto& list : neighbours) {
    std::sort(list.begin(), list.end());
    list.erase(std::unique(list.begin(), list.end()), list.end());
  }
  return neighbours;
}

std::vector<int> NRing(const std::vector<std::vector<int>>& neighbours,
                       int vertex,
                       int n) {
  const int num_vertices = static_cast<int>(neighbours.size());
  if (vertex < 0 || vertex >= num_vertices) {
    throw ShapeError(
        fmt::format("NRing: vertex {} outside [0, {})", vertex, num_vertices));
  }
  std::vector<int> result;
  if (n <= 0) return result;
  std::vector<char> seen(num_vertices, 0);
  seen[vertex] = 1;
  std::vector<int> frontier = {vertex};
  for (int ring = 0; ring < n && !frontier.empty(); ++ring) {
    std::vector<int> next;
    for (const int v : frontier) {
      for (const int u : neighbours[v]) {
        if (!seen[u]) {
          seen[u] = 1;
          next.push_back(u);
          result.push_back(u);
        }
      }
    }
    frontier = std::move(next);
  }
  std::sort(result.begin(), result.end());
  return result;
}

}  // namespace soma
