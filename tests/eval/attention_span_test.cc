#include "framework/eval/attention_span.h"

#include "framework/core/error.h"

#include <gtest/gtest.h>

namespace soma {
namespace {

Eigen::Matrix3Xd FourPoints() {
  Eigen::Matrix3Xd p(3, 4);
  p << 0, 1, 0, 3,  //
      0, 0, 2, 0,   //
      0, 0, 0, 0;
  return p;
}

TEST(AttentionSpan, SelfAttentionHasNoSpanAndUniformAttentionTheMeanDistance) {
  const Eigen::MatrixXd d = PairwiseDistances(FourPoints());
  EXPECT_DOUBLE_EQ(d(0, 3), 3.0);
  EXPECT_DOUBLE_EQ(d(1, 2), std::sqrt(5.0));
  EXPECT_EQ(d, d.transpose());
  const Eigen::MatrixXd identity = Eigen::MatrixXd::Identity(4, 4);
  const Eigen::MatrixXd uniform = Eigen::MatrixXd::Constant(4, 4, 0.25);
  const std::vector<AttentionSpanLayer> layers =
      ComputeAttentionSpan({uniform, identity}, d);
  ASSERT_EQ(layers.size(), 2u);
  for (int i = 0; i < 4; ++i) {
    EXPECT_NEAR(layers[0].per_marker_m[i], d.row(i).mean(), 1e-12);
  }
  EXPECT_NEAR(layers[0].mean_m, d.mean(), 1e-12);
  EXPECT_GT(layers[0].ci95_m, 0.0);
  EXPECT_EQ(layers[1].mean_m, 0.0);  // every marker attends to itself
  EXPECT_EQ(layers[1].ci95_m, 0.0);
}

TEST(AttentionSpan, RowsAreNormalisedAfterTheHeadMaximum) {
  const Eigen::MatrixXd d = PairwiseDistances(FourPoints());
  // Marker 0 attends to itself and marker 3 equally (weights 2 and 2 after
  // a max over heads need not sum to 1): span 0.5 * 0 + 0.5 * 3.
  Eigen::MatrixXd w = Eigen::MatrixXd::Identity(4, 4);
  w(0, 0) = 2.0;
  w(0, 3) = 2.0;
  const std::vector<AttentionSpanLayer> layers = ComputeAttentionSpan({w}, d);
  EXPECT_DOUBLE_EQ(layers[0].per_marker_m[0], 1.5);
  EXPECT_DOUBLE_EQ(layers[0].mean_m, 1.5 / 4);
}

TEST(AttentionSpan, BadInputThrows) {
  const Eigen::MatrixXd d = PairwiseDistances(FourPoints());
  EXPECT_THROW(ComputeAttentionSpan({Eigen::MatrixXd::Identity(3, 3)}, d),
               ShapeError);
  EXPECT_THROW(ComputeAttentionSpan({Eigen::MatrixXd::Zero(4, 4)}, d),
               ShapeError);
  EXPECT_THROW(ComputeAttentionSpan({-Eigen::MatrixXd::Identity(4, 4)}, d),
               ShapeError);
  EXPECT_THROW(ComputeAttentionSpan({}, Eigen::MatrixXd::Zero(4, 3)),
               ShapeError);
}

}  // namespace
}  // namespace soma
