// The marker model of the body solver (REFERENCE.md 7.2, simplified): every
// latent marker is a point of the canonical (rest-pose, shaped) body, the
// shaped vertex it belongs to plus a free offset in the rest frame,
//   x_m(beta, o_m) = v(beta)[vid_m] + o_m,
// and is posed by linear blend skinning with the (truncated, renormalised)
// skinning weights of that vertex,
//   p_m = sum_j w_mj (R_j (x_m - r_j(beta)) + c_j(beta, t, theta)),
// with R_j, c_j the world rotation and position of joint j from forward
// kinematics and r_j the rest joint. A marker offset along the rest normal
// (o_m = n_m d_m) reproduces MoSh++'s initial latent markers v + n d; the
// offset may slide along the surface in stage I. Pose correctives of the body
// (SMPL posedirs) are not applied to markers.
//
// Parameters are packed per frame as one vector (FrameParams):
//   [t (3), theta_0 (3, root axis-angle), theta_1 ... theta_{J-1}]
// and Evaluate() returns marker positions with analytic Jacobians with
// respect to the frame vector, the betas and the offsets (tested against
// finite differences in tests/solve/marker_model_test.cc). The Jacobian of a
// joint rotation uses the left Jacobian of SO(3): d/dtheta_k of a point q
// rigidly attached below joint k is -[q - c_k]_x R_parent(k) J_l(theta_k).
#pragma once

#include "framework/body/body_model.h"
#include "framework/body/marker_layout.h"

#include <Eigen/Core>

#include <vector>

namespace soma {

/// Size of the per-frame parameter vector of a body with `num_joints` joints.
inline int FrameParamSize(int num_joints) { return 3 + 3 * num_joints; }

/// A BodyPose packed as [t, theta_0, ..., theta_{J-1}].
Eigen::VectorXd PackFrameParams(const BodyPose& pose);
/// The inverse of PackFrameParams.
BodyPose UnpackFrameParams(const double* params, int num_joints);

/// Row-major dense Jacobian blocks as Ceres hands them out.
using RowMajorMatrix =
    Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

/// Left Jacobian of SO(3) at axis-angle `w`: exp(w + d) ~ exp(J_l(w) d) exp(w).
Eigen::Matrix3d LeftJacobianSO3(const Eigen::Vector3d& w);

/// What the marker model needs of a layout: each marker's vertex (its first
/// vertex id) and its distance from the skin, in layout order.
struct LayoutMarkerVertices {
  std::vector<int> vertex_ids;
  std::vector<double> distances;
};
LayoutMarkerVertices MarkerVertices(const MarkerLayout& layout);

/// Offsets n_m d_m along the rest normals of the shaped body (MoSh++'s
/// initial latent markers v + n d), 3 x M.
Eigen::Matrix3Xd NormalOffsets(const BodyModel& body,
                               const Eigen::VectorXd& betas,
                               const std::vector<int>& vertex_ids,
                               const std::vector<double>& distances);

class MarkerModel {
 public:
  /// One marker per entry of `vertex_ids` (each in [0, V)); throws ShapeError
  /// for an empty list or an id out of range, or a body without joints.
  MarkerModel(const BodyModel& body, const std::vector<int>& vertex_ids);

  int num_markers() const { return static_cast<int>(vertex_ids_.size()); }
  int num_joints() const { return static_cast<int>(parents_.size()); }
  int num_betas() const { return static_cast<int>(joint_shape_dirs_.cols()); }
  int frame_size() const { return FrameParamSize(num_joints()); }
  const std::vector<int>& vertex_ids() const { return vertex_ids_; }
  const std::vector<int>& parents() const { return parents_; }

  /// Shaped rest positions of the marker vertices (3 x M), without offsets.
  Eigen::Matrix3Xd RestVertices(const Eigen::VectorXd& betas) const;
  /// Rest joints (3 x J) for `betas`.
  Eigen::Matrix3Xd RestJoints(const Eigen::VectorXd& betas) const;

  /// Fixes betas and offsets (3 x M) for the pose-only Evaluate (stage II).
  void SetShape(const Eigen::VectorXd& betas, const Eigen::Matrix3Xd& offsets);
  const Eigen::VectorXd& betas() const { return betas_; }
  const Eigen::Matrix3Xd& offsets() const { return offsets_; }
  /// The latent markers of the current shape: rest vertex + offset (3 x M).
  const Eigen::Matrix3Xd& latent_markers() const { return latent_; }

  /// Posed positions of the markers `markers` (indices into the model's
  /// markers; all when empty) for the frame vector `frame` with the shape
  /// from SetShape: `positions` 3 x K. `jacobian_frame`, if not null, gets
  /// the (3K) x frame_size() row-major Jacobian.
  void Evaluate(const double* frame,
                const std::vector<int>& markers,
                Eigen::Matrix3Xd* positions,
                double* jacobian_frame) const;

  /// Full evaluation with free shape (stage I): betas (num_betas()), offsets
  /// (3M, marker-major). Jacobians (row-major, any may be null): frame
  /// (3K x frame_size), betas (3K x B), offsets (3K x 3: the 3 x 3 block of
  /// each evaluated marker with respect to its own offset; a marker does not
  /// depend on the other markers' offsets).
  void EvaluateWithShape(const double* frame,
                         const double* betas,
                         const double* offsets,
                         const std::vector<int>& markers,
                         Eigen::Matrix3Xd* positions,
                         double* jacobian_frame,
                         double* jacobian_betas,
                         double* jacobian_offsets) const;

 private:
  struct Influence {
    int joint;
    double weight;
  };
  struct Kinematics {
    std::vector<Eigen::Matrix3d> rotation;  // R_j, world
    std::vector<Eigen::Vector3d> position;  // c_j, world
    std::vector<Eigen::Matrix3d> omega;     // R_parent(j) J_l(theta_j)
  };
  void ForwardKinematics(const double* frame,
                         const Eigen::Matrix3Xd& rest_joints,
                         bool with_jacobian,
                         Kinematics* kin) const;
  /// Shared core: positions and the frame Jacobian of the markers, given
  /// latent rest points and rest joints.
  void PoseMarkers(const double* frame,
                   const Eigen::Matrix3Xd& latent,
                   const Eigen::Matrix3Xd& rest_joints,
                   const std::vector<int>& markers,
                   Eigen::Matrix3Xd* positions,
                   double* jacobian_frame,
                   Kinematics* kin) const;

  std::vector<int> parents_;
  std::vector<std::vector<int>> ancestors_;  // per joint: itself, parent, ...
  Eigen::Matrix3Xd joint_template_;          // 3 x J
  Eigen::MatrixXd joint_shape_dirs_;         // 3J x B
  std::vector<int> vertex_ids_;              // M
  Eigen::Matrix3Xd vertex_template_;         // 3 x M
  Eigen::MatrixXd vertex_shape_dirs_;        // 3M x B
  std::vector<std::vector<Influence>> influences_;  // M
  // Current shape (SetShape).
  Eigen::VectorXd betas_;
  Eigen::Matrix3Xd offsets_;
  Eigen::Matrix3Xd latent_;
  Eigen::Matrix3Xd rest_joints_;
};

}  // namespace soma
