// Fast virtual markers (REFERENCE.md 3.3): marker = v[vid] + n[vid] * d,
// with v the posed (LBS) vertex and n its area-weighted vertex normal.
//
// VirtualMarkerSampler precomputes everything that does not depend on the
// sample for a fixed (body, marker vertex ids): only the marker vertices and
// their 1-ring neighbours are shaped and skinned (never the whole mesh), the
// normal at a marker vertex is the normalised sum of the cross products of
// its posed incident faces (exactly VertexNormals at that vertex), and only
// the joints that influence those vertices (plus their ancestors) are posed.
// Arithmetic is float32 after forward kinematics in double; results agree
// with PoseVertices/VertexNormals to ~1e-5 m.
#pragma once

#include "framework/body/body_model.h"
#include "framework/body/local_skinning.h"
#include "framework/body/marker_layout.h"

#include <Eigen/Core>

#include <vector>

namespace soma {

class VirtualMarkerSampler {
 public:
  /// Scratch memory of one Sample() call; one per thread.
  struct Workspace {
    Eigen::VectorXf betas;
    Eigen::VectorXf shaped;  // 4 * local vertices (x, y, z, 1)
    Eigen::VectorXf posed;   // 3 * local vertices
    SkinningTransforms transforms;
  };

  /// Markers on `vertex_ids` (M >= 1) with one distance per marker (metres),
  /// or a single distance for all. Throws ShapeError on bad sizes or ids.
  VirtualMarkerSampler(const BodyModel& body,
                       const std::vector<int>& vertex_ids,
                       const std::vector<double>& distances_from_skin);

  /// The layout's markers, each on its first vertex id, in layout order.
  VirtualMarkerSampler(const BodyModel& body, const MarkerLayout& layout);

  int num_markers() const { return static_cast<int>(marker_local_.size()); }
  /// Vertices shaped and skinned per sample (markers + 1-rings).
  int num_local_vertices() const { return static_cast<int>(local_ids_.size()); }
  const std::vector<int>& marker_vertex_ids() const {
    return marker_vertex_ids_;
  }

  /// Marker positions (3 x M, world, metres) for `betas` (size <= B, missing
  /// = 0) and `pose`. Reuses `workspace` (no allocation after the first call).
  void Sample(const Eigen::VectorXd& betas,
              const BodyPose& pose,
              Workspace* workspace,
              Eigen::Matrix3Xd* markers) const;

  /// Convenience overload with a temporary workspace.
  Eigen::Matrix3Xd Sample(const Eigen::VectorXd& betas,
                          const BodyPose& pose) const;

  /// The posed marker vertices and their unit normals (3 x M each), without
  /// the skin offset.
  void SampleSurface(const Eigen::VectorXd& betas,
                     const BodyPose& pose,
                     Workspace* workspace,
                     Eigen::Matrix3Xd* vertices,
                     Eigen::Matrix3Xd* normals) const;

 private:
  void Init(const BodyModel& body,
            const std::vector<int>& vertex_ids,
            const std::vector<double>& distances_from_skin);
  /// Shapes, poses and skins the local vertices into workspace->posed.
  void PoseLocal(const Eigen::VectorXd& betas,
                 const BodyPose& pose,
                 Workspace* workspace) const;
  /// Unnormalised normal (sum of face cross products) at marker m.
  Eigen::Vector3f MarkerNormal(int m, const float* posed) const;

  static constexpr int kMaxInfluences = kMaxSkinningInfluences;

  int num_joints_ = 0;
  int num_betas_ = 0;
  std::vector<int> parents_;
  std::vector<int> marker_vertex_ids_;  // M
  std::vector<float> distances_;        // M
  std::vector<int> local_ids_;          // L body vertex ids
  std::vector<int> marker_local_;       // M local index of each marker vertex
  // Per marker: ring faces as pairs (local b, local c) with (m, b, c) CCW.
  std::vector<int> ring_offsets_;     // M + 1
  std::vector<int> ring_pairs_;       // 2 per face
  Eigen::VectorXf template_;          // 4L: (x, y, z, 1) per vertex
  Eigen::MatrixXf shape_dirs_;        // 4L x B, rows 4l+3 zero
  Eigen::MatrixXf pose_dirs_;         // 4L x 9(J-1), empty if none
  Eigen::Matrix3Xd joint_template_;   // 3 x J
  Eigen::MatrixXd joint_shape_dirs_;  // 3J x B
  std::vector<int> posed_joints_;  // joints needed, ascending (parents first)
  std::vector<int> influence_joint_;     // L x kMaxInfluences
  std::vector<float> influence_weight_;  // L x kMaxInfluences (0-padded)
  std::vector<int> influence_count_;     // L, local vertices sorted by it
  std::vector<int> count_begin_;  // first local vertex with >= k influences
};

}  // namespace soma
