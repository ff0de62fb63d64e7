// Output normalisations: log-domain optimal transport against an independent
// double-precision loop implementation of REFERENCE 1.4, marginals, autograd
// against finite differences, and log-softmax.
#include "framework/model/normalization.h"

#include "framework/core/error.h"

#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <limits>
#include <vector>

namespace soma {
namespace {

/// REFERENCE 1.4 written out with plain loops in double precision.
std::vector<std::vector<double>> ReferenceOptimalTransport(
    const std::vector<std::vector<double>>& scores, double alpha, int iters) {
  const size_t n = scores.size();
  const size_t l = scores[0].size();
  std::vector<std::vector<double>> z(n + 1, std::vector<double>(l + 1, alpha));
  for (size_t i = 0; i < n; ++i) {
    for (size_t j = 0; j < l; ++j) z[i][j] = scores[i][j];
  }
  const double norm = -std::log(static_cast<double>(n + l));
  std::vector<double> log_mu(n + 1, norm), log_nu(l + 1, norm);
  log_mu[n] = std::log(static_cast<double>(l)) + norm;
  log_nu[l] = std::log(static_cast<double>(n)) + norm;
  std::vector<double> u(n + 1, 0.0), v(l + 1, 0.0);
  auto lse = [](const std::vector<double>& values) {
    double m = -std::numeric_limits<double>::infinity();
    for (double x : values) m = std::max(m, x);
    double s = 0;
    for (double x : values) s += std::exp(x - m);
    return m + std::log(s);
  };
  for (int it = 0; it < iters; ++it) {
    for (size_t i = 0; i <= n; ++i) {
      std::vector<double> row(l + 1);
      for (size_t j = 0; j <= l; ++j) row[j] = z[i][j] + v[j];
      u[i] = log_mu[i] - lse(row);
    }
    for (size_t j = 0; j <= l; ++j) {
      std::vector<double> col(n + 1);
      for (size_t i = 0; i <= n; ++i) col[i] = z[i][j] + u[i];
      v[j] = log_nu[j] - lse(col);
    }
  }
  std::vector<std::vector<double>> p(n + 1, std::vector<double>(l + 1));
  for (size_t i = 0; i <= n; ++i) {
    for (size_t j = 0; j <= l; ++j) p[i][j] = z[i][j] + u[i] + v[j] - norm;
  }
  return p;
}

TEST(Sinkhorn, MatchesIndependentLoopImplementation) {
  torch::manual_seed(21);
  const int64_t batch = 3, n = 7, l = 5;
  const torch::Tensor scores =
      torch::randn({batch, n, l}, torch::kDouble) * 2.0;
  for (int iters : {0, 1, 35}) {
    const torch::Tensor p =
        LogOptimalTransport(scores, torch::tensor(0.8, torch::kDouble), iters);
    ASSERT_EQ(p.sizes(), (std::vector<int64_t>{batch, n + 1, l + 1}));
    const torch::Tensor p_float = LogOptimalTransport(
        scores.to(torch::kFloat), torch::tensor(0.8f), iters);
    for (int64_t b = 0; b < batch; ++b) {
      std::vector<std::vector<double>> s(n, std::vector<double>(l));
      for (int64_t i = 0; i < n; ++i) {
        for (int64_t j = 0; j < l; ++j)
          s[i][j] = scores[b][i][j].item<double>();
      }
      const auto expected = ReferenceOptimalTransport(s, 0.8, iters);
      for (int64_t i = 0; i <= n; ++i) {
        for (int64_t j = 0; j <= l; ++j) {
          EXPECT_NEAR(p[b][i][j].item<double>(), expected[i][j], 1e-10);
          EXPECT_NEAR(p_float[b][i][j].item<float>(), expected[i][j], 2e-5);
        }
      }
    }
  }
}

TEST(Sinkhorn, MarginalsAtConvergence) {
  torch::manual_seed(22);
  const int64_t n = 9, l = 6;
  const torch::Tensor scores = torch::randn({2, n, l}, torch::kDouble);
  const torch::Tensor plan =
      LogOptimalTransport(scores, torch::tensor(1.0, torch::kDouble), 500)
          .exp();
  // Point rows are distributions over the L+1 columns; the dustbin row holds
  // mass L (it can absorb every label), the dustbin column mass N.
  EXPECT_TRUE(torch::allclose(plan.narrow(1, 0, n).sum(2),
                              torch::ones({2, n}, torch::kDouble),
                              0,
                              1e-9));
  EXPECT_NEAR(
      plan.select(1, n).sum(1)[0].item<double>(), static_cast<double>(l), 1e-9);
  // Every label column carries mass 1; the dustbin column N (exact after the
  // final column update).
  EXPECT_TRUE(torch::allclose(plan.narrow(2, 0, l).sum(1),
                              torch::ones({2, l}, torch::kDouble),
                              0,
                              1e-12));
  EXPECT_NEAR(plan.select(2, l).sum(1)[1].item<double>(),
              static_cast<double>(n),
              1e-12);
  // At the paper's 35 iterations rows are already close to distributions.
  const torch::Tensor plan35 =
      LogOptimalTransport(scores, torch::tensor(1.0, torch::kDouble), 35).exp();
  EXPECT_TRUE(torch::allclose(plan35.narrow(1, 0, n).sum(2),
                              torch::ones({2, n}, torch::kDouble),
                              0,
                              1e-3));
}

TEST(Sinkhorn, AutogradMatchesFiniteDifferences) {
  torch::manual_seed(23);
  const int64_t n = 4, l = 3;
  const torch::Tensor scores =
      torch::randn({1, n, l}, torch::kDouble).requires_grad_(true);
  const torch::Tensor alpha =
      torch::tensor(0.6, torch::kDouble).requires_grad_(true);
  const torch::Tensor weights = torch::randn({1, n + 1, l + 1}, torch::kDouble);
  auto objective = [&](const torch::Tensor& s, const torch::Tensor& a) {
    return (LogOptimalTransport(s, a, 12) * weights).sum();
  };
  objective(scores, alpha).backward();
  const double h = 1e-6;
  torch::NoGradGuard no_grad;
  for (int64_t i = 0; i < n; ++i) {
    for (int64_t j = 0; j < l; ++j) {
      torch::Tensor plus = scores.detach().clone(),
                    minus = scores.detach().clone();
      plus[0][i][j] += h;
      minus[0][i][j] -= h;
      const double fd = (objective(plus, alpha).item<double>() -
                         objective(minus, alpha).item<double>()) /
                        (2 * h);
      EXPECT_NEAR(scores.grad()[0][i][j].item<double>(), fd, 1e-6)
          << i << "," << j;
    }
  }
  const double fd_alpha = (objective(scores, alpha + h).item<double>() -
                           objective(scores, alpha - h).item<double>()) /
                          (2 * h);
  EXPECT_NEAR(alpha.grad().item<double>(), fd_alpha, 1e-6);
}

TEST(Sinkhorn, ModuleHasLearnableBinScore) {
  Sinkhorn sinkhorn(SinkhornOptions{7, 1.0});
  EXPECT_EQ(sinkhorn->NumScoreColumns(41), 41);
  EXPECT_TRUE(sinkhorn->HasDustbinRow());
  ASSERT_EQ(sinkhorn->parameters().size(), 1u);
  EXPECT_TRUE(sinkhorn->bin_score.requires_grad());
  const torch::Tensor p = sinkhorn(torch::randn({2, 5, 4}));
  EXPECT_EQ(p.sizes(), (std::vector<int64_t>{2, 6, 5}));
  p.sum().backward();
  EXPECT_TRUE(sinkhorn->bin_score.grad().defined());
  EXPECT_THROW(Sinkhorn(SinkhornOptions{-1, 1.0}), ConfigError);
  EXPECT_THROW(
      LogOptimalTransport(torch::randn({5, 4}), torch::tensor(1.0f), 3),
      ShapeError);
}

TEST(LogSoftmax, RowsAreLogDistributionsWithNullColumn) {
  LogSoftmax norm;
  EXPECT_EQ(norm->NumScoreColumns(41), 42);
  EXPECT_FALSE(norm->HasDustbinRow());
  EXPECT_TRUE(norm->parameters().empty());
  const torch::Tensor scores = torch::randn({2, 5, 4});
  const torch::Tensor p = norm(scores);
  EXPECT_TRUE(
      torch::allclose(p.exp().sum(-1), torch::ones({2, 5}), 1e-6, 1e-6));
  EXPECT_TRUE(torch::allclose(p, torch::log_softmax(scores, -1)));
}

}  // namespace
}  // namespace soma
