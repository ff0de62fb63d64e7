#include "framework/body/vertex_descriptors.h"

#include "framework/body/marker_layout.h"
#include "framework/core/error.h"

#include <gtest/gtest.h>

#include "tests/body/body_test_util.h"

namespace soma {
namespace {

using ::soma::testing::ProceduralBody;

constexpr double kTol = 1e-5;  // float32 descriptors of O(1) values

TEST(VertexDescriptors, ShapesAndFrame) {
  const BodyModel& body = ProceduralBody();
  const VertexDescriptors vd = ComputeVertexDescriptors(body);
  EXPECT_EQ(vd.num_vertices(), body.num_vertices());
  EXPECT_EQ(vd.num_joints(), body.num_joints());
  EXPECT_EQ(vd.normals.cols(), body.num_vertices());
  EXPECT_EQ(vd.skinning_weights.cols(), body.num_vertices());
  EXPECT_GT(vd.height, 1.0);
  EXPECT_LT(vd.height, 2.5);
  for (int v = 0; v < vd.num_vertices(); v += 97) {
    EXPECT_NEAR(vd.normals.col(v).norm(), 1.0, kTol) << v;
    EXPECT_NEAR(vd.skinning_weights.col(v).sum(), 1.0, kTol) << v;
  }
  // Body frame: the top of the head is up (+y), the feet below the pelvis.
  Eigen::Index top = 0;
  body.template_vertices.row(2).maxCoeff(&top);
  EXPECT_GT(vd.positions(1, top), 0.2);
  EXPECT_LT(vd.positions.row(1).minCoeff(), -0.3);
  // Left (+x world) stays +x; the body faces -y world = +z body.
  Eigen::Index leftmost = 0;
  body.template_vertices.row(0).maxCoeff(&leftmost);
  EXPECT_GT(vd.positions(0, leftmost), 0.3);
}

TEST(VertexDescriptors, LabelDescriptorMatchesHandComputation) {
  const BodyModel& body = ProceduralBody();
  const VertexDescriptors vd = ComputeVertexDescriptors(body);
  const MarkerLayout layout = MakeBuiltinLayout(body, "cmu41");
  const Eigen::MatrixXf q = LayoutDescriptors(vd, layout);
  const int num_joints = body.num_joints();
  ASSERT_EQ(q.rows(), layout.num_markers());
  ASSERT_EQ(q.cols(), LabelDescriptorWidth(num_joints));
  ASSERT_EQ(q.cols(), 3 + 3 + 1 + num_joints + 4);

  for (const std::string label : {"LFHD", "RWRA"}) {
    const int l = layout.FindLabel(label);
    ASSERT_GE(l, 0) << label;
    const MarkerLayout::Marker& marker = layout.markers[l];
    ASSERT_EQ(marker.vertex_ids.size(), 1u);
    const int v = marker.vertex_ids[0];
    // By hand, from the body: world rest vertex and normal, pelvis origin.
    const Eigen::Matrix3Xd normals =
        VertexNormals(body.template_vertices, body.faces);
    const Eigen::Vector3d pelvis =
        body.RestJoints(body.template_vertices).col(0);
    const double height = body.template_vertices.row(2).maxCoeff() -
                          body.template_vertices.row(2).minCoeff();
    const Eigen::Vector3d world = body.template_vertices.col(v) +
                                  marker.distance_from_skin * normals.col(v);
    const Eigen::Vector3d rel = (world - pelvis) / height;
    // (left, up, forward) = (x, z, -y).
    EXPECT_NEAR(q(l, 0), rel.x(), kTol) << label;
    EXPECT_NEAR(q(l, 1), rel.z(), kTol) << label;
    EXPECT_NEAR(q(l, 2), -rel.y(), kTol) << label;
    EXPECT_NEAR(q(l, 3), normals(0, v), kTol) << label;
    EXPECT_NEAR(q(l, 4), normals(2, v), kTol) << label;
    EXPECT_NEAR(q(l, 5), -normals(1, v), kTol) << label;
    EXPECT_NEAR(q(l, 6), marker.distance_from_skin / height, kTol) << label;
    for (int j = 0; j < num_joints; ++j) {
      EXPECT_NEAR(q(l, 7 + j), body.skinning_weights.coeff(v, j), kTol)
          << label << " joint " << j;
    }
    const int type = label == "RWRA" ? 1 : 0;
    for (int c = 0; c < kNumMarkerTypeClasses; ++c) {
      EXPECT_EQ(q(l, 7 + num_joints + c), c == type ? 1.0f : 0.0f) << label;
    }
  }
}

TEST(VertexDescriptors, SupersetMarkerIsTheMeanOfItsVertices) {
  const BodyModel& body = ProceduralBody();
  const VertexDescriptors vd = ComputeVertexDescriptors(body);
  MarkerLayout one;
  one.markers.push_back({"A", "body", {10}, 0.0});
  one.markers.push_back({"B", "body", {20}, 0.0});
  MarkerLayout both;
  both.markers.push_back({"AB", "body", {10, 20}, 0.0});
  const Eigen::MatrixXf q1 = LayoutDescriptors(vd, one);
  const Eigen::MatrixXf q2 = LayoutDescriptors(vd, both);
  const Eigen::RowVectorXf mean = 0.5f * (q1.row(0) + q1.row(1));
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(q2(0, c), mean(c), kTol);
  for (int c = 7; c < q2.cols(); ++c) EXPECT_NEAR(q2(0, c), mean(c), kTol);
  const float normal_norm = q2.block<1, 3>(0, 3).norm();
  EXPECT_NEAR(normal_norm, 1.0, kTol);
}

TEST(VertexDescriptors, Deterministic) {
  const BodyModel& body = ProceduralBody();
  const MarkerLayout layout = MakeBuiltinLayout(body, "soma53");
  const Eigen::MatrixXf a =
      LayoutDescriptors(ComputeVertexDescriptors(body), layout);
  const Eigen::MatrixXf b =
      LayoutDescriptors(ComputeVertexDescriptors(body), layout);
  EXPECT_EQ(a, b);  // bitwise
}

TEST(VertexDescriptors, MarkerTypeClasses) {
  EXPECT_EQ(MarkerTypeClass("body"), 0);
  EXPECT_EQ(MarkerTypeClass("wrist"), 1);
  EXPECT_EQ(MarkerTypeClass("face"), 2);
  EXPECT_EQ(MarkerTypeClass("finger_left"), 3);
  EXPECT_EQ(MarkerTypeClass("finger"), 3);
  EXPECT_EQ(MarkerTypeClass("something_else"), 0);
}

TEST(VertexDescriptors, VertexOutOfRangeNamesTheLabel) {
  const BodyModel& body = ProceduralBody();
  const VertexDescriptors vd = ComputeVertexDescriptors(body);
  MarkerLayout layout;
  layout.markers.push_back({"LFHD", "body", {body.num_vertices()}, 0.0095});
  try {
    LayoutDescriptors(vd, layout);
    FAIL() << "expected ConfigError";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("LFHD"), std::string::npos)
        << e.what();
  }
  layout.markers[0].vertex_ids.clear();
  EXPECT_THROW(LayoutDescriptors(vd, layout), ConfigError);
}

}  // namespace
}  // namespace soma
