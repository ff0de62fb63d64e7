#include "framework/solve/cost_functions.h"

#include "framework/body/marker_layout.h"
#include "framework/core/random.h"
#include "framework/testing/body_fixture.h"

#include <ceres/gradient_checker.h>
#include <gtest/gtest.h>

#include <memory>

namespace soma {
namespace {

using ::soma::testing::ProceduralBody;

constexpr double kRelativePrecision = 1e-6;  // GradientChecker tolerance

struct Fixture {
  MarkerModel model;
  GaussianPosePrior prior;
  Eigen::VectorXd frame;
  Eigen::VectorXd betas;
  Eigen::Matrix3Xd offsets;
};

Fixture MakeFixture() {
  const BodyModel& body = ProceduralBody();
  const MarkerLayout layout = MakeBuiltinLayout(body, "cmu41");
  std::vector<int> vids;
  for (const auto& m : layout.markers) vids.push_back(m.vertex_ids[0]);
  Rng rng(9);
  Eigen::MatrixXd samples(3 * (body.num_joints() - 1), 200);
  for (int i = 0; i < samples.size(); ++i) samples(i) = 0.3 * rng.Normal();
  Fixture f{MarkerModel(body, vids),
            GaussianPosePrior::Fit(samples, 0.2, 0.05),
            Eigen::VectorXd(FrameParamSize(body.num_joints())),
            Eigen::VectorXd(body.num_betas()),
            Eigen::Matrix3Xd(3, vids.size())};
  for (int i = 0; i < f.frame.size(); ++i) f.frame(i) = 0.4 * rng.Normal();
  for (int i = 0; i < f.betas.size(); ++i) f.betas(i) = rng.Normal();
  for (int i = 0; i < f.offsets.size(); ++i) {
    f.offsets.data()[i] = 0.01 * rng.Normal();
  }
  f.model.SetShape(f.betas, f.offsets);
  return f;
}

void ExpectGradientsMatch(const ceres::CostFunction* cost,
                          const std::vector<const double*>& params) {
  ceres::NumericDiffOptions options;
  const std::vector<const ceres::Manifold*>* no_manifolds = nullptr;
  ceres::GradientChecker checker(cost, no_manifolds, options);
  ceres::GradientChecker::ProbeResults results;
  EXPECT_TRUE(checker.Probe(params.data(), kRelativePrecision, &results))
      << results.error_log;
}

TEST(MarkerDataCost, JacobianMatchesFiniteDifferences) {
  Fixture f = MakeFixture();
  const std::vector<int> markers = {0, 4, 9, 22, 40};
  Eigen::Matrix3Xd observed = Eigen::Matrix3Xd::Random(3, markers.size());
  const MarkerDataCost cost(&f.model, markers, observed, 37.0);
  ExpectGradientsMatch(&cost, {f.frame.data()});
}

TEST(ShapeMarkerDataCost, JacobiansMatchFiniteDifferences) {
  Fixture f = MakeFixture();
  const std::vector<int> markers = {1, 7, 30};
  Eigen::Matrix3Xd observed = Eigen::Matrix3Xd::Random(3, markers.size());
  const ShapeMarkerDataCost cost(&f.model, markers, observed, 11.0);
  std::vector<const double*> params = {f.frame.data(), f.betas.data()};
  for (int m : markers) params.push_back(f.offsets.col(m).data());
  ExpectGradientsMatch(&cost, params);
}

TEST(PosePriorCost, JacobianMatchesFiniteDifferencesAndValue) {
  Fixture f = MakeFixture();
  const PosePriorCost cost(&f.prior, static_cast<int>(f.frame.size()), 2.0);
  ExpectGradientsMatch(&cost, {f.frame.data()});
  // |residual|^2 = 4 * Mahalanobis distance of the body pose.
  std::vector<double> residuals(cost.num_residuals());
  const double* p[] = {f.frame.data()};
  ASSERT_TRUE(cost.Evaluate(p, residuals.data(), nullptr));
  const Eigen::VectorXd d = f.frame.tail(f.prior.num_dofs()) - f.prior.mean();
  const Eigen::MatrixXd info =
      f.prior.sqrt_information().transpose() * f.prior.sqrt_information();
  EXPECT_NEAR(Eigen::Map<Eigen::VectorXd>(residuals.data(), residuals.size())
                  .squaredNorm(),
              4.0 * d.dot(info * d),
              1e-8 * d.dot(info * d));
}

TEST(PoseVelocityCost, PullsRotationsOnly) {
  Fixture f = MakeFixture();
  const std::unique_ptr<ceres::CostFunction> cost(
      MakePoseVelocityCost(Eigen::VectorXd::Zero(f.frame.size()), 2.5));
  std::vector<double> residuals(cost->num_residuals());
  const double* p[] = {f.frame.data()};
  ASSERT_TRUE(cost->Evaluate(p, residuals.data(), nullptr));
  ASSERT_EQ(residuals.size(), static_cast<size_t>(f.frame.size() - 3));
  for (size_t i = 0; i < residuals.size(); ++i) {
    EXPECT_DOUBLE_EQ(residuals[i], 2.5 * f.frame(3 + i));
  }
}

}  // namespace
}  // namespace soma
