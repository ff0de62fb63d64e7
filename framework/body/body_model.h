// BodyModel: a parametric human body in the SMPL family's form (template
// mesh, linear shape space, joint regressor, skinning weights, optional pose
// correctives) posed by linear blend skinning. Every body source — the
// procedural default, MakeHuman/MPFB2, SMPL/SMPL-X .npz — produces one of
// these, so synthesis, solving and evaluation never care where a body came
// from.
//
// Conventions: metres, right-handed, Z up. At rest the body stands in a
// T-pose with its feet on z = 0, faces -Y and has its left side at +X (SMPL's
// Y-up frame rotated to Z-up by (x, y, z) -> (x, -z, y)). Joint 0 is the root
// (pelvis); parents[j] < j. A pose is one local rotation per joint
// (axis-angle, relative to the rest pose, expressed in the world-aligned rest
// frame of the joint as in SMPL) plus a root translation added to the root
// joint's rest position.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <Eigen/SparseCore>

#include <cstdint>
#include <string>
#include <vector>

namespace soma {

/// Standard joint names of the body skeleton (SMPL body joint order). Bodies
/// may have more joints after these (fingers), never fewer than kNumCoreJoints.
enum CoreJoint : int {
  kPelvis = 0,
  kLeftHip = 1,
  kRightHip = 2,
  kSpine1 = 3,
  kLeftKnee = 4,
  kRightKnee = 5,
  kSpine2 = 6,
  kLeftAnkle = 7,
  kRightAnkle = 8,
  kSpine3 = 9,
  kLeftFoot = 10,
  kRightFoot = 11,
  kNeck = 12,
  kLeftCollar = 13,
  kRightCollar = 14,
  kHead = 15,
  kLeftShoulder = 16,
  kRightShoulder = 17,
  kLeftElbow = 18,
  kRightElbow = 19,
  kLeftWrist = 20,
  kRightWrist = 21,
  kLeftHand = 22,
  kRightHand = 23,
  kNumCoreJoints = 24,
};

/// Names of the core joints in CoreJoint order ("pelvis", "left_hip", ...).
const std::vector<std::string>& CoreJointNames();

/// A pose: root translation (metres, world) and one axis-angle rotation per
/// joint (radians, local to the parent, relative to the rest pose).
struct BodyPose {
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
  Eigen::Matrix3Xd rotations;  // 3 x num_joints, axis-angle

  static BodyPose Rest(int num_joints);
};

/// The parametric body. A plain value type; build one with a body source
/// (see body_source.h) or fill the fields and call Validate().
class BodyModel {
 public:
  std::string name;  // "procedural", "makehuman", "smplx", ...

  // ---- Mesh.
  Eigen::Matrix3Xd template_vertices;  // 3 x V, rest pose, mean shape
  Eigen::Matrix3Xi faces;              // 3 x F, counter-clockwise = outward

  // ---- Shape space: v(beta) = template + sum_k beta_k * shape_dirs[k].
  /// (3V) x B, column k = displacement field of beta_k (vertex-major xyz).
  Eigen::MatrixXd shape_dirs;
  /// Prior std of each beta (betas are drawn as N(0, 1) and scaled by the
  /// directions; kept for documentation and samplers).
  Eigen::VectorXd beta_stddev;

  // ---- Skeleton.
  std::vector<std::string> joint_names;
  std::vector<int> parents;  // parents[0] = -1
  /// J x V sparse regressor: rest joint positions = regressor * vertices^T.
  Eigen::SparseMatrix<double, Eigen::RowMajor> joint_regressor;
  /// V x J sparse skinning weights, rows sum to 1.
  Eigen::SparseMatrix<double, Eigen::RowMajor> skinning_weights;

  // ---- Optional pose correctives (SMPL posedirs): (3V) x (9 (J-1)), driven
  // by the flattened (R_j - I) of the non-root joints. Empty if none.
  Eigen::MatrixXd pose_dirs;

  int num_vertices() const {
    return static_cast<int>(template_vertices.cols());
  }
  int num_faces() const { return static_cast<int>(faces.cols()); }
  int num_joints() const { return static_cast<int>(parents.size()); }
  int num_betas() const { return static_cast<int>(shape_dirs.cols()); }
  int FindJoint(const std::string& joint_name) const;  // -1 if absent

  /// Throws ShapeError/IoError on inconsistent sizes, parents[j] >= j, face
  /// indices out of range, weights that do not sum to 1.
  void Validate() const;

  /// Rest-pose vertices for `betas` (size <= num_betas; missing = 0).
  Eigen::Matrix3Xd ShapedVertices(const Eigen::VectorXd& betas) const;
  /// Rest joint positions for the shaped vertices.
  Eigen::Matrix3Xd RestJoints(const Eigen::Matrix3Xd& shaped_vertices) const;
};

/// Forward kinematics of a pose.
struct PosedSkeleton {
  /// G[j]: world frame of joint j (translation = joint position in the world).
  std::vector<Eigen::Isometry3d> global;
  /// A[j] = G[j] * Translation(-rest_joint[j]): maps a rest-pose point
  /// rigidly attached to joint j to the world; skinning is sum_j w_j A[j] x.
  std::vector<Eigen::Isometry3d> skinning;
};

/// `rest_joints` from BodyModel::RestJoints (3 x J).
PosedSkeleton PoseSkeleton(const BodyModel& body,
                           const Eigen::Matrix3Xd& rest_joints,
                           const BodyPose& pose);

/// Poses every vertex by linear blend skinning (with pose correctives when
/// the body has them).
Eigen::Matrix3Xd PoseVertices(const BodyModel& body,
                              const Eigen::VectorXd& betas,
                              const BodyPose& pose);

/// Area-weighted vertex normals (normalised sum of unnormalised face normals
/// of incident faces), unit length, outward for a closed CCW mesh.
Eigen::Matrix3Xd VertexNormals(const Eigen::Matrix3Xd& vertices,
                               const Eigen::Matrix3Xi& faces);

/// Vertex adjacency from the mesh edges; neighbours sorted.
std::vector<std::vector<int>> VertexNeighbours(int num_vertices,
                                               const Eigen::Matrix3Xi& faces);

/// The n-ring of `vertex`: vertices at edge distance 1..n (not the vertex
/// itself), sorted.
std::vector<int> NRing(const std::vector<std::vector<int>>& neighbours,
                       int vertex,
                       int n);

}  // namespace soma
