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
  const int nv = body.num_vertices();
  for (const int vid : vertex_ids) {
    if (vid < 0 || vid >= nv) {
      throw ShapeError(fmt::format(
          "PlacedMarkerSampler: vertex id {} outside [0, {}) of '{}'",
          vid,
          nv,
          body.name));
    }
  }
  num_joints_ = body.num_joints();
  num_betas_ = body.num_betas();
  parents_ = body.parents;
  for (const double d : distances) distances_.push_back(static_cast<float>(d));

  all_joints_.resize(num_joints_);
  for (int j = 0; j < num_joints_; ++j) all_joints_[j] = j;

  // Candidate vertices, their incident faces and the local vertex set.
  MarkerRings rings = BuildMarkerRings(body, vertex_ids);
  const std::vector<int>& local_ids = rings.local_ids;
  candidate_local_ = std::move(rings.marker_local);
  ring_offsets_ = std::move(rings.ring_offsets);
  ring_pairs_ = std::move(rings.ring_pairs);
  num_local_ = static_cast<int>(local_ids.size());

  template_.assign(4 * static_cast<size_t>(num_local_), 0.0f);
  shape_dirs_.assign(4 * static_cast<size_t>(num_local_) * num_betas_, 0.0f);
  for (int l = 0; l < num_local_; ++l) {
    const int vid = local_ids[l];
    template_[4 * l + 3] = 1.0f;
    for (int c = 0; c < 3; ++c) {
      template_[4 * l + c] = static_cast<float>(body.template_vertices(c, vid));
      for (int b = 0; b < num_betas_; ++b) {
        shape_dirs_[(static_cast<size_t>(l) * num_betas_ + b) * 4 + c] =
            static_cast<float>(body.shape_dirs(3 * vid + c, b));
      }
    }
  }
  if (body.pose_dirs.size() != 0) {
    pose_dirs_ = Eigen::MatrixXf::Zero(4 * num_local_, body.pose_dirs.cols());
    for (int l = 0; l < num_local_; ++l) {
      for (int c = 0; c < 3; ++c) {
        pose_dirs_.row(4 * l + c) =
            body.pose_dirs.row(3 * local_ids[l] + c).cast<float>();
      }
    }
  }

  joint_template_ = body.RestJoints(body.template_vertices);
  joint_shape_dirs_ = JointShapeDirections(body);

  influence_joint_.assign(static_cast<size_t>(num_local_) * kMaxInfluences, 0);
  influence_weight_.assign(static_cast<size_t>(num_local_) * kMaxInfluences,
                           0.0f);
  for (int l = 0; l < num_local_; ++l) {
    const std::vector<std::pair<double, int>> w =
        SkinningInfluences(body, local_ids[l]);
    for (size_t k = 0; k < w.size(); ++k) {
      influence_joint_[l * kMaxInfluences + k] = w[k].second;
      influence_weight_[l * kMaxInfluences + k] =
          static_cast<float>(w[k].first);
    }
  }
}

void PlacedMarkerSampler::Select(const std::vector<int>& candidates,
                                 Selection* selection) const {
  selection->candidates = candidates;
  selection->active.clear();
  std::vector<char> used(num_local_, 0);
  for (const int c : candidates) {
    if (c < 0 || c >= num_candidates()) {
      throw InternalError(
          fmt::format("PlacedMarkerSampler: candidate {} out of range", c));
    }
    used[candidate_local_[c]] = 1;
    for (int f = ring_offsets_[c]; f < ring_offsets_[c + 1]; ++f) {
      used[ring_pairs_[2 * f]] = 1;
      used[ring_pairs_[2 * f + 1]] = 1;
    }
  }
  for (int l = 0; l < num_local_; ++l) {
    if (used[l]) selection->active.push_back(l);
  }
}

void PlacedMarkerSampler::Sample(const Eigen::VectorXd& betas,
                                 const BodyPose& pose,
                                 const Selection& selection,
                                 Workspace* ws,
                                 float* out) const {
  if (betas.size() > num_betas_ || pose.rotations.cols() != num_joints_) {
    throw ShapeError(fmt::format(
        "PlacedMarkerSampler: {} betas (body has {}), {} joint rotations "
        "(body has {})",
        betas.size(),
        num_betas_,
        pose.rotations.cols(),
        num_joints_));
  }
  const int nb = static_cast<int>(betas.size());
  // Forward kinematics (double) to 3x4 skinning transforms (float).
  const bool correctives = pose_dirs_.size() != 0;
  ComputeSkinningTransforms(parents_,
                            joint_template_,
                            joint_shape_dirs_,
                            betas,
                            pose,
                            all_joints_,
                            correctives,
                            &ws->transforms);
  ws->betas.resize(nb);
  for (int b = 0; b < nb; ++b) ws->betas[b] = static_cast<float>(betas(b));
  ws->posed.resize(3 * static_cast<size_t>(num_local_));

  // Shape and skin the active local vertices (float, 4-wide).
  const Eigen::Vector4f* rows = ws->transforms.rows.data();
  for (const int l : selection.active) {
    Eigen::Vector4f v = Eigen::Map<const Eigen::Vector4f>(&template_[4 * l]);
    const float* dirs = &shape_dirs_[static_cast<size_t>(l) * num_betas_ * 4];
    for (int b = 0; b < nb; ++b) {
      v += ws->betas[b] * Eigen::Map<const Eigen::Vector4f>(dirs + 4 * b);
    }
    if (correctives) {
      v += pose_dirs_.middleRows(4 * l, 4) * ws->transforms.pose_features;
    }
    const int* jj = &influence_joint_[kMaxInfluences * l];
    const float* ww = &influence_weight_[kMaxInfluences * l];
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
    const int a = candidate_local_[c];
    const Eigen::Vector3f pa(posed[3 * a], posed[3 * a + 1], posed[3 * a + 2]);
    Eigen::Vector3f n = Eigen::Vector3f::Zero();
    for (int f = ring_offsets_[c]; f < ring_offsets_[c + 1]; ++f) {
      const int b = ring_pairs_[2 * f];
      const int d = ring_pairs_[2 * f + 1];
      const Eigen::Vector3f pb(
          posed[3 * b], posed[3 * b + 1], posed[3 * b + 2]);
      const Eigen::Vector3f pd(
          posed[3 * d], posed[3 * d + 1], posed[3 * d + 2]);
      n += (pb - pa).cross(pd - pa);
    }
    const float norm = n.norm();
    if (norm > 0.0f) n /= norm;
    for (int k = 0; k < 3; ++k) out[3 * m + k] = pa(k) + distances_[c] * n(k);
  }
}

}  // namespace soma::internal
