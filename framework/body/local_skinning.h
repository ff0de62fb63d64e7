// Building blocks shared by the samplers that skin only a few vertices of a
// body (VirtualMarkerSampler, the synthesizer's PlacedMarkerSampler):
// joint shape directions, truncated skinning influences, the rings of
// marker vertices and their normals, the precomputed skinning model of the
// local vertices, and forward kinematics to per-joint 3x4 LBS transforms.
// Arithmetic is double up to the transforms, which are stored in float.
#pragma once

#include "framework/body/body_model.h"

#include <Eigen/Core>

#include <string_view>
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

/// Throws ShapeError("<who>: vertex id <id> outside [0, V) of '<body>'") for
/// the first of `vertex_ids` that is not a vertex of `body`.
void CheckVertexIds(const BodyModel& body,
                    const std::vector<int>& vertex_ids,
                    std::string_view who);

/// Unnormalised normal at marker `m` of `rings`: the sum of the cross
/// products of its incident faces, from the posed local vertices `posed`
/// (3 floats per local vertex). Normalised, it is VertexNormals at that
/// vertex.
inline Eigen::Vector3f RingNormal(const MarkerRings& rings,
                                  int m,
                                  const float* posed) {
  const int a = rings.marker_local[m];
  const Eigen::Vector3f pa(posed[3 * a], posed[3 * a + 1], posed[3 * a + 2]);
  Eigen::Vector3f n = Eigen::Vector3f::Zero();
  for (int f = rings.ring_offsets[m]; f < rings.ring_offsets[m + 1]; ++f) {
    const int b = rings.ring_pairs[2 * f];
    const int c = rings.ring_pairs[2 * f + 1];
    const Eigen::Vector3f pb(posed[3 * b], posed[3 * b + 1], posed[3 * b + 2]);
    const Eigen::Vector3f pc(posed[3 * c], posed[3 * c + 1], posed[3 * c + 2]);
    n += (pb - pa).cross(pc - pa);
  }
  return n;
}

/// Everything about a few ("local") vertices of a body that does not depend
/// on the sample, in float, each vertex stored homogeneous (x, y, z, 1) so
/// that skinning loads it as one aligned 4-vector, plus the joint model
/// (double) for forward kinematics.
struct LocalSkinningModel {
  int num_joints = 0;
  int num_betas = 0;
  std::vector<int> parents;             // J
  Eigen::VectorXf template_vertices;    // 4L: (x, y, z, 1) per local vertex
  Eigen::MatrixXf shape_dirs;           // 4L x B, rows 4l+3 zero
  Eigen::MatrixXf pose_dirs;            // 4L x 9(J-1), empty if none
  Eigen::Matrix3Xd joint_template;      // 3 x J rest joints at beta = 0
  Eigen::MatrixXd joint_shape_dirs;     // 3J x B (JointShapeDirections)
  std::vector<int> influence_joint;     // L x kMaxSkinningInfluences
  std::vector<float> influence_weight;  // L x kMaxSkinningInfluences, 0-padded
  std::vector<int> influence_count;     // L: non-zero influences

  int num_local() const { return static_cast<int>(influence_count.size()); }
};

/// The skinning model of the body vertices `local_ids` (local vertex l is
/// body vertex local_ids[l]); influences as SkinningInfluences.
LocalSkinningModel BuildLocalSkinningModel(const BodyModel& body,
                                           const std::vector<int>& local_ids);

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
