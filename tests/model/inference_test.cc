// Per-frame inference: the duplicate-label rule (REFERENCE 5.4), the random
// per-frame permutation and its inversion (REFERENCE 5.3), batching.
#include "framework/model/inference.h"

#include "framework/config/node.h"
#include "framework/core/error.h"
#include "framework/model/label_encoder.h"
#include "framework/model/labeler.h"

#include <gtest/gtest.h>
#include <torch/torch.h>

#include "tests/model/conditioned_labeler.h"
#include <numbers>
#include <string>
#include <vector>

namespace soma {
namespace {

Labeler SmallModel(int64_t num_labels) {
  torch::manual_seed(41);
  LabelerOptions options;
  options.num_labels = num_labels;
  options.d_model = 16;
  options.hidden = 16;
  SelfAttentionOptions attention;
  attention.d_model = 16;
  attention.num_layers = 2;
  attention.num_heads = 4;
  Labeler model(options, SelfAttention(attention).ptr(), Sinkhorn().ptr());
  model->eval();
  return model;
}

torch::Tensor Points(int64_t frames, int64_t p) {
  torch::manual_seed(42);
  torch::Tensor points = torch::randn({frames, p, 3});
  points.narrow(1, p - 2, 2).zero_();  // padding
  return points;
}

/// The mean of the label distributions of `views` single-view labellings
/// (`options`, which must have one view) of `points` rotated by 2*pi*v/views
/// about Z: what FrameLabeler with `views` views should give.
torch::Tensor MeanOfRotatedViews(const Labeler& model,
                                 const InferenceOptions& options,
                                 const torch::Tensor& points,
                                 int views,
                                 const LabelSlots* slots = nullptr) {
  torch::Tensor sum;
  for (int view = 0; view < views; ++view) {
    const torch::Tensor confidence =
        FrameLabeler(model.ptr(), options)
            .Label(RotateAboutVertical(points,
                                       2 * std::numbers::pi * view / views),
                   0,
                   slots)
            .label_confidence;
    sum = view == 0 ? confidence.clone() : sum + confidence;
  }
  return sum / views;
}

TEST(ResolveDuplicateLabels, AllClaimantsOfARealLabelBecomeNull) {
  const int64_t l = 4;  // null = 4
  const torch::Tensor ids = torch::tensor({0,
                                           1,
                                           1,
                                           4,
                                           2,
                                           2,
                                           2,
                                           3,  //
                                           3,
                                           0,
                                           1,
                                           2,
                                           4,
                                           4,
                                           0,
                                           1},
                                          torch::kLong)
                                .view({2, 8});
  torch::Tensor valid = torch::ones({2, 8}, torch::kBool);
  valid[1][6] = false;  // a zero point claiming label 0 does not count...
  valid[1][7] = false;  // ...and is reported as null itself
  const torch::Tensor expected = torch::tensor({0,
                                                4,
                                                4,
                                                4,
                                                4,
                                                4,
                                                4,
                                                3,  //
                                                3,
                                                0,
                                                1,
                                                2,
                                                4,
                                                4,
                                                4,
                                                4},
                                               torch::kLong)
                                     .view({2, 8});
  EXPECT_TRUE(torch::equal(ResolveDuplicateLabels(ids, valid, l), expected));
  // Null is never a "duplicate" to resolve.
  const torch::Tensor nulls = torch::full({1, 3}, l, torch::kLong);
  EXPECT_TRUE(torch::equal(
      ResolveDuplicateLabels(nulls, torch::ones({1, 3}, torch::kBool), l),
      nulls));
  EXPECT_THROW(
      ResolveDuplicateLabels(ids, torch::ones({2, 7}, torch::kBool), l),
      ShapeError);
}

TEST(FrameLabeler, OutputsAreInInputOrderWhateverThePermutation) {
  Labeler model = SmallModel(6);
  const torch::Tensor points = Points(9, 11);
  for (bool fast : {true, false}) {
    SCOPED_TRACE(fast ? "fast path" : "torch path");
    InferenceOptions plain;
    plain.permute = false;
    plain.use_fast_path = fast;
    const FrameLabels reference =
        FrameLabeler(model.ptr(), plain).Label(points);
    EXPECT_EQ(FrameLabeler(model.ptr(), plain).uses_fast_path(), fast);
    for (uint64_t seed : {1u, 2u}) {
      InferenceOptions permuted = plain;
      permuted.permute = true;
      permuted.seed = seed;
      permuted.batch_size = 4;  // batches of 4, 4, 1
      const FrameLabels labels =
          FrameLabeler(model.ptr(), permuted).Label(points);
      EXPECT_TRUE(torch::allclose(
          labels.label_confidence, reference.label_confidence, 1e-4, 1e-5));
      EXPECT_TRUE(torch::equal(labels.predicted_ids, reference.predicted_ids));
      EXPECT_TRUE(torch::equal(labels.label_ids, reference.label_ids));
    }
  }
}

TEST(FrameLabeler, PermutingInputPointsPermutesOutputs) {
  // The network is permutation equivariant (no positional encoding, median
  // centring is order-free): a random model must map permuted inputs to
  // permuted outputs.
  Labeler model = SmallModel(5);
  const torch::Tensor points = Points(4, 10);
  const torch::Tensor perm = torch::randperm(10, torch::kLong);
  InferenceOptions options;
  options.seed = 7;
  const FrameLabeler labeler(model.ptr(), options);
  const FrameLabels a = labeler.Label(points);
  const FrameLabels b = labeler.Label(points.index_select(1, perm));
  EXPECT_TRUE(torch::allclose(b.label_confidence,
                              a.label_confidence.index_select(1, perm),
                              1e-4,
                              1e-5));
  EXPECT_TRUE(torch::equal(b.label_ids, a.label_ids.index_select(1, perm)));
}

TEST(FrameLabeler, LabelsFollowTheDuplicateRuleAndZeroPointsAreNull) {
  Labeler model = SmallModel(3);
  const torch::Tensor points = Points(6, 12);
  const FrameLabels labels = FrameLabeler(model.ptr()).Label(points);
  EXPECT_EQ(labels.label_ids.sizes(), (std::vector<int64_t>{6, 12}));
  EXPECT_EQ(labels.label_confidence.sizes(), (std::vector<int64_t>{6, 12, 4}));
  EXPECT_TRUE(
      torch::equal(labels.predicted_ids, labels.label_confidence.argmax(-1)));
  EXPECT_TRUE(torch::equal(
      labels.label_ids,
      ResolveDuplicateLabels(labels.predicted_ids, points.ne(0).any(-1), 3)));
  EXPECT_TRUE(labels.label_ids.narrow(1, 10, 2).eq(3).all().item<bool>());
  // Every real label appears at most once per frame.
  for (int64_t t = 0; t < 6; ++t) {
    for (int64_t label = 0; label < 3; ++label) {
      EXPECT_LE(labels.label_ids[t].eq(label).sum().item<int64_t>(), 1);
    }
  }
}

TEST(FrameLabeler, MatchingDecodeIsTheMatchOfTheSameRows) {
  Labeler model = SmallModel(4);
  const torch::Tensor points = Points(7, 9);
  InferenceOptions argmax;
  argmax.seed = 3;
  InferenceOptions matching = argmax;
  matching.decode = LabelDecode::kMatching;
  const FrameLabels a = FrameLabeler(model.ptr(), argmax).Label(points);
  const FrameLabels m = FrameLabeler(model.ptr(), matching).Label(points);
  // The decode changes the labels only: the rows and their argmax are those
  // of the argmax decode.
  EXPECT_TRUE(torch::equal(m.label_confidence, a.label_confidence));
  EXPECT_TRUE(torch::equal(m.predicted_ids, a.predicted_ids));
  const torch::Tensor valid = points.ne(0).any(-1);
  EXPECT_TRUE(
      torch::equal(m.label_ids, MatchLabels(m.label_confidence, valid)));
  EXPECT_TRUE(m.label_ids.narrow(1, 7, 2).eq(4).all().item<bool>());
  for (int64_t t = 0; t < 7; ++t) {
    for (int64_t label = 0; label < 4; ++label) {
      EXPECT_LE(m.label_ids[t].eq(label).sum().item<int64_t>(), 1);
    }
  }
  // SOMA's rule also gives a labelling without a repeated label, so the
  // matching's log-likelihood is at least as high, frame by frame.
  auto log_likelihood = [&](const torch::Tensor& ids) {
    return (m.label_confidence.gather(2, ids.unsqueeze(-1)).squeeze(-1).log() *
            valid)
        .sum(1);
  };
  EXPECT_TRUE(log_likelihood(m.label_ids)
                  .ge(log_likelihood(a.label_ids) - 1e-4)
                  .all()
                  .item<bool>());
  EXPECT_THROW(MatchLabels(m.label_confidence, valid.narrow(1, 0, 8)),
               ShapeError);
}

TEST(RotateAboutVertical, TurnsXYAboutTheOriginAndKeepsZAndZeroPoints) {
  const torch::Tensor points =
      torch::tensor({1.0f, 0.0f, 0.5f, 0.0f, 2.0f, -1.0f, 0.0f, 0.0f, 0.0f})
          .view({1, 3, 3});
  const torch::Tensor quarter =
      RotateAboutVertical(points, std::numbers::pi / 2);
  const torch::Tensor expected =
      torch::tensor({0.0f, 1.0f, 0.5f, -2.0f, 0.0f, -1.0f, 0.0f, 0.0f, 0.0f})
          .view({1, 3, 3});
  EXPECT_TRUE(torch::allclose(quarter, expected, 1e-6, 1e-6));
  // Distances and heights are kept; a full turn is the identity.
  const torch::Tensor p = Points(4, 9);
  const torch::Tensor r = RotateAboutVertical(p, 0.7);
  EXPECT_TRUE(torch::allclose(r.norm(2, -1), p.norm(2, -1), 1e-5, 1e-6));
  EXPECT_TRUE(torch::equal(r.select(-1, 2), p.select(-1, 2)));
  EXPECT_TRUE(torch::allclose(
      RotateAboutVertical(p, 2 * std::numbers::pi), p, 1e-5, 1e-6));
  EXPECT_THROW(RotateAboutVertical(torch::zeros({4, 2}), 0.1), ShapeError);
}

TEST(FrameLabeler, ViewsAverageTheDistributionsOfRotatedFrames) {
  Labeler model = SmallModel(5);
  const torch::Tensor points = Points(6, 10);
  InferenceOptions one;
  one.permute = false;
  one.batch_size = 4;  // the views of a batch are averaged batch by batch
  InferenceOptions three = one;
  three.views = 3;
  three.decode = LabelDecode::kMatching;
  const FrameLabels ensemble = FrameLabeler(model.ptr(), three).Label(points);
  EXPECT_TRUE(torch::allclose(ensemble.label_confidence,
                              MeanOfRotatedViews(model, one, points, 3),
                              1e-5,
                              1e-6));
  EXPECT_TRUE(torch::equal(ensemble.predicted_ids,
                           ensemble.label_confidence.argmax(-1)));
  const torch::Tensor valid = points.ne(0).any(-1);
  EXPECT_TRUE(torch::equal(ensemble.label_ids,
                           MatchLabels(ensemble.label_confidence, valid)));
  // The network is not rotation invariant, so the views do differ: the
  // ensemble is not the first view alone.
  const FrameLabels first = FrameLabeler(model.ptr(), one).Label(points);
  EXPECT_GT((ensemble.label_confidence - first.label_confidence)
                .abs()
                .max()
                .item<float>(),
            1e-3);
}

TEST(FrameLabeler, OneViewIsTheDefaultAndViewsIgnoreTheBatchSplit) {
  Labeler model = SmallModel(4);
  const torch::Tensor points = Points(5, 9);
  InferenceOptions options;
  options.seed = 7;
  // views = 1 is the labelling without the option, bit for bit.
  InferenceOptions one = options;
  one.views = 1;
  const FrameLabels a = FrameLabeler(model.ptr(), options).Label(points);
  const FrameLabels b = FrameLabeler(model.ptr(), one).Label(points);
  EXPECT_TRUE(torch::equal(a.label_confidence, b.label_confidence));
  EXPECT_TRUE(torch::equal(a.label_ids, b.label_ids));
  // With two views, each frame's views and permutations come from its own
  // index: neither the batch split nor where the call starts changes them.
  InferenceOptions two = options;
  two.views = 2;
  const FrameLabels c = FrameLabeler(model.ptr(), two).Label(points);
  InferenceOptions two_batched = two;
  two_batched.batch_size = 2;
  const FrameLabels d = FrameLabeler(model.ptr(), two_batched).Label(points);
  EXPECT_TRUE(
      torch::allclose(c.label_confidence, d.label_confidence, 1e-6, 1e-7));
  const FrameLabels tail =
      FrameLabeler(model.ptr(), two).Label(points.narrow(0, 2, 3), 2);
  EXPECT_TRUE(torch::allclose(
      tail.label_confidence, c.label_confidence.narrow(0, 2, 3), 1e-6, 1e-7));
}

TEST(FrameLabeler, ViewsOfAConditionedLabelerShareEachFramesSlots) {
  Labeler model = testing::SmallConditionedLabeler(5);
  model->eval();
  const torch::Tensor points = Points(6, 9);
  torch::manual_seed(3);
  const LabelSlots slots{
      torch::randn({6, 5, testing::kConditionedDescriptorWidth}), {}};
  InferenceOptions one;
  one.permute = false;
  one.batch_size = 4;
  InferenceOptions three = one;
  three.views = 3;
  const FrameLabels ensemble =
      FrameLabeler(model.ptr(), three).Label(points, 0, &slots);
  EXPECT_TRUE(torch::allclose(ensemble.label_confidence,
                              MeanOfRotatedViews(model, one, points, 3, &slots),
                              1e-5,
                              1e-6));
  // With permutations, the batch split still does not matter.
  InferenceOptions permuted = three;
  permuted.permute = true;
  InferenceOptions permuted_batched = permuted;
  permuted_batched.batch_size = 6;
  EXPECT_TRUE(torch::allclose(FrameLabeler(model.ptr(), permuted)
                                  .Label(points, 0, &slots)
                                  .label_confidence,
                              FrameLabeler(model.ptr(), permuted_batched)
                                  .Label(points, 0, &slots)
                                  .label_confidence,
                              1e-5,
                              1e-6));
}

TEST(FrameLabeler, OptionsAndShapes) {
  ConfigNode node = ConfigNode::EmptyMap();
  node.Set("batch_size", ConfigNode(30));
  node.Set("seed", ConfigNode(5));
  const InferenceOptions options = DecodeInferenceOptions(node);
  EXPECT_EQ(options.batch_size, 30);
  EXPECT_EQ(options.seed, 5u);
  EXPECT_TRUE(options.permute);
  EXPECT_EQ(options.decode, LabelDecode::kArgmax);
  node.Set("decode", ConfigNode("matching"));
  EXPECT_EQ(DecodeInferenceOptions(node).decode, LabelDecode::kMatching);
  node.Set("decode", ConfigNode("hungarian"));
  EXPECT_THROW(DecodeInferenceOptions(node), ConfigError);
  node.Set("decode", ConfigNode("argmax"));
  EXPECT_EQ(DecodeInferenceOptions(node).views, 1);
  node.Set("views", ConfigNode(8));
  EXPECT_EQ(DecodeInferenceOptions(node).views, 8);
  node.Set("views", ConfigNode(0));
  try {
    DecodeInferenceOptions(node);
    ADD_FAILURE() << "views = 0 was accepted";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("views"), std::string::npos)
        << e.what();
    EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos) << e.what();
  }
  InferenceOptions no_views;
  no_views.views = 0;
  EXPECT_THROW(FrameLabeler(SmallModel(2).ptr(), no_views), ConfigError);
  node.Set("views", ConfigNode(1));
  node.Set("batch_size", ConfigNode(0));
  EXPECT_THROW(DecodeInferenceOptions(node), ConfigError);
  Labeler model = SmallModel(3);
  const FrameLabeler labeler(model.ptr());
  EXPECT_THROW(labeler.Label(torch::zeros({2, 3})), ShapeError);
  EXPECT_EQ(labeler.Label(torch::zeros({0, 4, 3})).label_ids.size(0), 0);
}

}  // namespace
}  // namespace soma
