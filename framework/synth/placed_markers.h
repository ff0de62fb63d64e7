// Virtual markers with a per-block choice among candidate vertices
// (REFERENCE.md 3.3, randomised placement): the same arithmetic as
// VirtualMarkerSampler (marker = v + n * d, LBS in float32 after forward
// kinematics in double, normal = normalised sum of the incident faces' cross
// products) on the same precomputed LocalSkinningModel
// (body/local_skinning.h), built once for the union of all labels' candidate
// vertices, but each frame shapes and skins only the vertices of the chosen
// candidates (and their 1-rings), so randomised placement costs about as much
// as a fixed layout.
#pragma once

#include "framework/body/body_model.h"
#include "framework/body/local_skinning.h"

#include <Eigen/Core>

#include <vector>

namespace soma::internal {

class PlacedMarkerSampler {
 public:
  /// Candidate c is vertex `vertex_ids[c]` with skin distance
  /// `distances[c]`. ShapeError on bad ids or sizes.
  PlacedMarkerSampler(const BodyModel& body,
                      const std::vector<int>& vertex_ids,
                      const std::vector<double>& distances);

  int num_candidates() const {
    return static_cast<int>(rings_.marker_local.size());
  }

  /// The local vertices a selection of candidates needs (computed once per
  /// placement block).
  struct Selection {
    std::vector<int> candidates;  // M chosen candidate indices
    std::vector<int> active;      // local vertices to pose, ascending
  };
  void Select(const std::vector<int>& candidates, Selection* selection) const;

  struct Workspace {
    SkinningTransforms transforms;
    std::vector<float> posed;  // 3 per local vertex (only active ones set)
    std::vector<float> betas;
    std::vector<int> stamp;  // Select() scratch
  };

  /// Positions of the selected candidates' markers (3 x M floats, world,
  /// metres) into `out` (size 3 M).
  void Sample(const Eigen::VectorXd& betas,
              const BodyPose& pose,
              const Selection& selection,
              Workspace* workspace,
              float* out) const;

 private:
  std::vector<int> all_joints_;   // 0..J-1
  std::vector<float> distances_;  // per candidate
  MarkerRings rings_;             // the candidate vertices and their 1-rings
  LocalSkinningModel skin_;       // of rings_.local_ids
};

}  // namespace soma::internal
