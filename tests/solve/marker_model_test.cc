#include "framework/solve/marker_model.h"

#include "framework/body/marker_layout.h"
#include "framework/core/error.h"
#include "framework/core/random.h"
#include "framework/testing/body_fixture.h"

#include <gtest/gtest.h>

namespace soma {
namespace {

using ::soma::testing::ProceduralBody;

constexpr double kFdStep = 1e-6;
constexpr double kJacobianTol = 1e-6;  // absolute, metres per unit
constexpr double kPositionTol = 1e-9;  // metres

std::vector<int> LayoutVertices(const MarkerLayout& layout) {
  std::vector<int> ids;
  for (const auto& m : layout.markers) ids.push_back(m.vertex_ids[0]);
  return ids;
}

Eigen::VectorXd RandomFrame(Rng* rng, int num_joints, double scale) {
  Eigen::VectorXd frame(FrameParamSize(num_joints));
  for (int i = 0; i < frame.size(); ++i) frame(i) = scale * rng->Normal();
  return frame;
}

TEST(MarkerModel, ZeroOffsetRestPoseGivesVertices) {
  const BodyModel& body = ProceduralBody();
  const MarkerLayout layout = MakeBuiltinLayout(body, "cmu41");
  const MarkerModel model(body, LayoutVertices(layout));
  Eigen::VectorXd frame = Eigen::VectorXd::Zero(model.frame_size());
  Eigen::Matrix3Xd positions;
  model.Evaluate(frame.data(), {}, &positions, nullptr);
  for (int m = 0; m < model.num_markers(); ++m) {
    EXPECT_LT(
        (positions.col(m) - body.template_vertices.col(model.vertex_ids()[m]))
            .norm(),
        kPositionTol);
  }
}

TEST(MarkerModel, MatchesFullLinearBlendSkinning) {
  const BodyModel& body = ProceduralBody();
  const MarkerLayout layout = MakeBuiltinLayout(body, "cmu41");
  MarkerModel model(body, LayoutVertices(layout));
  Rng rng(3);
  Eigen::VectorXd betas(body.num_betas());
  for (int b = 0; b < betas.size(); ++b) betas(b) = rng.Normal();
  model.SetShape(betas, Eigen::Matrix3Xd::Zero(3, model.num_markers()));
  const Eigen::VectorXd frame = RandomFrame(&rng, model.num_joints(), 0.4);
  Eigen::Matrix3Xd positions;
  model.Evaluate(frame.data(), {}, &positions, nullptr);
  const Eigen::Matrix3Xd posed = PoseVertices(
      body, betas, UnpackFrameParams(frame.data(), model.num_joints()));
  for (int m = 0; m < model.num_markers(); ++m) {
    // Truncation to 4 influences only differs where a vertex has more.
    EXPECT_LT((positions.col(m) - posed.col(model.vertex_ids()[m])).norm(),
              1e-3)
        << layout.markers[m].label;
  }
}

TEST(MarkerModel, LeftJacobianMatchesFiniteDifferences) {
  Rng rng(5);
  for (double scale : {0.0, 1e-5, 0.7, 2.5}) {
    const Eigen::Vector3d w =
        scale * Eigen::Vector3d(rng.Normal(), rng.Normal(), rng.Normal());
    const auto rot = [](const Eigen::Vector3d& v) {
      const double a = v.norm();
      return a < 1e-15 ? Eigen::Matrix3d::Identity().eval()
                       : Eigen::AngleAxisd(a, v / a).toRotationMatrix();
    };
    const Eigen::Matrix3d jl = LeftJacobianSO3(w);
    for (int c = 0; c < 3; ++c) {
      Eigen::Vector3d d = Eigen::Vector3d::Zero();
      d(c) = kFdStep;
      // exp(w + d) exp(w)^T ~ exp(J_l d): the skew part gives J_l d.
      const Eigen::Matrix3d delta =
          (rot(w + d) - rot(w - d)) * rot(w).transpose() / (2 * kFdStep);
      const Eigen::Vector3d omega(delta(2, 1), delta(0, 2), delta(1, 0));
      EXPECT_LT((omega - jl.col(c)).norm(), 1e-6) << "scale " << scale;
    }
  }
}

TEST(MarkerModel, AnalyticJacobiansMatchFiniteDifferences) {
  const BodyModel& body = ProceduralBody();
  const MarkerLayout layout = MakeBuiltinLayout(body, "cmu41");
  const MarkerModel model(body, LayoutVertices(layout));
  Rng rng(7);
  const int nb = model.num_betas();
  const int nm = model.num_markers();
  const int nf = model.frame_size();
  Eigen::VectorXd frame = RandomFrame(&rng, model.num_joints(), 0.5);
  Eigen::VectorXd betas(nb), offsets(3 * nm);
  for (int b = 0; b < nb; ++b) betas(b) = rng.Normal();
  for (int i = 0; i < 3 * nm; ++i) offsets(i) = 0.01 * rng.Normal();
  const std::vector<int> subset = {0, 5, 17, 40, 3};
  const int rows = 3 * static_cast<int>(subset.size());
  RowMajorMatrix jf(rows, nf), jb(rows, nb), jo(rows, 3);
  Eigen::Matrix3Xd p0;
  model.EvaluateWithShape(frame.data(),
                          betas.data(),
                          offsets.data(),
                          subset,
                          &p0,
                          jf.data(),
                          jb.data(),
                          jo.data());
  const auto eval = [&](const Eigen::VectorXd& f,
                        const Eigen::VectorXd& b,
                        const Eigen::VectorXd& o) {
    Eigen::Matrix3Xd p;
    model.EvaluateWithShape(
        f.data(), b.data(), o.data(), subset, &p, nullptr, nullptr, nullptr);
    return Eigen::Map<const Eigen::VectorXd>(p.data(), p.size()).eval();
  };
  const auto check =
      [&](const RowMajorMatrix& jac, Eigen::VectorXd* var, const char* what) {
        for (int c = 0; c < var->size(); ++c) {
          const double keep = (*var)(c);
          (*var)(c) = keep + kFdStep;
          const Eigen::VectorXd plus = eval(frame, betas, offsets);
          (*var)(c) = keep - kFdStep;
          const Eigen::VectorXd minus = eval(frame, betas, offsets);
          (*var)(c) = keep;
          const Eigen::VectorXd fd = (plus - minus) / (2 * kFdStep);
          EXPECT_LT((fd - jac.col(c)).cwiseAbs().maxCoeff(), kJacobianTol)
              << what << " column " << c;
        }
      };
  check(jf, &frame, "frame");
  check(jb, &betas, "betas");
  // Offsets: marker subset[i] depends only on its own offset, through the
  // 3 x 3 block in rows 3i..3i+2 of `jo`.
  RowMajorMatrix jo_full = RowMajorMatrix::Zero(rows, 3 * nm);
  for (size_t i = 0; i < subset.size(); ++i) {
    jo_full.block<3, 3>(3 * i, 3 * subset[i]) = jo.middleRows<3>(3 * i);
  }
  check(jo_full, &offsets, "offsets");

  // The pose-only path agrees with the full one.
  MarkerModel fixed = model;
  fixed.SetShape(betas,
                 Eigen::Map<const Eigen::Matrix3Xd>(offsets.data(), 3, nm));
  RowMajorMatrix jf2(rows, nf);
  Eigen::Matrix3Xd p1;
  fixed.Evaluate(frame.data(), subset, &p1, jf2.data());
  EXPECT_LT((p1 - p0).cwiseAbs().maxCoeff(), kPositionTol);
  EXPECT_LT((jf2 - jf).cwiseAbs().maxCoeff(), 1e-12);
}

TEST(MarkerModel, RejectsVertexOutsideBody) {
  const BodyModel& body = ProceduralBody();
  EXPECT_THROW(MarkerModel(body, {0, body.num_vertices()}), ShapeError);
  EXPECT_THROW(MarkerModel(body, {-1}), ShapeError);
  EXPECT_THROW(MarkerModel(body, {}), Error);
}

}  // namespace
}  // namespace soma
