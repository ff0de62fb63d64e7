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

  int num_markers() const {
    return static_cast<int>(rings_.marker_local.size());
  }
  /// Vertices shaped and skinned per sample (markers + 1-rings).
  int num_local_vertices() const {
    return static_cast<int>(rings_.local_ids.size());
  }
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

  static constexpr int kMaxInfluences = kMaxSkinningInfluences;

  std::vector<int> marker_vertex_ids_;  // M
  std::vector<float> distances_;        // M
  // The marker vertices and their 1-rings; local vertices sorted by their
  // number of skinning influences.
  MarkerRings rings_;
  LocalSkinningModel skin_;        // of rings_.local_ids
  std::vector<int> posed_joints_;  // joints needed, ascending (parents first)
  std::vector<int> count_begin_;   // first local vertex with >= k influences
};

}  // namespace soma
