#include "framework/solve/marker_model.h"

#include "framework/body/local_skinning.h"
#include "framework/core/error.h"

#include <fmt/format.h>

#include <cmath>

namespace soma {
namespace {

Eigen::Matrix3d Skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d k;
  k << 0.0, -v.z(), v.y(), v.z(), 0.0, -v.x(), -v.y(), v.x(), 0.0;
  return k;
}

}  // namespace

Eigen::VectorXd PackFrameParams(const BodyPose& pose) {
  const int num_joints = static_cast<int>(pose.rotations.cols());
  Eigen::VectorXd params(FrameParamSize(num_joints));
  params.head<3>() = pose.translation;
  for (int j = 0; j < num_joints; ++j) {
    params.segment<3>(3 + 3 * j) = pose.rotations.col(j);
  }
  return params;
}

BodyPose UnpackFrameParams(const double* params, int num_joints) {
  BodyPose pose = BodyPose::Rest(num_joints);
  pose.translation = Eigen::Vector3d(params[0], params[1], params[2]);
  for (int j = 0; j < num_joints; ++j) {
    pose.rotations.col(j) = Eigen::Vector3d(
        params[3 + 3 * j], params[4 + 3 * j], params[5 + 3 * j]);
  }
  return pose;
}

Eigen::Matrix3d LeftJacobianSO3(const Eigen::Vector3d& w) {
  const double angle2 = w.squaredNorm();
  const Eigen::Matrix3d k = Skew(w);
  if (angle2 < 1e-12) {
    return Eigen::Matrix3d::Identity() + 0.5 * k + (1.0 / 6.0) * k * k;
  }
  const double angle = std::sqrt(angle2);
  const double a = (1.0 - std::cos(angle)) / angle2;
  const double b = (angle - std::sin(angle)) / (angle2 * angle);
  return Eigen::Matrix3d::Identity() + a * k + b * k * k;
}

LayoutMarkerVertices MarkerVertices(const MarkerLayout& layout) {
  LayoutMarkerVertices out;
  for (const MarkerLayout::Marker& m : layout.markers) {
    out.vertex_ids.push_back(m.vertex_ids.at(0));
    out.distances.push_back(m.distance_from_skin);
  }
  return out;
}

Eigen::Matrix3Xd NormalOffsets(const BodyModel& body,
                               const Eigen::VectorXd& betas,
                               const std::vector<int>& vertex_ids,
                               const std::vector<double>& distances) {
  SOMA_CHECK_EQ(vertex_ids.size(), distances.size()) << "NormalOffsets";
  const Eigen::Matrix3Xd normals =
      VertexNormals(body.ShapedVertices(betas), body.faces);
  Eigen::Matrix3Xd offsets(3, vertex_ids.size());
  for (size_t m = 0; m < vertex_ids.size(); ++m) {
    SOMA_CHECK(vertex_ids[m] >= 0 && vertex_ids[m] < body.num_vertices())
        << "vertex id " << vertex_ids[m];
    offsets.col(m) = normals.col(vertex_ids[m]) * distances[m];
  }
  return offsets;
}

MarkerModel::MarkerModel(const BodyModel& body,
                         const std::vector<int>& vertex_ids)
    : parents_(body.parents), vertex_ids_(vertex_ids) {
  SOMA_CHECK(!vertex_ids.empty()) << "MarkerModel: no markers";
  SOMA_CHECK(body.num_joints() > 0) << "MarkerModel: body has no joints";
  const int num_markers = static_cast<int>(vertex_ids.size());
  for (int m = 0; m < num_markers; ++m) {
    if (vertex_ids[m] < 0 || vertex_ids[m] >= body.num_vertices()) {
      throw ShapeError(fmt::format(
          "MarkerModel: marker {} has vertex id {}, outside [0, {}) of body "
          "'{}' (body/layout mismatch?)",
          m,
          vertex_ids[m],
          body.num_vertices(),
          body.name));
    }
  }
  const int num_joints = body.num_joints();
  ancestors_.resize(num_joints);
  for (int j = 0; j < num_joints; ++j) {
    for (int k = j; k >= 0; k = parents_[k]) ancestors_[j].push_back(k);
  }
  joint_template_ = body.RestJoints(body.template_vertices);
  joint_shape_dirs_ = JointShapeDirections(body);
  const int num_betas = body.num_betas();
  vertex_template_.resize(3, num_markers);
  vertex_shape_dirs_.setZero(3 * num_markers, num_betas);
  influences_.resize(num_markers);
  for (int m = 0; m < num_markers; ++m) {
    const int vid = vertex_ids[m];
    vertex_template_.col(m) = body.template_vertices.col(vid);
    if (num_betas > 0) {
      vertex_shape_dirs_.middleRows(3 * m, 3) =
          body.shape_dirs.middleRows(3 * vid, 3);
    }
    for (const auto& [weight, joint] : SkinningInfluences(body, vid)) {
      influences_[m].push_back({joint, weight});
    }
    SOMA_CHECK(!influences_[m].empty())
        << "MarkerModel: vertex " << vid << " has no skinning weights";
  }
  SetShape(Eigen::VectorXd::Zero(num_betas),
           Eigen::Matrix3Xd::Zero(3, num_markers));
}

Eigen::Matrix3Xd MarkerModel::RestVertices(const Eigen::VectorXd& betas) const {
  Eigen::Matrix3Xd rest = vertex_template_;
  const int nb = std::min<int>(static_cast<int>(betas.size()), num_betas());
  if (nb > 0) {
    const Eigen::VectorXd d = vertex_shape_dirs_.leftCols(nb) * betas.head(nb);
    rest += Eigen::Map<const Eigen::Matrix3Xd>(d.data(), 3, num_markers());
  }
  return rest;
}

Eigen::Matrix3Xd MarkerModel::RestJoints(const Eigen::VectorXd& betas) const {
  Eigen::Matrix3Xd rest = joint_template_;
  const int nb = std::min<int>(static_cast<int>(betas.size()), num_betas());
  if (nb > 0) {
    const Eigen::VectorXd d = joint_shape_dirs_.leftCols(nb) * betas.head(nb);
    rest += Eigen::Map<const Eigen::Matrix3Xd>(d.data(), 3, num_joints());
  }
  return rest;
}

void MarkerModel::SetShape(const Eigen::VectorXd& betas,
                           const Eigen::Matrix3Xd& offsets) {
  SOMA_CHECK_EQ(offsets.cols(), num_markers()) << "MarkerModel::SetShape";
  betas_ = Eigen::VectorXd::Zero(num_betas());
  const int nb = std::min<int>(static_cast<int>(betas.size()), num_betas());
  betas_.head(nb) = betas.head(nb);
  offsets_ = offsets;
  latent_ = RestVertices(betas_) + offsets_;
  rest_joints_ = RestJoints(betas_);
}

void MarkerModel::ForwardKinematics(const double* frame,
                                    const Eigen::Matrix3Xd& rest_joints,
                                    bool with_jacobian,
                                    Kinematics* kin) const {
  const int num_joints = this->num_joints();
  kin->rotation.resize(num_joints);
  kin->position.resize(num_joints);
  if (with_jacobian) kin->omega.resize(num_joints);
  const Eigen::Vector3d t(frame[0], frame[1], frame[2]);
  for (int j = 0; j < num_joints; ++j) {
    const double* w = frame + 3 + 3 * j;
    const Eigen::Matrix3d local = AxisAngleRotation(w[0], w[1], w[2]);
    const int p = parents_[j];
    if (p < 0) {
      kin->rotation[j] = local;
      kin->position[j] = rest_joints.col(j) + t;
      if (with_jacobian) {
        kin->omega[j] = LeftJacobianSO3(Eigen::Vector3d(w[0], w[1], w[2]));
      }
    } else {
      kin->rotation[j] = kin->rotation[p] * local;
      kin->position[j] =
          kin->position[p] +
          kin->rotation[p] * (rest_joints.col(j) - rest_joints.col(p));
      if (with_jacobian) {
        kin->omega[j] = kin->rotation[p] *
                        LeftJacobianSO3(Eigen::Vector3d(w[0], w[1], w[2]));
      }
    }
  }
}

void MarkerModel::PoseMarkers(const double* frame,
                              const Eigen::Matrix3Xd& latent,
                              const Eigen::Matrix3Xd& rest_joints,
                              const std::vector<int>& markers,
                              Eigen::Matrix3Xd* positions,
                              double* jacobian_frame,
                              Kinematics* kin) const {
  const bool all = markers.empty();
  const int count = all ? num_markers() : static_cast<int>(markers.size());
  ForwardKinematics(frame, rest_joints, jacobian_frame != nullptr, kin);
  positions->resize(3, count);
  const int cols = frame_size();
  if (jacobian_frame != nullptr) {
    Eigen::Map<RowMajorMatrix>(jacobian_frame, 3 * count, cols).setZero();
  }
  const int num_joints = this->num_joints();
  // Scratch for the Jacobian: per joint the weighted sum of the points it
  // moves and their weight.
  std::vector<Eigen::Vector3d> moved(jacobian_frame ? num_joints : 0);
  std::vector<double> moved_weight(jacobian_frame ? num_joints : 0, 0.0);
  std::vector<int> touched;
  for (int i = 0; i < count; ++i) {
    const int m = all ? i : markers[i];
    SOMA_CHECK(m >= 0 && m < num_markers()) << "marker index " << m;
    const Eigen::Vector3d x = latent.col(m);
    Eigen::Vector3d p = Eigen::Vector3d::Zero();
    touched.clear();
    for (const Influence& in : influences_[m]) {
      const Eigen::Vector3d q =
          kin->rotation[in.joint] * (x - rest_joints.col(in.joint)) +
          kin->position[in.joint];
      p += in.weight * q;
      if (jacobian_frame == nullptr) continue;
      for (int k : ancestors_[in.joint]) {
        if (moved_weight[k] == 0.0) {
          moved[k].setZero();
          touched.push_back(k);
        }
        moved[k] += in.weight * q;
        moved_weight[k] += in.weight;
      }
    }
    positions->col(i) = p;
    if (jacobian_frame == nullptr) continue;
    Eigen::Map<RowMajorMatrix> jac(jacobian_frame + 3 * i * cols, 3, cols);
    double total = 0.0;
    for (const Influence& in : influences_[m]) total += in.weight;
    jac.leftCols<3>() = total * Eigen::Matrix3d::Identity();
    for (int k : touched) {
      jac.middleCols<3>(3 + 3 * k) =
          -Skew(moved[k] - moved_weight[k] * kin->position[k]) * kin->omega[k];
      moved_weight[k] = 0.0;
    }
  }
}

void MarkerModel::Evaluate(const double* frame,
                           const std::vector<int>& markers,
                           Eigen::Matrix3Xd* positions,
                           double* jacobian_frame) const {
  Kinematics kin;
  PoseMarkers(
      frame, latent_, rest_joints_, markers, positions, jacobian_frame, &kin);
}

void MarkerModel::EvaluateWithShape(const double* frame,
                                    const double* betas,
                                    const double* offsets,
                                    const std::vector<int>& markers,
                                    Eigen::Matrix3Xd* positions,
                                    double* jacobian_frame,
                                    double* jacobian_betas,
                                    double* jacobian_offsets) const {
  const int num_markers = this->num_markers();
  const int num_joints = this->num_joints();
  const int nb = num_betas();
  const Eigen::VectorXd beta =
      nb > 0 ? Eigen::Map<const Eigen::VectorXd>(betas, nb).eval()
             : Eigen::VectorXd();
  const Eigen::Matrix3Xd latent =
      RestVertices(beta) +
      Eigen::Map<const Eigen::Matrix3Xd>(offsets, 3, num_markers);
  const Eigen::Matrix3Xd rest_joints = RestJoints(beta);
  Kinematics kin;
  PoseMarkers(
      frame, latent, rest_joints, markers, positions, jacobian_frame, &kin);
  const bool all = markers.empty();
  const int count = all ? num_markers : static_cast<int>(markers.size());
  if (jacobian_betas != nullptr) {
    Eigen::Map<RowMajorMatrix> jac(jacobian_betas, 3 * count, nb);
    if (nb > 0) {
      // d c_j / d beta: rows 3j..3j+2 of `dc` (3J x B).
      Eigen::MatrixXd dc(3 * num_joints, nb);
      for (int j = 0; j < num_joints; ++j) {
        const int p = parents_[j];
        if (p < 0) {
          dc.middleRows<3>(3 * j) = joint_shape_dirs_.middleRows<3>(3 * j);
        } else {
          dc.middleRows<3>(3 * j).noalias() =
              dc.middleRows<3>(3 * p) +
              kin.rotation[p] * (joint_shape_dirs_.middleRows<3>(3 * j) -
                                 joint_shape_dirs_.middleRows<3>(3 * p));
        }
      }
      Eigen::Matrix<double, 3, Eigen::Dynamic> block(3, nb);
      for (int i = 0; i < count; ++i) {
        const int m = all ? i : markers[i];
        block.setZero();
        for (const Influence& in : influences_[m]) {
          block.noalias() +=
              in.weight * (kin.rotation[in.joint] *
                               (vertex_shape_dirs_.middleRows<3>(3 * m) -
                                joint_shape_dirs_.middleRows<3>(3 * in.joint)) +
                           dc.middleRows<3>(3 * in.joint));
        }
        jac.middleRows<3>(3 * i) = block;
      }
    }
  }
  if (jacobian_offsets != nullptr) {
    Eigen::Map<RowMajorMatrix> jac(jacobian_offsets, 3 * count, 3);
    for (int i = 0; i < count; ++i) {
      const int m = all ? i : markers[i];
      Eigen::Matrix3d block = Eigen::Matrix3d::Zero();
      for (const Influence& in : influences_[m]) {
        block += in.weight * kin.rotation[in.joint];
      }
      jac.block<3, 3>(3 * i, 0) = block;
    }
  }
}

}  // namespace soma
