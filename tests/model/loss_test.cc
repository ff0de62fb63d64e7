// The labelling loss: G' and W on hand-made frames (REFERENCE 2.1-2.2), the
// loss value (Eq. 6, REFERENCE 2.3) and its gradient against finite
// differences through the Sinkhorn layer.
#include "framework/model/loss.h"

#include "framework/config/node.h"
#include "framework/core/error.h"
#include "framework/model/normalization.h"
#include "framework/registry/registry.h"

#include <gtest/gtest.h>
#include <torch/torch.h>

#include <vector>

namespace soma {
namespace {

constexpr double kTol = 1e-6;

TEST(AugmentedTargets, HandMadeFrame) {
  // L = 4 labels, N = 5 points: labels 2, null, 0, null, 1; label 3 missing.
  const int64_t l = 4;
  const torch::Tensor ids =
      torch::tensor({2, 4, 0, 4, 1}, torch::kLong).view({1, 5});
  const AugmentedTargets t = BuildAugmentedTargets(ids, l);
  const torch::Tensor expected_g = torch::tensor({0, 0, 1, 0, 0,  //
                                                  0, 0, 0, 0, 1,  //
                                                  1, 0, 0, 0, 0,  //
                                                  0, 0, 0, 0, 1,  //
                                                  0, 1, 0, 0, 0,  //
                                                  0, 0, 0, 1, 4},
                                                 torch::kFloat)
                                       .view({1, 6, 5});
  EXPECT_TRUE(torch::equal(t.assignment, expected_g));
  // Label columns sum to 1; total N + L + 1; corner L + 1 - #unavailable.
  EXPECT_TRUE(
      torch::equal(t.assignment.narrow(2, 0, l).sum(1), torch::ones({1, l})));
  EXPECT_EQ(t.assignment.sum().item<float>(), 5 + 4 + 1);
  EXPECT_EQ(t.assignment[0][5][4].item<float>(), 4 + 1 - 1);
  // Two null points: null rows and the dustbin row weigh 1/2.
  const torch::Tensor row_weight =
      torch::tensor({1.0, 0.5, 1.0, 0.5, 1.0, 0.5}, torch::kFloat);
  EXPECT_TRUE(
      torch::equal(t.weights, row_weight.view({1, 6, 1}).expand({1, 6, 5})));
}

TEST(AugmentedTargets, NoNullPointsAndAvailabilityMask) {
  // Frame 0: all 3 labels present, no null point -> null weight 1, corner 4.
  // Frame 1: labels 0 and 2 present, one ghost; label 1 unavailable.
  const int64_t l = 3;
  const torch::Tensor ids =
      torch::tensor({1, 0, 2, 3, 2, 0}, torch::kLong).view({2, 3});
  const torch::Tensor available =
      torch::tensor({true, true, true, true, false, true}).view({2, 3});
  const AugmentedTargets t = BuildAugmentedTargets(ids, l, available);
  EXPECT_TRUE(torch::equal(t.weights[0], torch::ones({4, 4})));
  EXPECT_TRUE(
      torch::equal(t.assignment[0][3], torch::tensor({0.f, 0.f, 0.f, 4.f})));
  EXPECT_TRUE(
      torch::equal(t.assignment[1][3], torch::tensor({0.f, 1.f, 0.f, 3.f})));
  EXPECT_EQ(t.assignment[1].sum().item<float>(), 3 + 3 + 1);
  EXPECT_TRUE(torch::equal(t.weights[1].select(1, 0),
                           torch::ones({4})));  // 1 null: 1/1
  // Inconsistent availability, duplicate real labels and bad ids are errors.
  const torch::Tensor wrong = torch::ones({2, 3}, torch::kBool);
  EXPECT_THROW(BuildAugmentedTargets(ids, l, wrong), InternalError);
  EXPECT_THROW(BuildAugmentedTargets(torch::tensor({1, 1, 3}).view({1, 3}), l),
               InternalError);
  EXPECT_THROW(BuildAugmentedTargets(torch::tensor({5, 0, 1}).view({1, 3}), l),
               InternalError);
  EXPECT_THROW(BuildAugmentedTargets(torch::tensor({0, 1}), l), ShapeError);
  EXPECT_THROW(BuildAugmentedTargets(ids, l, torch::ones({2, 4}, torch::kBool)),
               ShapeError);
}

TEST(LabelingLoss, OptimalTransportValue) {
  torch::manual_seed(31);
  const int64_t l = 3, n = 4;
  const torch::Tensor ids =
      torch::tensor({0, 3, 2, 3, 1, 3, 3, 0}, torch::kLong).view({2, n});
  const AugmentedTargets t = BuildAugmentedTargets(ids, l);
  const torch::Tensor p = torch::randn({2, n + 1, l + 1}, torch::kDouble);
  double expected = 0;
  for (int64_t b = 0; b < 2; ++b) {
    double num = 0, den = 0;
    for (int64_t i = 0; i <= n; ++i) {
      for (int64_t j = 0; j <= l; ++j) {
        const double g = t.assignment[b][i][j].item<double>();
        num +=
            g * t.weights[b][i][j].item<double>() * p[b][i][j].item<double>();
        den += g;
      }
    }
    EXPECT_DOUBLE_EQ(den, n + l + 1);
    expected += -num / den;  // summed over the batch
  }
  EXPECT_NEAR(ComputeLabelingLoss(p, t).item<double>(), expected, 1e-12);
}

TEST(LabelingLoss, LogSoftmaxQuirkUsesProbabilitiesOnPointRows) {
  torch::manual_seed(32);
  const int64_t l = 3, n = 4;
  const torch::Tensor ids =
      torch::tensor({0, 3, 2, 3}, torch::kLong).view({1, n});
  const AugmentedTargets t = BuildAugmentedTargets(ids, l);
  const torch::Tensor p =
      torch::log_softmax(torch::randn({1, n, l + 1}, torch::kDouble), -1);
  // Point rows: labels 0 and 2 weight 1, the two nulls weight 1/2; sum G = N.
  const double quirk = -(p[0][0][0].exp() + p[0][2][2].exp() +
                         0.5 * p[0][1][3].exp() + 0.5 * p[0][3][3].exp())
                            .item<double>() /
                       n;
  const double nll =
      -(p[0][0][0] + p[0][2][2] + 0.5 * p[0][1][3] + 0.5 * p[0][3][3])
           .item<double>() /
      n;
  EXPECT_NEAR(
      ComputeLabelingLoss(p, t).item<double>(), quirk, 1e-12);  // default
  LabelingLossOptions proper;
  proper.quirk_probability_loss = false;
  EXPECT_NEAR(ComputeLabelingLoss(p, t, proper).item<double>(), nll, 1e-12);
  EXPECT_THROW(ComputeLabelingLoss(torch::zeros({1, n - 1, l + 1}), t),
               ShapeError);
  EXPECT_THROW(ComputeLabelingLoss(torch::zeros({1, n + 1, l}), t), ShapeError);
}

TEST(LabelingLoss, GradientThroughSinkhornMatchesFiniteDifferences) {
  torch::manual_seed(33);
  const int64_t l = 4, n = 6;
  const torch::Tensor ids =
      torch::tensor({1, 4, 0, 3, 4, 4}, torch::kLong).view({1, n});
  const AugmentedTargets t = BuildAugmentedTargets(ids, l);
  const torch::Tensor scores =
      torch::randn({1, n, l}, torch::kDouble).requires_grad_(true);
  const torch::Tensor alpha = torch::tensor(1.0, torch::kDouble);
  auto loss = [&](const torch::Tensor& s) {
    return ComputeLabelingLoss(LogOptimalTransport(s, alpha, 35), t);
  };
  loss(scores).backward();
  const double h = 1e-6;
  torch::NoGradGuard no_grad;
  for (int64_t i = 0; i < n; ++i) {
    for (int64_t j = 0; j < l; ++j) {
      torch::Tensor plus = scores.detach().clone(),
                    minus = scores.detach().clone();
      plus[0][i][j] += h;
      minus[0][i][j] -= h;
      const double fd =
          (loss(plus).item<double>() - loss(minus).item<double>()) / (2 * h);
      EXPECT_NEAR(scores.grad()[0][i][j].item<double>(), fd, kTol)
          << i << "," << j;
    }
  }
}

TEST(LabelingLoss, GradientOfLogSoftmaxVariantsMatchesFiniteDifferences) {
  torch::manual_seed(34);
  const int64_t l = 3, n = 5;
  const torch::Tensor ids =
      torch::tensor({1, 3, 0, 3, 2}, torch::kLong).view({1, n});
  const AugmentedTargets t = BuildAugmentedTargets(ids, l);
  for (bool quirk : {true, false}) {
    LabelingLossOptions options;
    options.quirk_probability_loss = quirk;
    torch::Tensor scores =
        torch::randn({1, n, l + 1}, torch::kDouble).requires_grad_(true);
    auto loss = [&](const torch::Tensor& s) {
      return ComputeLabelingLoss(torch::log_softmax(s, -1), t, options);
    };
    loss(scores).backward();
    const double h = 1e-6;
    torch::NoGradGuard no_grad;
    for (int64_t i = 0; i < n; ++i) {
      for (int64_t j = 0; j <= l; ++j) {
        torch::Tensor plus = scores.detach().clone(),
                      minus = scores.detach().clone();
        plus[0][i][j] += h;
        minus[0][i][j] -= h;
        const double fd =
            (loss(plus).item<double>() - loss(minus).item<double>()) / (2 * h);
        EXPECT_NEAR(scores.grad()[0][i][j].item<double>(), fd, kTol);
      }
    }
  }
}

TEST(LabelingLoss, BuildsFromTheRegistry) {
  ConfigNode node = ConfigNode::EmptyMap();
  node.Set("name", ConfigNode("soma"));
  node.Set("quirk_probability_loss", ConfigNode(false));
  BuildContext ctx;
  const std::unique_ptr<LabelingLoss> loss =
      Instantiate<LabelingLoss>(node, ctx);
  const auto* soma_loss = dynamic_cast<const SomaLabelingLoss*>(loss.get());
  ASSERT_NE(soma_loss, nullptr);
  EXPECT_FALSE(soma_loss->options().quirk_probability_loss);
  node.Set("typo", ConfigNode(1));
  EXPECT_THROW(Instantiate<LabelingLoss>(node, ctx), ConfigError);
}

}  // namespace
}  // namespace soma
