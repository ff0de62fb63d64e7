#include "framework/synth/placed_markers.h"

#include "framework/core/error.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <utility>

namespace soma::internal {
namespace {

constexpr int kMaxInfluences = 4;

Eigen::Matrix3d Rodrigues(double x, double y, double z) {
  const double angle2 = x * x + y * y + z * z;
  Eigen::Matrix3d k;
  k << 0.0, -z, y, z, 0.0, -x, -y, x, 0.0;
  if (angle2 < 1e-24) return Eigen::Matrix3d::Identity() + k;
  const double angle = std::sqrt(angle2);
  const double s = std::sin(angle) / angle;
  const double c = (1.0 - std::cos(angle)) / angle2;
  return Eigen::Matrix3d::Identity() + s * k + c * (k * k);
}

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

  std::map<int, int> local_of;
  std::vector<int> local_ids;
  auto local = [&](int vid) {
    const auto [it, inserted] =
        local_of.emplace(vid, static_cast<int>(local_ids.size()));
    if (inserted) local_ids.push_back(vid);
    return it->second;
  };
  for (const int vid : vertex_ids) candidate_local_.push_back(local(vid));
  // Incident faces of each candidate vertex, in face order (as VertexNormals
  // sums them).
  std::map<int, std::vector<int>> candidates_of_vertex;
  for (int c = 0; c < num_candidates; ++c)
    candidates_of_vertex[vertex_ids[c]].push_back(c);
  std::vector<std::vector<std::pair<int, int>>> ring(num_candidates);
  for (Eigen::Index f = 0; f < body.faces.cols(); ++f) {
    for (int k = 0; k < 3; ++k) {
      const auto it = candidates_of_vertex.find(body.faces(k, f));
      if (it == candidates_of_vertex.end()) continue;
      const int b = body.faces((k + 1) % 3, f);
      const int c = body.faces((k + 2) % 3, f);
      for (const int m : it->second) ring[m].emplace_back(b, c);
    }
  }
  ring_offsets_.push_back(0);
  for (int m = 0; m < num_candidates; ++m) {
    for (const auto& [b, c] : ring[m]) {
      ring_pairs_.push_back(local(b));
      ring_pairs_.push_back(local(c));
    }
    ring_offsets_.push_back(static_cast<int>(ring_pairs_.size() / 2));
  }
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
  joint_shape_dirs_.resize(3 * num_joints_, num_betas_);
  for (int b = 0; b < num_betas_; ++b) {
    const Eigen::Map<const Eigen::Matrix3Xd> dir(
        body.shape_dirs.col(b).data(), 3, nv);
    const Eigen::MatrixXd joint_dir = body.joint_regressor * dir.transpose();
    for (int j = 0; j < num_joints_; ++j) {
      for (int c = 0; c < 3; ++c)
        joint_shape_dirs_(3 * j + c, b) = joint_dir(j, c);
    }
  }

  influence_joint_.assign(static_cast<size_t>(num_local_) * kMaxInfluences, 0);
  influence_weight_.assign(static_cast<size_t>(num_local_) * kMaxInfluences,
                           0.0f);
  for (int l = 0; l < num_local_; ++l) {
    std::vector<std::pair<double, int>> w;
    for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator it(
             body.skinning_weights, local_ids[l]);
         it;
         ++it) {
      if (it.value() != 0.0)
        w.emplace_back(it.value(), static_cast<int>(it.col()));
    }
    if (static_cast<int>(w.size()) > kMaxInfluences) {
      // Keep the strongest and renormalise, as VirtualMarkerSampler.
      std::sort(w.begin(), w.end(), [](const auto& a, const auto& b) {
        return a.first > b.first;
      });
      w.resize(kMaxInfluences);
      double total = 0.0;
      for (const auto& x : w) total += x.first;
      for (auto& x : w) x.first /= total;
    }
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
  // Rest joints and forward kinematics (double).
  ws->rest_joints = joint_template_;
  if (nb > 0) {
    const Eigen::VectorXd offsets = joint_shape_dirs_.leftCols(nb) * betas;
    ws->rest_joints +=
        Eigen::Map<const Eigen::Matrix3Xd>(offsets.data(), 3, num_joints_);
  }
  ws->global_rotation.resize(num_joints_);
  ws->global_translation.resize(num_joints_);
  ws->rows.resize(3 * static_cast<size_t>(num_joints_));
  for (int j = 0; j < num_joints_; ++j) {
    const Eigen::Matrix3d r = Rodrigues(
        pose.rotations(0, j), pose.rotations(1, j), pose.rotations(2, j));
    const int p = parents_[j];
    if (p < 0) {
      ws->global_rotation[j] = r;
      ws->global_translation[j] = ws->rest_joints.col(j) + pose.translation;
    } else {
      ws->global_rotation[j] = ws->global_rotation[p] * r;
      ws->global_translation[j] =
          ws->global_rotation[p] *
              (ws->rest_joints.col(j) - ws->rest_joints.col(p)) +
          ws->global_translation[p];
    }
    const Eigen::Matrix3d& g = ws->global_rotation[j];
    const Eigen::Vector3d t =
        ws->global_translation[j] - g * ws->rest_joints.col(j);
    for (int row = 0; row < 3; ++row) {
      ws->rows[3 * j + row] = Eigen::Vector4f(static_cast<float>(g(row, 0)),
                                              static_cast<float>(g(row, 1)),
                                              static_cast<float>(g(row, 2)),
                                              static_cast<float>(t(row)));
    }
  }
  const bool correctives = pose_dirs_.size() != 0;
  if (correctives) {
    ws->pose_features.resize(9 * (num_joints_ - 1));
    for (int j = 1; j < num_joints_; ++j) {
      const Eigen::Matrix3d r = Rodrigues(
          pose.rotations(0, j), pose.rotations(1, j), pose.rotations(2, j));
      for (int a = 0; a < 3; ++a) {
        for (int b = 0; b < 3; ++b) {
          ws->pose_features(9 * (j - 1) + 3 * a + b) =
              static_cast<float>(r(a, b) - (a == b ? 1.0 : 0.0));
        }
      }
    }
  }
  ws->betas.resize(nb);
  for (int b = 0; b < nb; ++b) ws->betas[b] = static_cast<float>(betas(b));
  ws->posed.resize(3 * static_cast<size_t>(num_local_));

  // Shape and skin the active local vertices (float, 4-wide).
  const Eigen::Vector4f* rows = ws->rows.data();
  for (const int l : selection.active) {
    Eigen::Vector4f v = Eigen::Map<const Eigen::Vector4f>(&template_[4 * l]);
    const float* dirs = &shape_dirs_[static_cast<size_t>(l) * num_betas_ * 4];
    for (int b = 0; b < nb; ++b) {
      v += ws->betas[b] * Eigen::Map<const Eigen::Vector4f>(dirs + 4 * b);
    }
    if (correctives) {
      v += pose_dirs_.middleRows(4 * l, 4) * ws->pose_features;
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
