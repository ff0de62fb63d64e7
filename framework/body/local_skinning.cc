#include "framework/body/local_skinning.h"

#include "framework/core/error.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <map>

namespace soma {

Eigen::Matrix3d AxisAngleRotation(double x, double y, double z) {
  const double angle2 = x * x + y * y + z * z;
  Eigen::Matrix3d k;
  k << 0.0, -z, y, z, 0.0, -x, -y, x, 0.0;
  if (angle2 < 1e-24) return Eigen::Matrix3d::Identity() + k;
  const double angle = std::sqrt(angle2);
  const double s = std::sin(angle) / angle;
  const double c = (1.0 - std::cos(angle)) / angle2;
  return Eigen::Matrix3d::Identity() + s * k + c * (k * k);
}

Eigen::MatrixXd JointShapeDirections(const BodyModel& body) {
  const int num_joints = body.num_joints();
  const int num_betas = body.num_betas();
  Eigen::MatrixXd dirs(3 * num_joints, num_betas);
  for (int b = 0; b < num_betas; ++b) {
    const Eigen::Map<const Eigen::Matrix3Xd> dir(
        body.shape_dirs.col(b).data(), 3, body.num_vertices());
    const Eigen::MatrixXd joint_dir =
        body.joint_regressor * dir.transpose();  // J x 3
    for (int j = 0; j < num_joints; ++j) {
      for (int c = 0; c < 3; ++c) dirs(3 * j + c, b) = joint_dir(j, c);
    }
  }
  return dirs;
}

std::vector<std::pair<double, int>> SkinningInfluences(const BodyModel& body,
                                                       int vid) {
  std::vector<std::pair<double, int>> w;
  for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator it(
           body.skinning_weights, vid);
       it;
       ++it) {
    if (it.value() != 0.0)
      w.emplace_back(it.value(), static_cast<int>(it.col()));
  }
  if (static_cast<int>(w.size()) > kMaxSkinningInfluences) {
    std::sort(w.begin(), w.end(), [](const auto& a, const auto& b) {
      return a.first > b.first;
    });
    w.resize(kMaxSkinningInfluences);
    double total = 0.0;
    for (const auto& x : w) total += x.first;
    for (auto& x : w) x.first /= total;
  }
  return w;
}

MarkerRings BuildMarkerRings(const BodyModel& body,
                             const std::vector<int>& vertex_ids) {
  MarkerRings rings;
  const int num_markers = static_cast<int>(vertex_ids.size());
  std::map<int, int> local_of;  // body id -> local index
  auto local = [&](int vid) {
    const auto [it, inserted] =
        local_of.emplace(vid, static_cast<int>(rings.local_ids.size()));
    if (inserted) rings.local_ids.push_back(vid);
    return it->second;
  };
  for (const int vid : vertex_ids) rings.marker_local.push_back(local(vid));
  std::vector<std::vector<std::pair<int, int>>> ring(num_markers);
  std::map<int, std::vector<int>> markers_of_vertex;
  for (int m = 0; m < num_markers; ++m)
    markers_of_vertex[vertex_ids[m]].push_back(m);
  for (Eigen::Index f = 0; f < body.faces.cols(); ++f) {
    for (int k = 0; k < 3; ++k) {
      const auto it = markers_of_vertex.find(body.faces(k, f));
      if (it == markers_of_vertex.end()) continue;
      const int b = body.faces((k + 1) % 3, f);
      const int c = body.faces((k + 2) % 3, f);
      for (const int m : it->second) ring[m].emplace_back(b, c);
    }
  }
  rings.ring_offsets.push_back(0);
  for (int m = 0; m < num_markers; ++m) {
    for (const auto& [b, c] : ring[m]) {
      rings.ring_pairs.push_back(local(b));
      rings.ring_pairs.push_back(local(c));
    }
    rings.ring_offsets.push_back(static_cast<int>(rings.ring_pairs.size() / 2));
  }
  return rings;
}

void CheckVertexIds(const BodyModel& body,
                    const std::vector<int>& vertex_ids,
                    std::string_view who) {
  const int nv = body.num_vertices();
  for (const int vid : vertex_ids) {
    if (vid < 0 || vid >= nv) {
      throw ShapeError(fmt::format(
          "{}: vertex id {} outside [0, {}) of '{}'", who, vid, nv, body.name));
    }
  }
}

LocalSkinningModel BuildLocalSkinningModel(const BodyModel& body,
                                           const std::vector<int>& local_ids) {
  LocalSkinningModel model;
  model.num_joints = body.num_joints();
  model.num_betas = body.num_betas();
  model.parents = body.parents;
  const int nl = static_cast<int>(local_ids.size());
  const int nb = model.num_betas;

  // Shape space restricted to the local vertices.
  model.template_vertices = Eigen::VectorXf::Zero(4 * nl);
  model.shape_dirs = Eigen::MatrixXf::Zero(4 * nl, nb);
  for (int l = 0; l < nl; ++l) {
    const int vid = local_ids[l];
    model.template_vertices(4 * l + 3) = 1.0f;
    for (int c = 0; c < 3; ++c) {
      model.template_vertices(4 * l + c) =
          static_cast<float>(body.template_vertices(c, vid));
      for (int b = 0; b < nb; ++b) {
        model.shape_dirs(4 * l + c, b) =
            static_cast<float>(body.shape_dirs(3 * vid + c, b));
      }
    }
  }
  if (body.pose_dirs.size() != 0) {
    model.pose_dirs = Eigen::MatrixXf::Zero(4 * nl, body.pose_dirs.cols());
    for (int l = 0; l < nl; ++l) {
      for (int c = 0; c < 3; ++c) {
        model.pose_dirs.row(4 * l + c) =
            body.pose_dirs.row(3 * local_ids[l] + c).cast<float>();
      }
    }
  }

  // Joints: J(beta) = regressor * (template + dirs * beta), precomputed.
  model.joint_template = body.RestJoints(body.template_vertices);
  model.joint_shape_dirs = JointShapeDirections(body);

  // Skinning influences, strongest first, at most kMaxSkinningInfluences.
  constexpr int kMax = kMaxSkinningInfluences;
  model.influence_joint.assign(static_cast<size_t>(nl) * kMax, 0);
  model.influence_weight.assign(static_cast<size_t>(nl) * kMax, 0.0f);
  model.influence_count.assign(nl, 0);
  for (int l = 0; l < nl; ++l) {
    const std::vector<std::pair<double, int>> w =
        SkinningInfluences(body, local_ids[l]);
    model.influence_count[l] = static_cast<int>(w.size());
    for (size_t k = 0; k < w.size(); ++k) {
      model.influence_joint[l * kMax + k] = w[k].second;
      model.influence_weight[l * kMax + k] = static_cast<float>(w[k].first);
    }
  }
  return model;
}

void ComputeSkinningTransforms(const std::vector<int>& parents,
                               const Eigen::Matrix3Xd& joint_template,
                               const Eigen::MatrixXd& joint_shape_dirs,
                               const Eigen::VectorXd& betas,
                               const BodyPose& pose,
                               const std::vector<int>& joints,
                               bool pose_features,
                               SkinningTransforms* out) {
  const int num_joints = static_cast<int>(parents.size());
  const int nb = static_cast<int>(betas.size());
  out->rest_joints = joint_template;
  if (nb > 0) {
    const Eigen::VectorXd offsets = joint_shape_dirs.leftCols(nb) * betas;
    out->rest_joints +=
        Eigen::Map<const Eigen::Matrix3Xd>(offsets.data(), 3, num_joints);
  }
  out->global_rotation.resize(num_joints);
  out->global_translation.resize(num_joints);
  out->rows.assign(3 * static_cast<size_t>(num_joints),
                   Eigen::Vector4f::Zero());
  for (const int j : joints) {
    const Eigen::Matrix3d r = AxisAngleRotation(
        pose.rotations(0, j), pose.rotations(1, j), pose.rotations(2, j));
    const int p = parents[j];
    if (p < 0) {
      out->global_rotation[j] = r;
      out->global_translation[j] = out->rest_joints.col(j) + pose.translation;
    } else {
      out->global_rotation[j] = out->global_rotation[p] * r;
      out->global_translation[j] =
          out->global_rotation[p] *
              (out->rest_joints.col(j) - out->rest_joints.col(p)) +
          out->global_translation[p];
    }
    const Eigen::Matrix3d& g = out->global_rotation[j];
    const Eigen::Vector3d t =
        out->global_translation[j] - g * out->rest_joints.col(j);
    for (int row = 0; row < 3; ++row) {
      out->rows[3 * j + row] = Eigen::Vector4f(static_cast<float>(g(row, 0)),
                                               static_cast<float>(g(row, 1)),
                                               static_cast<float>(g(row, 2)),
                                               static_cast<float>(t(row)));
    }
  }
  if (!pose_features) return;
  out->pose_features.resize(9 * (num_joints - 1));
  for (int j = 1; j < num_joints; ++j) {
    const Eigen::Matrix3d r = AxisAngleRotation(
        pose.rotations(0, j), pose.rotations(1, j), pose.rotations(2, j));
    for (int a = 0; a < 3; ++a) {
      for (int b = 0; b < 3; ++b) {
        out->pose_features(9 * (j - 1) + 3 * a + b) =
            static_cast<float>(r(a, b) - (a == b ? 1.0 : 0.0));
      }
    }
  }
}

}  // namespace soma
