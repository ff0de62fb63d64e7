// Per-vertex and per-label descriptors of a body for the layout-conditioned
// labeller (issue #25 item 1, docs/any_layout_design.md): where a marker sits
// on the body, described in the body's own frame so that the description does
// not depend on the vertex numbering of a layout file.
//
// The body frame: origin at the rest pelvis joint (joint 0) of the mean shape,
// axes (left, up, forward) = world (+X, +Z, -Y) (body_model.h: the rest body
// faces -Y with its left side at +X), lengths divided by the rest body height
// (max z - min z of the template).
//
// A label descriptor q_l (one row per marker of a layout, width
// LabelDescriptorWidth(J)):
//   [0, 3)        rest marker position (vertex + skin distance x normal),
//                 body frame / height;
//   [3, 6)        vertex normal in the body frame (unit);
//   [6, 7)        skin distance / height;
//   [7, 7 + J)    the vertex's skinning weights over the J joints;
//   [7 + J, +4)   the marker type one-hot (body, wrist, face, finger).
// A superset marker with several vertex ids gets the mean of its vertices'
// positions, normals (renormalised) and weights.
#pragma once

#include "framework/body/body_model.h"
#include "framework/body/marker_layout.h"

#include <Eigen/Core>

#include <string_view>

namespace soma {

/// Marker-type classes of the one-hot in a label descriptor.
inline constexpr int kNumMarkerTypeClasses = 4;

/// 0 body (and any type not listed), 1 wrist, 2 face, 3 finger (any type
/// starting with "finger": finger, finger_left, finger_right).
int MarkerTypeClass(std::string_view type);

/// Q = 3 + 3 + 1 + num_joints + kNumMarkerTypeClasses.
int LabelDescriptorWidth(int num_joints);

/// Rest position, normal and skinning weights of every vertex of a body, in
/// the body frame (see the file comment). Computed once per body.
struct VertexDescriptors {
  Eigen::Matrix3Xd positions;        // 3 x V, body frame / height
  Eigen::Matrix3Xd normals;          // 3 x V, unit, body frame
  Eigen::MatrixXd skinning_weights;  // J x V, columns sum to 1
  Eigen::Vector3d origin_in_world;   // the rest pelvis joint, metres
  double height = 0;                 // metres

  int num_vertices() const { return static_cast<int>(positions.cols()); }
  int num_joints() const { return static_cast<int>(skinning_weights.rows()); }
};

/// The body-frame rotation: (left, up, forward) = R * world.
Eigen::Matrix3d BodyFromWorldRotation();

/// VertexDescriptors of `body` at its template (mean shape, rest pose).
/// ShapeError on an empty mesh or a body of zero height.
VertexDescriptors ComputeVertexDescriptors(const BodyModel& body);

/// q_l for every marker of `layout` (L x Q, row l = marker l in layout
/// order) with Q = LabelDescriptorWidth(vertices.num_joints()). ConfigError
/// naming the label for a marker without vertices or with a vertex id out of
/// range.
Eigen::MatrixXf LayoutDescriptors(const VertexDescriptors& vertices,
                                  const MarkerLayout& layout);

}  // namespace soma
