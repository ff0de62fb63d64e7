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
  CheckVertexIds(body, vertex_ids, "VirtualMarkerSampler");
  marker_vertex_ids_ = vertex_ids;
  distances_.resize(num_markers);
  for (int m = 0; m < num_markers; ++m) {
    distances_[m] = static_cast<float>(distances_from_skin.size() == 1
                                           ? distances_from_skin[0]
                                           : distances_from_skin[m]);
  }

  // The marker vertices, their incident faces and the local vertex set.
  rings_ = BuildMarkerRings(body, vertex_ids);
  const int nl = static_cast<int>(rings_.local_ids.size());

  // Order the local vertices by their number of skinning influences, so that
  // skinning runs one branch-free loop per count.
  {
    std::vector<int> count(nl);
    for (int l = 0; l < nl; ++l) {
      const int vid = rings_.local_ids[l];
      count[l] = std::min<int>(
          kMaxInfluences,
          static_cast<int>(body.skinning_weights.outerIndexPtr()[vid + 1] -
                           body.skinning_weights.outerIndexPtr()[vid]));
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
      ids[l] = rings_.local_ids[order[l]];
    }
    rings_.local_ids = std::move(ids);
    for (int& m : rings_.marker_local) m = rank[m];
    for (int& r : rings_.ring_pairs) r = rank[r];
  }

  // Shape space, pose correctives, joints and skinning influences of the
  // local vertices.
  skin_ = BuildLocalSkinningModel(body, rings_.local_ids);

  // Only the joints that influence a local vertex, and their ancestors.
  std::vector<char> needed(skin_.num_joints, 0);
  for (int l = 0; l < nl; ++l) {
    for (int k = 0; k < skin_.influence_count[l]; ++k) {
      for (int j = skin_.influence_joint[l * kMaxInfluences + k]; j >= 0;
           j = skin_.parents[j]) {
        needed[j] = 1;
      }
    }
  }
  for (int j = 0; j < skin_.num_joints; ++j) {
    if (needed[j]) posed_joints_.push_back(j);
  }
  count_begin_.assign(kMaxInfluences + 2, nl);
  for (int l = nl - 1; l >= 0; --l) {
    for (int k = 0; k <= skin_.influence_count[l]; ++k) count_begin_[k] = l;
  }
}

void VirtualMarkerSampler::PoseLocal(const Eigen::VectorXd& betas,
                                     const BodyPose& pose,
                                     Workspace* ws) const {
  if (betas.size() > skin_.num_betas) {
    throw ShapeError(
        fmt::format("VirtualMarkerSampler: {} betas given, the body has {}",
                    betas.size(),
                    skin_.num_betas));
  }
  if (pose.rotations.cols() != skin_.num_joints) {
    throw ShapeError(fmt::format(
        "VirtualMarkerSampler: pose has {} joint rotations, the body "
        "has {}",
        pose.rotations.cols(),
        skin_.num_joints));
  }
  const int nb = static_cast<int>(betas.size());
  const int nl = num_local_vertices();

  // Forward kinematics of the needed joints (double) to 3x4 skinning
  // transforms (float), and the shaped local vertices (float).
  const bool correctives = skin_.pose_dirs.size() != 0;
  ComputeSkinningTransforms(skin_.parents,
                            skin_.joint_template,
                            skin_.joint_shape_dirs,
                            betas,
                            pose,
                            posed_joints_,
                            correctives,
                            &ws->transforms);
  ws->shaped = skin_.template_vertices;
  if (nb > 0) {
    ws->betas = betas.cast<float>();
    ws->shaped.noalias() += skin_.shape_dirs.leftCols(nb) * ws->betas;
  }
  if (correctives) {
    ws->shaped.noalias() += skin_.pose_dirs * ws->transforms.pose_features;
  }
  // Linear blend skinning of the local vertices, grouped by influence count.
  ws->posed.resize(3 * nl);
  const float* shaped = ws->shaped.data();
  float* posed = ws->posed.data();
  const Eigen::Vector4f* rows = ws->transforms.rows.data();
  const int* joints = skin_.influence_joint.data();
  const float* weights = skin_.influence_weight.data();
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

void VirtualMarkerSampler::Sample(const Eigen::VectorXd& betas,
                                  const BodyPose& pose,
                                  Workspace* workspace,
                                  Eigen::Matrix3Xd* markers) const {
  PoseLocal(betas, pose, workspace);
  const int num = num_markers();
  markers->resize(3, num);
  const float* posed = workspace->posed.data();
  for (int m = 0; m < num; ++m) {
    Eigen::Vector3f n = RingNormal(rings_, m, posed);
    const float norm = n.norm();
    if (norm > 0.0f) n /= norm;
    const int a = rings_.marker_local[m];
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
    Eigen::Vector3f n = RingNormal(rings_, m, posed);
    const float norm = n.norm();
    if (norm > 0.0f) n /= norm;
    const int a = rings_.marker_local[m];
    for (int c = 0; c < 3; ++c) {
      (*vertices)(c, m) = posed[3 * a + c];
      (*normals)(c, m) = n(c);
    }
  }
}

}  // namespace soma
