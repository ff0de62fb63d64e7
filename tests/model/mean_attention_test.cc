#include "framework/model/mean_attention.h"

#include "framework/core/error.h"
#include "framework/model/layers.h"
#include "framework/model/normalization.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>
#include <torch/torch.h>

#include <memory>
#include <utility>
#include <vector>

namespace soma {
namespace {

constexpr int64_t kLabels = 4;

/// A labeler of kLabels labels and width 12 on `backbone`.
Labeler SmallLabeler(std::shared_ptr<BackboneImpl> backbone) {
  LabelerOptions options;
  options.num_labels = kLabels;
  options.d_model = 12;
  options.hidden = 16;
  return Labeler(
      options, std::move(backbone), Sinkhorn(SinkhornOptions{}).ptr());
}

Labeler SmallAttentionLabeler() {
  SelfAttentionOptions attention;
  attention.d_model = 12;
  attention.num_layers = 2;
  attention.num_heads = 3;
  return SmallLabeler(SelfAttention(attention).ptr());
}

TEST(MeanAttention, MaxOverHeadsMeanOverFramesInAnyBatchSize) {
  torch::manual_seed(3);
  Labeler model = SmallAttentionLabeler();
  const torch::Tensor points = torch::randn({5, kLabels, 3});
  const std::vector<Eigen::MatrixXd> layers =
      MeanAttention(*model, points, /*batch_size=*/2);
  ASSERT_EQ(layers.size(), 2u);

  // The reference: one forward over all frames, B x k x h x N x N.
  torch::NoGradGuard no_grad;
  model->eval();
  const torch::Tensor attention =
      model->forward(points, /*return_attention=*/true).attention;
  ASSERT_TRUE(attention.defined());
  const torch::Tensor expected =
      std::get<0>(attention.max(/*dim=*/2)).mean(/*dim=*/0).to(torch::kDouble);
  for (int l = 0; l < 2; ++l) {
    ASSERT_EQ(layers[l].rows(), kLabels);
    ASSERT_EQ(layers[l].cols(), kLabels);
    for (int i = 0; i < kLabels; ++i) {
      for (int j = 0; j < kLabels; ++j) {
        // Row i is the attending point (not transposed on the way).
        EXPECT_NEAR(layers[l](i, j), expected[l][i][j].item<double>(), 1e-6)
            << l << " " << i << " " << j;
        EXPECT_GE(layers[l](i, j), 0.0);
      }
    }
  }
  // Batches of one frame give the same mean.
  const std::vector<Eigen::MatrixXd> single = MeanAttention(*model, points, 1);
  for (int l = 0; l < 2; ++l) {
    EXPECT_TRUE(single[l].isApprox(layers[l], 1e-5)) << l;
  }
}

TEST(MeanAttention, ModelWithoutSelfAttentionIsAConfigError) {
  Conv1dBackboneOptions conv;
  conv.d_model = 12;
  conv.num_layers = 1;
  conv.hidden = 16;
  Labeler model = SmallLabeler(Conv1dBackbone(conv).ptr());
  const torch::Tensor points = torch::randn({2, kLabels, 3});
  EXPECT_THROW(MeanAttention(*model, points, 2), ConfigError);
}

}  // namespace
}  // namespace soma
