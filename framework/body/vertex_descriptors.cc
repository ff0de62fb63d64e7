#include "framework/body/vertex_descriptors.h"

#include "framework/core/error.h"

#include <fmt/format.h>

namespace soma {

int MarkerTypeClass(std::string_view type) {
  if (type == kWristMarkerType) return 1;
  if (type == "face") return 2;
  if (type.substr(0, 6) == "finger") return 3;
  return 0;
}

int LabelDescriptorWidth(int num_joints) {
  return 3 + 3 + 1 + num_joints + kNumMarkerTypeClasses;
}

Eigen::Matrix3d BodyFromWorldRotation() {
  Eigen::Matrix3d r;
  // left = +x, up = +z, forward = -y.
  r << 1, 0, 0,  //
      0, 0, 1,   //
      0, -1, 0;
  return r;
}

VertexDescriptors ComputeVertexDescriptors(const BodyModel& body) {
  if (body.num_vertices() == 0) {
    throw ShapeError(fmt::format(
        "ComputeVertexDescriptors: body '{}' has no vertices", body.name));
  }
  const Eigen::Matrix3Xd& rest = body.template_vertices;
  VertexDescriptors out;
  out.height = rest.row(2).maxCoeff() - rest.row(2).minCoeff();
  if (!(out.height > 0)) {
    throw ShapeError(fmt::format(
        "ComputeVertexDescriptors: body '{}' has zero height", body.name));
  }
  out.origin_in_world = body.RestJoints(rest).col(0);
  const Eigen::Matrix3d rotation = BodyFromWorldRotation();
  out.positions =
      (rotation * (rest.colwise() - out.origin_in_world)) / out.height;
  out.normals = rotation * VertexNormals(rest, body.faces);
  out.skinning_weights =
      Eigen::MatrixXd(body.skinning_weights).transpose();  // J x V
  return out;
}

Eigen::MatrixXf LayoutDescriptors(const VertexDescriptors& vertices,
                                  const MarkerLayout& layout) {
  const int num_joints = vertices.num_joints();
  const int width = LabelDescriptorWidth(num_joints);
  Eigen::MatrixXf out = Eigen::MatrixXf::Zero(layout.num_markers(), width);
  for (int l = 0; l < layout.num_markers(); ++l) {
    const MarkerLayout::Marker& marker = layout.markers[l];
    if (marker.vertex_ids.empty()) {
      throw ConfigError(fmt::format(
          "LayoutDescriptors: marker '{}' has no vertex ids", marker.label));
    }
    Eigen::Vector3d position = Eigen::Vector3d::Zero();
    Eigen::Vector3d normal = Eigen::Vector3d::Zero();
    Eigen::VectorXd weights = Eigen::VectorXd::Zero(num_joints);
    for (const int v : marker.vertex_ids) {
      if (v < 0 || v >= vertices.num_vertices()) {
        throw ConfigError(fmt::format(
            "LayoutDescriptors: marker '{}' has vertex id {}, expected 0 <= "
            "id < {} (the body's vertex count)",
            marker.label,
            v,
            vertices.num_vertices()));
      }
      position += vertices.positions.col(v);
      normal += vertices.normals.col(v);
      weights += vertices.skinning_weights.col(v);
    }
    const double count = static_cast<double>(marker.vertex_ids.size());
    position /= count;
    weights /= count;
    if (normal.norm() > 0) normal.normalize();
    const double distance = marker.distance_from_skin / vertices.height;
    const Eigen::Vector3d marker_position = position + distance * normal;
    out.block<1, 3>(l, 0) = marker_position.transpose().cast<float>();
    out.block<1, 3>(l, 3) = normal.transpose().cast<float>();
    out(l, 6) = static_cast<float>(distance);
    out.block(l, 7, 1, num_joints) = weights.transpose().cast<float>();
    out(l, 7 + num_joints + MarkerTypeClass(marker.type)) = 1.0f;
  }
  return out;
}

}  // namespace soma
