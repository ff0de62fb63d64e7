// Building blocks shared by the samplers that skin only a few vertices of a
// body (VirtualMarkerSampler, the synthesizer's PlacedMarkerSampler):
// joint shape directions, truncated skinning influences, the rings of
// marker vertices, and forward kinematics to per-joint 3x4 LBS transforms.
// Arithmetic is double up to the transforms, which are stored in float.
#pragma once

#include "framework/body/body_model.h"

#include <Eigen/Core>

#include <utility>
#include <vector>

namespace soma {

/// Most skinning influences kept per vertex.
inline constexpr int kMaxSkinningInfluences = 4;

/// Rotation matrix of an axis-angle vector (Rodrigues).
Eigen::Matrix3d AxisAngleRotation(double x, double y, double z);

/// 3J x B: column b is the joint-position change of beta_b
/// (regressor * shape direction b), so J(beta) = J(0) + dirs * beta.
Eigen::MatrixXd JointShapeDirections(const BodyModel& body);

/// Non-zero skinning influences (weight, joint) of vertex `vid`; more than
/// kMaxSkinningInfluences are cut to the strongest and renormalised (SMPL-X
/// has up to ~8 with tiny tails).
std::vector<std::pair<double, int>> SkinningInfluences(const BodyModel& body,
                                                       int vid);

/// The vertices a set of marker vertices needs to be posed with normals:
/// each marker vertex and its incident faces (in face order, as
/// VertexNormals sums them), numbered locally.
struct MarkerRings {
  std::vector<int> local_ids;     // body vertex id of each local vertex
  std::vector<int> marker_local;  // local index of each marker vertex
  std::vector<int> ring_offsets;  // per marker, into ring_pairs (pairs)
  std::vector<int> ring_pairs;    // local (b, c) with (marker, b, c) CCW
};
MarkerRings BuildMarkerRings(const BodyModel& body,
                             const std::vector<int>& vertex_ids);

/// Per-joint LBS transforms of one (betas, pose).
struct SkinningTransforms {
  Eigen::Matrix3Xd rest_joints;  // 3 x J, for the betas
  std::vector<Eigen::Matrix3d> global_rotation;
  std::vector<Eigen::Vector3d> global_translation;
  std::vector<Eigen::Vector4f> rows;  // 3 per joint: rows of the 3x4 transform
  Eigen::VectorXf pose_features;      // 9 (J - 1): R_j - I, if requested
};

/// Rest joints `joint_template + joint_shape_dirs * betas`, forward
/// kinematics of `joints` (ascending, every parent included; other joints'
/// rows are zero) and, with `pose_features`, the pose-corrective features
/// of all joints but the root.
void ComputeSkinningTransforms(const std::vector<int>& parents,
                               const Eigen::Matrix3Xd& joint_template,
                               const Eigen::MatrixXd& joint_shape_dirs,
                               const Eigen::VectorXd& betas,
                               const BodyPose& pose,
                               const std::vector<int>& joints,
                               bool pose_features,
                               SkinningTransforms* out);

}  // namespace soma
