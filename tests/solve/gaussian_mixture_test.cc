#include "framework/solve/gaussian_mixture.h"

#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/core/random.h"
#include "framework/io/hdf5_util.h"
#include "framework/registry/registry.h"
#include "framework/solve/pose_prior.h"
#include "framework/testing/body_fixture.h"
#include "framework/testing/testing.h"

#include <Eigen/Cholesky>
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

namespace soma {
namespace {

/// A known 2-D mixture: weights 0.3 / 0.7, well separated, correlated.
GaussianMixture TwoBlobs() {
  GaussianMixture g;
  g.weights = Eigen::Vector2d(0.3, 0.7);
  g.means = {Eigen::Vector2d(-2.0, 0.0), Eigen::Vector2d(2.0, 1.0)};
  Eigen::Matrix2d a;
  a << 0.20, 0.08, 0.08, 0.10;
  Eigen::Matrix2d b;
  b << 0.05, -0.02, -0.02, 0.30;
  g.covariances = {a, b};
  return g;
}

Eigen::MatrixXd Sample(const GaussianMixture& g, int n, uint64_t seed) {
  Rng rng(seed);
  Eigen::MatrixXd x(g.dim(), n);
  for (int i = 0; i < n; ++i) {
    const int k = rng.Uniform() < g.weights[0] ? 0 : 1;
    const Eigen::MatrixXd l = g.covariances[k].llt().matrixL();
    Eigen::VectorXd z(g.dim());
    for (int d = 0; d < g.dim(); ++d) z[d] = rng.Normal();
    x.col(i) = g.means[k] + l * z;
  }
  return x;
}

TEST(GaussianMixture, EmRecoversAKnownMixture) {
  const GaussianMixture truth = TwoBlobs();
  const Eigen::MatrixXd x = Sample(truth, 4000, 1);
  GmmFitOptions options;
  options.components = 2;
  options.min_stddev = 1e-3;
  GmmFitReport report;
  const GaussianMixture fit = FitGaussianMixture(x, options, &report);
  EXPECT_TRUE(report.converged);
  // Components come back in either order.
  const int a = fit.means[0][0] < 0 ? 0 : 1;
  const int b = 1 - a;
  EXPECT_NEAR(fit.weights[a], 0.3, 0.03);
  EXPECT_NEAR(fit.weights[b], 0.7, 0.03);
  EXPECT_LT((fit.means[a] - truth.means[0]).norm(), 0.05);
  EXPECT_LT((fit.means[b] - truth.means[1]).norm(), 0.05);
  EXPECT_LT((fit.covariances[a] - truth.covariances[0]).norm(), 0.03);
  EXPECT_LT((fit.covariances[b] - truth.covariances[1]).norm(), 0.03);
  // The fitted mixture explains its samples about as well as the truth.
  EXPECT_NEAR(report.mean_log_likelihood, truth.LogDensity(x).mean(), 0.02);

  // Deterministic for a seed.
  const GaussianMixture again = FitGaussianMixture(x, options);
  EXPECT_EQ(again.means[0], fit.means[0]);
  EXPECT_EQ(again.covariances[1], fit.covariances[1]);
}

TEST(GaussianMixture, MoreComponentsExplainBimodalDataBetter) {
  const Eigen::MatrixXd x = Sample(TwoBlobs(), 2000, 2);
  GmmFitOptions one;
  one.components = 1;
  GmmFitOptions two;
  two.components = 2;
  GmmFitReport r1;
  GmmFitReport r2;
  FitGaussianMixture(x, one, &r1);
  FitGaussianMixture(x, two, &r2);
  EXPECT_GT(r2.mean_log_likelihood, r1.mean_log_likelihood + 0.5);
}

TEST(GaussianMixture, LogDensityOfOneComponentIsTheGaussianDensity) {
  GaussianMixture g;
  g.weights = Eigen::VectorXd::Ones(1);
  g.means = {Eigen::Vector3d(0.1, -0.2, 0.3)};
  Eigen::Matrix3d cov;
  cov << 0.5, 0.1, 0.0, 0.1, 0.4, 0.05, 0.0, 0.05, 0.3;
  g.covariances = {cov};
  const Eigen::Vector3d x(0.4, 0.1, -0.2);
  const Eigen::Vector3d e = x - g.means[0];
  const double expected = -0.5 * e.dot(cov.inverse() * e) -
                          0.5 * std::log(cov.determinant()) -
                          1.5 * std::log(2.0 * std::numbers::pi);
  EXPECT_NEAR(g.LogDensity(x)[0], expected, 1e-12);
  EXPECT_THROW(g.LogDensity(Eigen::Vector2d(0, 0)), ShapeError);
}

TEST(GaussianMixture, ValidateRejectsBadMixtures) {
  GaussianMixture g = TwoBlobs();
  EXPECT_NO_THROW(g.Validate());
  g.weights = Eigen::Vector2d(0.5, 0.6);
  EXPECT_THROW(g.Validate(), ShapeError);
  g = TwoBlobs();
  g.covariances[1](0, 0) = -1.0;  // not positive definite
  EXPECT_THROW(g.Validate(), ShapeError);
  g = TwoBlobs();
  g.means[0] = Eigen::Vector3d::Zero();
  EXPECT_THROW(g.Validate(), ShapeError);
  GmmFitOptions options;
  options.components = 3;
  EXPECT_THROW(FitGaussianMixture(Eigen::MatrixXd::Zero(2, 2), options),
               ShapeError);
  options.min_stddev = 0.0;
  EXPECT_THROW(FitGaussianMixture(Sample(TwoBlobs(), 10, 3), options),
               ConfigError);
}

TEST(GaussianMixture, Hdf5RoundTripAndBadFiles) {
  GaussianMixture g = TwoBlobs();
  g.metadata["body"] = {"procedural"};
  g.metadata["joint_names"] = {"pelvis", "spine"};
  const auto dir = soma::testing::CreateTestDir();
  const auto path = dir / "prior.h5";
  WriteGaussianMixture(path, g);
  const GaussianMixture back = ReadGaussianMixture(path);
  EXPECT_EQ(back.weights, g.weights);
  EXPECT_EQ(back.means[1], g.means[1]);
  EXPECT_EQ(back.covariances[0], g.covariances[0]);
  EXPECT_EQ(back.metadata, g.metadata);

  EXPECT_THROW(ReadGaussianMixture(dir / "absent.h5"), IoError);
  {
    // A file with the wrong format attribute.
    std::lock_guard lock(hdf5::Hdf5Mutex());
    hdf5::Hid file = hdf5::Check(
        H5Fopen(path.c_str(), H5F_ACC_RDWR, H5P_DEFAULT), H5Fclose, "open");
    hdf5::WriteStringAttribute(file.get(), "format", "soma-solve", "test");
  }
  try {
    ReadGaussianMixture(path);
    FAIL() << "expected an IoError";
  } catch (const IoError& e) {
    EXPECT_NE(std::string(e.what()).find("soma-solve"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find(path.string()), std::string::npos);
  }
}

// ---- The max-mixture pose prior.

GaussianMixture RandomMixture(int dofs, int components, uint64_t seed) {
  Rng rng(seed);
  GaussianMixture g;
  g.weights.resize(components);
  for (int k = 0; k < components; ++k) {
    g.weights[k] = 0.5 + rng.Uniform();
    Eigen::VectorXd mean(dofs);
    Eigen::MatrixXd a(dofs, dofs);
    for (int i = 0; i < dofs; ++i) mean[i] = 0.5 * rng.Normal();
    for (int i = 0; i < a.size(); ++i) a(i) = 0.2 * rng.Normal();
    g.means.push_back(mean);
    g.covariances.push_back(a * a.transpose() +
                            0.05 * Eigen::MatrixXd::Identity(dofs, dofs));
  }
  g.weights /= g.weights.sum();
  return g;
}

TEST(GmmPosePrior, ResidualIsTheBestComponentsNegativeLogDensity) {
  const int dofs = 6;
  const GaussianMixture g = RandomMixture(dofs, 4, 5);
  const GmmPosePrior prior(g);
  ASSERT_EQ(prior.num_residuals(), dofs + 1);
  // c_k(x) = e^T Sigma^-1 e + 2 (-log w + 1/2 log det Sigma).
  const auto cost = [&](int k, const Eigen::VectorXd& x) {
    const Eigen::VectorXd e = x - g.means[k];
    return e.dot(g.covariances[k].inverse() * e) +
           2.0 * (-std::log(g.weights[k]) +
                  0.5 * std::log(g.covariances[k].determinant()));
  };
  double c0_min = std::numeric_limits<double>::infinity();
  for (int k = 0; k < 4; ++k) c0_min = std::min(c0_min, cost(k, g.means[k]));
  Rng rng(6);
  for (int trial = 0; trial < 20; ++trial) {
    Eigen::VectorXd x(dofs);
    for (int i = 0; i < dofs; ++i) x[i] = rng.Normal();
    double best = std::numeric_limits<double>::infinity();
    int best_k = -1;
    for (int k = 0; k < 4; ++k) {
      if (cost(k, x) < best) {
        best = cost(k, x);
        best_k = k;
      }
    }
    Eigen::VectorXd r(dofs + 1);
    prior.Evaluate(x.data(), r.data(), nullptr);
    EXPECT_EQ(prior.BestComponent(x.data()), best_k);
    EXPECT_NEAR(r.squaredNorm(), best - c0_min, 1e-8 * (1 + std::abs(best)));
  }
}

TEST(GmmPosePrior, JacobianMatchesFiniteDifferences) {
  const int dofs = 9;
  const GmmPosePrior prior(RandomMixture(dofs, 3, 7));
  Rng rng(8);
  for (int trial = 0; trial < 10; ++trial) {
    Eigen::VectorXd x(dofs);
    for (int i = 0; i < dofs; ++i) x[i] = 0.7 * rng.Normal();
    Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> j(
        dofs + 1, dofs);
    Eigen::VectorXd r(dofs + 1);
    prior.Evaluate(x.data(), r.data(), j.data());
    const double h = 1e-6;
    for (int i = 0; i < dofs; ++i) {
      Eigen::VectorXd xp = x;
      Eigen::VectorXd xm = x;
      xp[i] += h;
      xm[i] -= h;
      // Central differences are exact for a linear residual as long as both
      // points stay in the same component's region.
      if (prior.BestComponent(xp.data()) != prior.BestComponent(x.data()) ||
          prior.BestComponent(xm.data()) != prior.BestComponent(x.data())) {
        continue;
      }
      Eigen::VectorXd rp(dofs + 1);
      Eigen::VectorXd rm(dofs + 1);
      prior.Evaluate(xp.data(), rp.data(), nullptr);
      prior.Evaluate(xm.data(), rm.data(), nullptr);
      const Eigen::VectorXd numeric = (rp - rm) / (2 * h);
      EXPECT_LT((numeric - j.col(i)).norm(), 1e-6 * (1 + numeric.norm()))
          << "dof " << i;
    }
  }
}

TEST(GmmPosePrior, OneComponentEqualsTheGaussianPrior) {
  GaussianMixture g = RandomMixture(6, 1, 9);
  const GmmPosePrior gmm(g);
  const Eigen::MatrixXd info = g.covariances[0].inverse();
  const GaussianPosePrior gaussian(
      g.means[0], Eigen::MatrixXd(info.llt().matrixL().transpose()));
  const Eigen::VectorXd x = Eigen::VectorXd::LinSpaced(6, -0.5, 0.5);
  Eigen::VectorXd a(7);
  Eigen::VectorXd b(6);
  gmm.Evaluate(x.data(), a.data(), nullptr);
  gaussian.Evaluate(x.data(), b.data(), nullptr);
  EXPECT_LT((a.head(6) - b).norm(), 1e-10);
  EXPECT_EQ(a[6], 0.0);
}

TEST(GmmPosePrior, RegisteredSourceChecksTheBodyItWasFittedFor) {
  const BodyModel& body = soma::testing::ProceduralBody();
  const int dofs = 3 * (body.num_joints() - 1);
  GaussianMixture g = RandomMixture(dofs, 2, 10);
  g.metadata["body"] = {"other"};
  g.metadata["joint_names"] = {"a", "b"};
  const auto path = soma::testing::CreateTestDir() / "gmm.h5";
  WriteGaussianMixture(path, g);
  const ConfigNode node =
      ParseYaml("name: gmm\npath: " + path.string() + "\n", "test");
  BuildContext ctx;
  const std::unique_ptr<PosePriorSource> source =
      Instantiate<PosePriorSource>(node, ctx);
  try {
    source->Make(body);
    FAIL() << "a GMM fitted for other joints must be rejected";
  } catch (const ShapeError& e) {
    EXPECT_NE(std::string(e.what()).find("other"), std::string::npos);
  }
  g.metadata["joint_names"] = body.joint_names;
  WriteGaussianMixture(path, g);
  const std::unique_ptr<PosePrior> prior = source->Make(body);
  ASSERT_NE(prior, nullptr);
  EXPECT_EQ(prior->num_dofs(), dofs);
  EXPECT_EQ(prior->num_residuals(), dofs + 1);
}

}  // namespace
}  // namespace soma
