#include "framework/body/virtual_markers.h"

#include "framework/core/error.h"

#include <fmt/format.h>

#include <algorithm>

namespace soma {
namespace {

/// LBS of local vertices [begin, end), each with exactly K influences
/// (stride kMaxInfluences = 4 in `joints`/`weights`): blend the rows of the
/// 3x4 transforms (4-wide SIMD), then apply.
template <int K>
void SkinBlock(int begin,
               int end,
               const int* joints,
               const float* weights,
               const Eigen::Vector4f* rows,
               const float* shaped,
               float* posed) {
  for (int l = begin; l < end; ++l) {
    const int* jj = joints + 4 * static_cast<size_t>(l);
    const float* ww = weights + 4 * static_cast<size_t>(l);
    const Eigen::Vector4f* a = rows + 3 * jj[0];
    Eigen::Vector4f m0 = ww[0] * a[0];
    Eigen::Vector4f m1 = ww[0] * a[1];
    Eigen::Vector4f m2 = ww[0] * a[2];
    for (int k = 1; k < K; ++k) {
      a = rows + 3 * jj[k];
      m0 += ww[k] * a[0];
      m1 += ww[k] * a[1];
      m2 += ww[k] * a[2];
    }
    const Eigen::Map<const Eigen::Vector4f, Eigen::Aligned16> p(shaped + 4 * l);
    posed[3 * l] = m0.dot(p);
    posed[3 * l + 1] = m1.dot(p);
    posed[3 * l + 2] = m2.dot(p);
  }
}

}  // namespace

VirtualMarkerSampler::VirtualMarkerSampler(
    const BodyModel& body,
    const std::vector<int>& vertex_ids,
    const std::vector<double>& distances_from_skin) {
  Init(body, vertex_ids, distances_from_skin);
}

VirtualMarkerSampler::VirtualMarkerSampler(const BodyModel& body,
                                           const MarkerLayout& layout) {
  std::vector<int> ids;
  std::vector<double> distances;
  for (const MarkerLayout::Marker& m : layout.markers) {
    if (m.vertex_ids.empty()) {
      throw ShapeError(fmt::format(
          "VirtualMarkerSampler: marker {} has no vertex id", m.label));
    }
    ids.push_back(m.vertex_ids[0]);
    distances.push_back(m.distance_from_skin);
  }
  Init(body, ids, distances);
}

void VirtualMarkerSampler::Init(
    const BodyModel& body,
    const std::vector<int>& vertex_ids,
    const std::vector<double>& distances_from_skin) {
  const int num_markers = static_cast<int>(vertex_ids.size());
  if (num_markers == 0) throw ShapeError("VirtualMarkerSampler: no markers");
  if (distances_from_skin.size() != 1 &&
      static_cast<int>(distances_from_skin.size()) != num_markers) {
    throw ShapeError(
        fmt::format("VirtualMarkerSampler: {} distances for {} markers",
                    distances_from_skin.size(),
                    num_markers));
  }
  const int nv = body.num_vertices();
  for (const int vid : vertex_ids) {
    if (vid < 0 || vid >= nv) {
      throw ShapeError(fmt::format(
          "VirtualMarkerSampler: vertex id {} outside [0, {}) of '{}'",
          vid,
          nv,
          body.name));
    }
  }
  num_joints_ = body.num_joints();
  num_betas_ = body.num_betas();
  parents_ = body.parents;
  marker_vertex_ids_ = vertex_ids;
  distances_.resize(num_markers);
  for (int m = 0; m < num_markers; ++m) {
    distances_[m] = static_cast<float>(distances_from_skin.size() == 1
                                           ? distances_from_skin[0]
                                           : distances_from_skin[m]);
  }

  // The marker vertices, their incident faces and the local vertex set.
  MarkerRings rings = BuildMarkerRings(body, vertex_ids);
  local_ids_ = std::move(rings.local_ids);
  marker_local_ = std::move(rings.marker_local);
  ring_offsets_ = std::move(rings.ring_offsets);
  ring_pairs_ = std::move(rings.ring_pairs);
  const int nl = static_cast<int>(local_ids_.size());

  // Order the local vertices by their number of skinning influences, so that
  // skinning runs one branch-free loop per count.
  {
    std::vector<int> count(nl);
    for (int l = 0; l < nl; ++l) {
      count[l] = std::min<int>(
          kMaxInfluences,
          static_cast<int>(
              body.skinning_weights.outerIndexPtr()[local_ids_[l] + 1] -
              body.skinning_weights.outerIndexPtr()[local_ids_[l]]));
    }
    std::vector<int> order(nl);
    for (int l = 0; l < nl; ++l) order[l] = l;
    std::stable_sort(order.begin(), order.end(), [&](int a, int b) {
      return count[a] < count[b];
    });
    std::vector<int> rank(nl);
    std::vector<int> ids(nl);
    for (int l = 0; l < nl; ++l) {
      rank[order[l]] = l;
      ids[l] = local_ids_[order[l]];
    }
    local_ids_ = std::move(ids);
    for (int& m : marker_local_) m = rank[m];
    for (int& r : ring_pairs_) r = rank[r];
  }

  // Shape space restricted to the local vertices, stored homogeneous
  // (x, y, z, 1) so that skinning loads each vertex as one aligned 4-vector.
  template_ = Eigen::VectorXf::Zero(4 * nl);
  shape_dirs_ = Eigen::MatrixXf::Zero(4 * nl, num_betas_);
  for (int l = 0; l < nl; ++l) {
    const int vid = local_ids_[l];
    template_(4 * l + 3) = 1.0f;
    for (int c = 0; c < 3; ++c) {
      template_(4 * l + c) = static_cast<float>(body.template_vertices(c, vid));
      for (int b = 0; b < num_betas_; ++b) {
        shape_dirs_(4 * l + c, b) =
            static_cast<float>(body.shape_dirs(3 * vid + c, b));
      }
    }
  }
  if (body.pose_dirs.size() != 0) {
    pose_dirs_ = Eigen::MatrixXf::Zero(4 * nl, body.pose_dirs.cols());
    for (int l = 0; l < nl; ++l) {
      for (int c = 0; c < 3; ++c) {
        pose_dirs_.row(4 * l + c) =
            body.pose_dirs.row(3 * local_ids_[l] + c).cast<float>();
      }
    }
  }

  // Joints: J(beta) = regressor * (template + dirs * beta), precomputed.
  joint_template_ = body.RestJoints(body.template_vertices);
  joint_shape_dirs_ = JointShapeDirections(body);

  // Skinning influences, strongest first, at most kMaxInfluences.
  influence_joint_.assign(static_cast<size_t>(nl) * kMaxInfluences, 0);
  influence_weight_.assign(static_cast<size_t>(nl) * kMaxInfluences, 0.0f);
  influence_count_.assign(nl, 0);
  std::vector<char> needed(num_joints_, 0);
  for (int l = 0; l < nl; ++l) {
    const std::vector<std::pair<double, int>> w =
        SkinningInfluences(body, local_ids_[l]);
    influence_count_[l] = static_cast<int>(w.size());
    for (size_t k = 0; k < w.size(); ++k) {
      influence_joint_[l * kMaxInfluences + k] = w[k].second;
      influence_weight_[l * kMaxInfluences + k] =
          static_cast<float>(w[k].first);
      for (int j = w[k].second; j >= 0; j = parents_[j]) needed[j] = 1;
    }
  }
  for (int j = 0; j < num_joints_; ++j) {
    if (needed[j]) posed_joints_.push_back(j);
  }
  count_begin_.assign(kMaxInfluences + 2, nl);
  for (int l = nl - 1; l >= 0; --l) {
    for (int k = 0; k <= influence_count_[l]; ++k) count_begin_[k] = l;
  }
}

void VirtualMarkerSampler::PoseLocal(const Eigen::VectorXd& betas,
                                     const BodyPose& pose,
                                     Workspace* ws) const {
  if (betas.size() > num_betas_) {
    throw ShapeError(
        fmt::format("VirtualMarkerSampler: {} betas given, the body has {}",
                    betas.size(),
                    num_betas_));
  }
  if (pose.rotations.cols() != num_joints_) {
    throw ShapeError(fmt::format(
        "VirtualMarkerSampler: pose has {} joint rotations, the body "
        "has {}",
        pose.rotations.cols(),
        num_joints_));
  }
  const int nb = static_cast<int>(betas.size());
  const int nl = num_local_vertices();

  // Forward kinematics of the needed joints (double) to 3x4 skinning
  // transforms (float), and the shaped local vertices (float).
  const bool correctives = pose_dirs_.size() != 0;
  ComputeSkinningTransforms(parents_,
                            joint_template_,
                            joint_shape_dirs_,
                            betas,
                            pose,
                            posed_joints_,
                            correctives,
                            &ws->transforms);
  ws->shaped = template_;
  if (nb > 0) {
    ws->betas = betas.cast<float>();
    ws->shaped.noalias() += shape_dirs_.leftCols(nb) * ws->betas;
  }
  if (correctives) {
    ws->shaped.noalias() += pose_dirs_ * ws->transforms.pose_features;
  }
  // Linear blend skinning of the local vertices, grouped by influence count.
  ws->posed.resize(3 * nl);
  const float* shaped = ws->shaped.data();
  float* posed = ws->posed.data();
  const Eigen::Vector4f* rows = ws->transforms.rows.data();
  const int* joints = influence_joint_.data();
  const float* weights = influence_weight_.data();
  for (int l = count_begin_[0]; l < count_begin_[1]; ++l) {
    for (int c = 0; c < 3; ++c) posed[3 * l + c] = shaped[4 * l + c];
  }
  SkinBlock<1>(
      count_begin_[1], count_begin_[2], joints, weights, rows, shaped, posed);
  SkinBlock<2>(
      count_begin_[2], count_begin_[3], joints, weights, rows, shaped, posed);
  SkinBlock<3>(
      count_begin_[3], count_begin_[4], joints, weights, rows, shaped, posed);
  SkinBlock<4>(
      count_begin_[4], count_begin_[5], joints, weights, rows, shaped, posed);
}

Eigen::Vector3f VirtualMarkerSampler::MarkerNormal(int m,
                                                   const float* posed) const {
  const int a = marker_local_[m];
  const Eigen::Vector3f pa(posed[3 * a], posed[3 * a + 1], posed[3 * a + 2]);
  Eigen::Vector3f n = Eigen::Vector3f::Zero();
  for (int f = ring_offsets_[m]; f < ring_offsets_[m + 1]; ++f) {
    const int b = ring_pairs_[2 * f];
    const int c = ring_pairs_[2 * f + 1];
    const Eigen::Vector3f pb(posed[3 * b], posed[3 * b + 1], posed[3 * b + 2]);
    const Eigen::Vector3f pc(posed[3 * c], posed[3 * c + 1], posed[3 * c + 2]);
    n += (pb - pa).cross(pc - pa);
  }
  return n;
}

void VirtualMarkerSampler::Sample(const Eigen::VectorXd& betas,
                                  const BodyPose& pose,
                                  Workspace* workspace,
                                  Eigen::Matrix3Xd* markers) const {
  PoseLocal(betas, pose, workspace);
  const int num = num_markers();
  markers->resize(3, num);
  const float* posed = workspace->posed.data();
  for (int m = 0; m < num; ++m) {
    Eigen::Vector3f n = MarkerNormal(m, posed);
    const float norm = n.norm();
    if (norm > 0.0f) n /= norm;
    const int a = marker_local_[m];
    const float d = distances_[m];
    for (int c = 0; c < 3; ++c) (*markers)(c, m) = posed[3 * a + c] + d * n(c);
  }
}

Eigen::Matrix3Xd VirtualMarkerSampler::Sample(const Eigen::VectorXd& betas,
                                              const BodyPose& pose) const {
  Workspace workspace;
  Eigen::Matrix3Xd markers;
  Sample(betas, pose, &workspace, &markers);
  return markers;
}

void VirtualMarkerSampler::SampleSurface(const Eigen::VectorXd& betas,
                                         const BodyPose& pose,
                                         Workspace* workspace,
                                         Eigen::Matrix3Xd* vertices,
                                         Eigen::Matrix3Xd* normals) const {
  PoseLocal(betas, pose, workspace);
  const int num = num_markers();
  vertices->resize(3, num);
  normals->resize(3, num);
  const float* posed = workspace->posed.data();
  for (int m = 0; m < num; ++m) {
    Eigen::Vector3f n = MarkerNormal(m, posed);
    const float norm = n.norm();
    if (norm > 0.0f) n /= norm;
    const int a = marker_local_[m];
    for (int c = 0; c < 3; ++c) {
      (*vertices)(c, m) = posed[3 * a + c];
      (*normals)(c, m) = n(c);
    }
  }
}

}  // namespace soma
