#include "framework/synth/placed_markers.h"

#include "framework/core/error.h"

#include <fmt/format.h>

#include <utility>

namespace soma::internal {
namespace {

constexpr int kMaxInfluences = kMaxSkinningInfluences;

}  // namespace

PlacedMarkerSampler::PlacedMarkerSampler(const BodyModel& body,
                                         const std::vector<int>& vertex_ids,
                                         const std::vector<double>& distances) {
  const int num_candidates = static_cast<int>(vertex_ids.size());
  if (num_candidates == 0 || distances.size() != vertex_ids.size()) {
    throw ShapeError(
        fmt::format("PlacedMarkerSampler: {} candidates with {} distances",
                    vertex_ids.size(),
                    distances.size()));
  }
  CheckVertexIds(body, vertex_ids, "PlacedMarkerSampler");
  for (const double d : distances) distances_.push_back(static_cast<float>(d));
  all_joints_.resize(body.num_joints());
  for (int j = 0; j < body.num_joints(); ++j) all_joints_[j] = j;

  // Candidate vertices, their incident faces and the local vertex set.
  rings_ = BuildMarkerRings(body, vertex_ids);
  skin_ = BuildLocalSkinningModel(body, rings_.local_ids);
}

void PlacedMarkerSampler::Select(const std::vector<int>& candidates,
                                 Selection* selection) const {
  selection->candidates = candidates;
  selection->active.clear();
  std::vector<char> used(skin_.num_local(), 0);
  for (const int c : candidates) {
    if (c < 0 || c >= num_candidates()) {
      throw InternalError(
          fmt::format("PlacedMarkerSampler: candidate {} out of range", c));
    }
    used[rings_.marker_local[c]] = 1;
    for (int f = rings_.ring_offsets[c]; f < rings_.ring_offsets[c + 1]; ++f) {
      used[rings_.ring_pairs[2 * f]] = 1;
      used[rings_.ring_pairs[2 * f + 1]] = 1;
    }
  }
  for (int l = 0; l < skin_.num_local(); ++l) {
    if (used[l]) selection->active.push_back(l);
  }
}

void PlacedMarkerSampler::Sample(const Eigen::VectorXd& betas,
                                 const BodyPose& pose,
                                 const Selection& selection,
                                 Workspace* ws,
                                 float* out) const {
  if (betas.size() > skin_.num_betas ||
      pose.rotations.cols() != skin_.num_joints) {
    throw ShapeError(fmt::format(
        "PlacedMarkerSampler: {} betas (body has {}), {} joint rotations "
        "(body has {})",
        betas.size(),
        skin_.num_betas,
        pose.rotations.cols(),
        skin_.num_joints));
  }
  const int nb = static_cast<int>(betas.size());
  const int nl = skin_.num_local();
  // Forward kinematics (double) to 3x4 skinning transforms (float).
  const bool correctives = skin_.pose_dirs.size() != 0;
  ComputeSkinningTransforms(skin_.parents,
                            skin_.joint_template,
                            skin_.joint_shape_dirs,
                            betas,
                            pose,
                            all_joints_,
                            correctives,
                            &ws->transforms);
  ws->betas.resize(nb);
  for (int b = 0; b < nb; ++b) ws->betas[b] = static_cast<float>(betas(b));
  ws->posed.resize(3 * static_cast<size_t>(nl));

  // Shape and skin the active local vertices (float, 4-wide).
  const Eigen::Vector4f* rows = ws->transforms.rows.data();
  for (const int l : selection.active) {
    Eigen::Vector4f v =
        Eigen::Map<const Eigen::Vector4f>(&skin_.template_vertices(4 * l));
    for (int b = 0; b < nb; ++b) {
      v += ws->betas[b] * skin_.shape_dirs.col(b).segment<4>(4 * l);
    }
    if (correctives) {
      v += skin_.pose_dirs.middleRows(4 * l, 4) * ws->transforms.pose_features;
    }
    const int* jj = &skin_.influence_joint[kMaxInfluences * l];
    const float* ww = &skin_.influence_weight[kMaxInfluences * l];
    Eigen::Vector4f m0 = ww[0] * rows[3 * jj[0]];
    Eigen::Vector4f m1 = ww[0] * rows[3 * jj[0] + 1];
    Eigen::Vector4f m2 = ww[0] * rows[3 * jj[0] + 2];
    for (int k = 1; k < kMaxInfluences; ++k) {
      if (ww[k] == 0.0f) break;
      m0 += ww[k] * rows[3 * jj[k]];
      m1 += ww[k] * rows[3 * jj[k] + 1];
      m2 += ww[k] * rows[3 * jj[k] + 2];
    }
    ws->posed[3 * l] = m0.dot(v);
    ws->posed[3 * l + 1] = m1.dot(v);
    ws->posed[3 * l + 2] = m2.dot(v);
  }

  // Markers: vertex + distance * unit normal.
  const float* posed = ws->posed.data();
  for (size_t m = 0; m < selection.candidates.size(); ++m) {
    const int c = selection.candidates[m];
    const int a = rings_.marker_local[c];
    Eigen::Vector3f n = RingNormal(rings_, c, posed);
    const float norm = n.norm();
    if (norm > 0.0f) n /= norm;
    for (int k = 0; k < 3; ++k) {
      out[3 * m + k] = posed[3 * a + k] + distances_[c] * n(k);
    }
  }
}

}  // namespace soma::internal
