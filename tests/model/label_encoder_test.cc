// The layout-conditioned labeller (model=soma_any_layout, issue #25 item 1):
// shapes, invariance to the order of the labels, padded label slots, the
// label branch's gradients against float64 finite differences, building
// from the config.
#include "framework/model/label_encoder.h"

#include "framework/body/vertex_descriptors.h"
#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/model/labeler.h"
#include "framework/model/normalization.h"
#include "framework/registry/registry.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>
#include <torch/torch.h>

#include "tests/model/conditioned_labeler.h"
#include <cmath>
#include <numbers>
#include <set>
#include <string>
#include <vector>

namespace soma {
namespace {

using testing::SmallConditionedLabeler;

constexpr int64_t kWidth = testing::kConditionedDescriptorWidth;
constexpr double kTol = 1e-5;      // float32 forward
constexpr double kGradTol = 1e-6;  // float64 FD vs autograd

ConfigNode LoadConfig(const std::string& relative) {
  return LoadConfigFile(testing::SourceDir() / "configs" / relative).content;
}

/// The label encoder of SmallConditionedLabeler: width 12, MLP hidden 10,
/// 2 layers of 3 heads.
LabelEncoderOptions SmallEncoderOptions() {
  LabelEncoderOptions options;
  options.descriptor_width = kWidth;
  options.d_model = 12;
  options.hidden = 10;
  options.num_layers = 2;
  options.num_heads = 3;
  return options;
}

torch::Tensor RandomDescriptors(int64_t batch, int64_t labels) {
  return torch::randn({batch, labels, kWidth});
}

TEST(LabelEncoder, DescriptorWidthMatchesTheBody) {
  EXPECT_EQ(LabelDescriptorWidth(24), kWidth);
}

TEST(LabelEncoder, FourierFeaturesOfTheRestPosition) {
  // bands = 0: the descriptors themselves.
  const torch::Tensor q = torch::randn({2, 4, kWidth}, torch::kDouble);
  EXPECT_TRUE(WithFourierFeatures(q, 0).is_same(q));
  // bands = 3: Q + 18 columns, the descriptor first, then sin and cos of
  // 2^k pi p, coordinate-major (p = columns 0-2).
  const torch::Tensor f = WithFourierFeatures(q, 3);
  ASSERT_EQ(f.sizes(), (std::vector<int64_t>{2, 4, kWidth + 18}));
  EXPECT_TRUE(torch::equal(f.narrow(-1, 0, kWidth), q));
  for (int64_t c = 0; c < 3; ++c) {
    for (int64_t k = 0; k < 3; ++k) {
      const double x =
          q[1][2][c].item<double>() * std::pow(2.0, k) * std::numbers::pi;
      const int64_t column = kWidth + 3 * c + k;
      EXPECT_NEAR(f[1][2][column].item<double>(), std::sin(x), 1e-12)
          << c << " " << k;
      EXPECT_NEAR(f[1][2][column + 9].item<double>(), std::cos(x), 1e-12)
          << c << " " << k;
    }
  }
  // Only the position is encoded: the other columns do not reach the
  // features.
  torch::Tensor other = q.clone();
  other.narrow(-1, 3, kWidth - 3).normal_();
  EXPECT_TRUE(torch::equal(WithFourierFeatures(other, 3).narrow(-1, kWidth, 18),
                           f.narrow(-1, kWidth, 18)));
  // The encoder's first layer takes them, and only the options' width.
  LabelEncoderOptions options;
  options.descriptor_width = kWidth;
  options.d_model = 10;
  options.hidden = 8;
  options.num_layers = 1;
  options.num_heads = 2;
  options.fourier_bands = 3;
  LabelEncoder encoder(options);
  EXPECT_EQ(encoder->input->weight.size(1), kWidth + 18);
  EXPECT_EQ(options.InputWidth(), kWidth + 18);
  const torch::Tensor mask = torch::ones({2, 4}, torch::kBool);
  EXPECT_EQ(encoder->forward(q.to(torch::kFloat), mask).sizes(),
            (std::vector<int64_t>{2, 10, 4}));
  options.fourier_bands = -1;
  EXPECT_THROW(LabelEncoder{options}, ConfigError);
  options.fourier_bands = kMaxFourierBands + 1;
  EXPECT_THROW(LabelEncoder{options}, ConfigError);
}

TEST(LabelEncoder, RelativeOffsetsOfTheRestPositions) {
  torch::Tensor q = torch::randn({1, 3, kWidth}, torch::kDouble);
  q.narrow(-1, 0, 3).zero_();
  q[0][1][0] = kRelativeOffsetScale;       // label 1: one unit along x
  q[0][2][1] = -2 * kRelativeOffsetScale;  // label 2: two units down y
  const torch::Tensor r = RelativeOffsets(q);
  ASSERT_EQ(r.sizes(), (std::vector<int64_t>{1, 3, 3, 4}));
  auto expect_row = [&](int64_t i, int64_t j, std::vector<double> want) {
    for (int64_t c = 0; c < 4; ++c) {
      EXPECT_NEAR(r[0][i][j][c].item<double>(), want[c], 2e-6)
          << i << " " << j << " " << c;
    }
  };
  expect_row(0, 1, {1, 0, 0, 1});  // p_1 - p_0
  expect_row(1, 0, {-1, 0, 0, 1});
  expect_row(1, 2, {-1, -2, 0, std::sqrt(5.0)});
  expect_row(2, 1, {1, 2, 0, std::sqrt(5.0)});
  expect_row(1, 1, {0, 0, 0, 0});
  // Only the position enters.
  torch::Tensor other = q.clone();
  other.narrow(-1, 3, kWidth - 3).normal_();
  EXPECT_TRUE(torch::equal(RelativeOffsets(other), r));
  // Translating the whole layout changes nothing.
  torch::Tensor moved = q.clone();
  moved.narrow(-1, 0, 3).add_(0.3);
  EXPECT_TRUE(torch::allclose(RelativeOffsets(moved), r, 1e-9, 1e-9));
}

// As built, the rest-offset biases are zero: the encoder is the plain one
// with the same weights. Once they are not, they move the embeddings.
TEST(LabelEncoder, RelativeBiasStartsAsPlainAttention) {
  torch::manual_seed(21);
  LabelEncoderOptions options = SmallEncoderOptions();
  LabelEncoder plain(options);
  options.relative_bias = 6;
  LabelEncoder biased(options);
  ASSERT_EQ(biased->relative.size(), 2u);
  EXPECT_EQ(biased->parameters().size(), plain->parameters().size() + 8);
  {
    torch::NoGradGuard no_grad;
    auto target = biased->named_parameters();
    for (const auto& item : plain->named_parameters()) {
      target[item.key()].copy_(item.value());
    }
  }
  plain->eval();
  biased->eval();
  const torch::Tensor q = torch::randn({2, 6, kWidth});
  torch::Tensor mask = torch::ones({2, 6}, torch::kBool);
  mask.index_put_({1, 5}, false);
  torch::NoGradGuard no_grad;
  const torch::Tensor a = plain->forward(q, mask);
  EXPECT_TRUE(torch::allclose(biased->forward(q, mask), a, 1e-6, 1e-6));
  biased->relative[1]->parameters().back().fill_(2.0);  // every head: 2
  biased->relative[1]->parameters()[2].normal_();       // last weight
  const torch::Tensor b = biased->forward(q, mask);
  EXPECT_GT((b - a).abs().max().item<double>(), 1e-3);
  // A bias equal for every key of a query is no bias (softmax shift).
  biased->relative[1]->parameters()[2].zero_();
  EXPECT_TRUE(torch::allclose(biased->forward(q, mask), a, 1e-6, 1e-6));
  options.relative_bias = -1;
  EXPECT_THROW(LabelEncoder{options}, ConfigError);
}

// A batch as training sees it: two layouts, each several times in its own
// slot order and padding, a padded slot holding garbage, a frame of one
// layout only. Frames 0, 1, 3 hold set A (5 labels), frame 2 set B (3
// labels), frame 4 set A minus one label (a third set).
struct RepeatedLayouts {
  torch::Tensor descriptors;  // 5 x 7 x Q
  torch::Tensor mask;         // 5 x 7
};

RepeatedLayouts MakeRepeatedLayouts(torch::Dtype dtype) {
  const torch::Tensor a = torch::randn({5, kWidth}, dtype);
  const torch::Tensor b = torch::randn({3, kWidth}, dtype);
  RepeatedLayouts r;
  r.descriptors = torch::zeros({5, 7, kWidth}, dtype);
  r.mask = torch::zeros({5, 7}, torch::kBool);
  auto place = [&](int64_t frame,
                   const torch::Tensor& rows,
                   const std::vector<int64_t>& slots) {
    for (size_t i = 0; i < slots.size(); ++i) {
      r.descriptors[frame][slots[i]] = rows[static_cast<int64_t>(i)];
      r.mask[frame][slots[i]] = true;
    }
  };
  place(0, a, {0, 1, 2, 3, 4});
  place(1, a, {6, 2, 0, 5, 3});
  place(2, b, {1, 4, 5});
  place(3, a, {4, 3, 2, 1, 0});
  r.descriptors[3][6] = 50 * torch::ones({kWidth}, dtype);  // padded garbage
  place(4, a.narrow(0, 0, 4), {3, 0, 6, 1});
  return r;
}

TEST(LabelEncoder, CompactSlotsHoldEachDistinctLabelSetOnce) {
  torch::manual_seed(11);
  const RepeatedLayouts r = MakeRepeatedLayouts(torch::kFloat);
  const CompactSlots c = CompactLabelSlots({r.descriptors, r.mask});
  // Sets A, B and A minus one; 6 columns (A's 5 labels and its padding
  // token).
  ASSERT_EQ(c.descriptors.sizes(), (std::vector<int64_t>{3, 6, kWidth}));
  ASSERT_EQ(c.index.sizes(), (std::vector<int64_t>{5 * 7}));
  EXPECT_EQ(c.mask.sum().item<int64_t>(), 5 + 3 + 4);
  // Each token stands for as many slots as the batch holds: A's labels for
  // 3 frames and its padding token for their 3 x 2 padded slots, B's
  // labels for 1 frame and its padding token for 4 slots, the third set's
  // for 1 and 3; the filler for none.
  EXPECT_EQ(c.weights.sum().item<double>(), 35.0);
  EXPECT_TRUE(torch::equal(c.weights,
                           torch::tensor({3.f,
                                          3.f,
                                          3.f,
                                          3.f,
                                          3.f,
                                          6.f,
                                          1.f,
                                          1.f,
                                          1.f,
                                          4.f,
                                          0.f,
                                          0.f,
                                          1.f,
                                          1.f,
                                          1.f,
                                          1.f,
                                          3.f,
                                          0.f})
                               .view({3, 6})));
  // Gathering the tokens by `index` gives back every labelled slot's
  // descriptor; every padded slot points at its set's padding token.
  const torch::Tensor gathered = c.descriptors.reshape({-1, kWidth})
                                     .index_select(0, c.index)
                                     .view({5, 7, kWidth});
  const torch::Tensor labelled = r.mask.unsqueeze(-1);
  EXPECT_TRUE(torch::equal(gathered.masked_select(labelled),
                           r.descriptors.masked_select(labelled)));
  EXPECT_TRUE(
      torch::equal(c.index.view({5, 7}).masked_select(r.mask.logical_not()),
                   torch::tensor(std::vector<int64_t>{
                       5, 5, 5, 5, 9, 9, 9, 9, 5, 5, 16, 16, 16})));
  // A batch of one layout in one order, no padding: one set.
  const CompactSlots one =
      CompactLabelSlots({r.descriptors.narrow(0, 0, 1).expand({3, 7, kWidth}),
                         torch::ones({3, 7}, torch::kBool)});
  EXPECT_EQ(one.descriptors.size(0), 1);
  EXPECT_EQ(one.weights.sum().item<double>(), 21.0);
}

// The label encoder over the distinct sets, gathered back, is the encoder
// over the batch: embeddings, running statistics and gradients, in
// training (batch statistics over the weighted tokens) and evaluation.
// Without and with the rest-offset logit biases.
class EncodingTheDistinctSets : public ::testing::TestWithParam<int64_t> {};

TEST_P(EncodingTheDistinctSets, IsEncodingTheBatch) {
  torch::manual_seed(12);
  LabelEncoderOptions options = SmallEncoderOptions();
  options.fourier_bands = 2;
  options.relative_bias = GetParam();
  LabelEncoder encoder(options);
  encoder->to(torch::kDouble);
  testing::DrawRelativeBiases(*encoder);  // as built they are zero
  const RepeatedLayouts r = MakeRepeatedLayouts(torch::kDouble);
  const torch::Tensor upstream = torch::randn({5, 12, 7}, torch::kDouble);
  const std::vector<torch::Tensor> initial_buffers = [&] {
    std::vector<torch::Tensor> out;
    for (const torch::Tensor& b : encoder->buffers()) out.push_back(b.clone());
    return out;
  }();
  struct Run {
    torch::Tensor embeddings;
    std::vector<torch::Tensor> grads;
    std::vector<torch::Tensor> buffers;
  };
  auto run = [&](bool compact, bool training) {
    encoder->train(training);
    {
      torch::NoGradGuard no_grad;
      const std::vector<torch::Tensor> buffers = encoder->buffers();
      for (size_t i = 0; i < buffers.size(); ++i) {
        buffers[i].copy_(initial_buffers[i]);
      }
    }
    encoder->zero_grad();
    Run out;
    out.embeddings = compact ? encoder->EncodeSlots(r.descriptors, r.mask)
                             : encoder->forward(r.descriptors, r.mask);
    (out.embeddings * upstream).sum().backward();
    for (const torch::Tensor& p : encoder->parameters()) {
      out.grads.push_back(p.grad().clone());
    }
    for (const torch::Tensor& b : encoder->buffers()) {
      out.buffers.push_back(b.clone());
    }
    return out;
  };
  for (const bool training : {true, false}) {
    const Run whole = run(false, training);
    const Run compact = run(true, training);
    ASSERT_EQ(compact.embeddings.sizes(), whole.embeddings.sizes());
    EXPECT_TRUE(
        torch::allclose(compact.embeddings, whole.embeddings, 1e-10, 1e-10))
        << "training=" << training << " max diff "
        << (compact.embeddings - whole.embeddings).abs().max().item<double>();
    ASSERT_EQ(compact.grads.size(), whole.grads.size());
    for (size_t i = 0; i < whole.grads.size(); ++i) {
      EXPECT_TRUE(
          torch::allclose(compact.grads[i], whole.grads[i], 1e-9, 1e-10))
          << "training=" << training << " parameter " << i;
      EXPECT_GT(whole.grads[i].abs().max().item<double>(), 0.0) << i;
    }
    for (size_t i = 0; i < whole.buffers.size(); ++i) {
      EXPECT_TRUE(
          torch::allclose(compact.buffers[i], whole.buffers[i], 1e-12, 1e-12))
          << "training=" << training << " buffer " << i;
    }
    // Training moved the running statistics (so the check above can fail).
    if (training) {
      EXPECT_FALSE(torch::allclose(whole.buffers[0], initial_buffers[0]));
    }
  }
}

INSTANTIATE_TEST_SUITE_P(LabelEncoder,
                         EncodingTheDistinctSets,
                         ::testing::Values(int64_t{0}, int64_t{6}));

TEST(ConditionedLabeler, OutputShapes) {
  torch::manual_seed(1);
  Labeler model = SmallConditionedLabeler(6);
  EXPECT_TRUE(model->conditioned());
  EXPECT_TRUE(model->head.is_empty());
  const torch::Tensor points = torch::randn({2, 9, 3});
  const LabelerOutput out =
      model->ForwardSlots(points, LabelSlots{RandomDescriptors(2, 6), {}});
  EXPECT_EQ(out.scores.sizes(), (std::vector<int64_t>{2, 9, 6}));
  EXPECT_EQ(out.log_assignment.sizes(), (std::vector<int64_t>{2, 10, 7}));
  EXPECT_EQ(out.label_confidence.sizes(), (std::vector<int64_t>{2, 9, 7}));
  EXPECT_EQ(out.label_ids.sizes(), (std::vector<int64_t>{2, 9}));
  // One layout shared by the batch (1 x L x Q) broadcasts.
  const LabelerOutput shared =
      model->ForwardSlots(points, LabelSlots{RandomDescriptors(1, 6), {}});
  EXPECT_EQ(shared.scores.sizes(), (std::vector<int64_t>{2, 9, 6}));
  // Wrong slot shapes are one-line ShapeErrors.
  EXPECT_THROW(
      model->ForwardSlots(points, LabelSlots{RandomDescriptors(2, 5), {}}),
      ShapeError);
  EXPECT_THROW(
      model->ForwardSlots(points, LabelSlots{RandomDescriptors(3, 6), {}}),
      ShapeError);
  EXPECT_THROW(
      model->ForwardSlots(
          points, LabelSlots{RandomDescriptors(2, 6), torch::ones({2, 6})}),
      ShapeError);  // float mask
}

// Permuting the slots of a layout permutes the score columns, in
// evaluation and in training.
void ExpectPermutationEquivariant(Labeler& model) {
  torch::NoGradGuard no_grad;
  for (const bool training : {false, true}) {
    model->train(training);
    const torch::Tensor points = torch::randn({3, 10, 3});
    const torch::Tensor q = RandomDescriptors(3, 7);
    const torch::Tensor perm = torch::randperm(7);
    const LabelerOutput a = model->ForwardSlots(points, LabelSlots{q, {}});
    const LabelerOutput b =
        model->ForwardSlots(points, LabelSlots{q.index_select(1, perm), {}});
    // Column j of b is column perm[j] of a; the null column stays last.
    EXPECT_TRUE(
        torch::allclose(b.scores, a.scores.index_select(2, perm), kTol, kTol))
        << "training=" << training;
    const torch::Tensor cols = torch::cat({perm, torch::tensor({int64_t{7}})});
    EXPECT_TRUE(torch::allclose(
        b.log_assignment, a.log_assignment.index_select(2, cols), kTol, kTol))
        << "training=" << training;
    // The label ids are the permuted slots.
    const torch::Tensor inverse = torch::argsort(cols);
    EXPECT_TRUE(torch::equal(inverse.index({a.label_ids}), b.label_ids))
        << "training=" << training;
  }
}

TEST(ConditionedLabeler, PermutingTheLayoutPermutesTheColumns) {
  torch::manual_seed(2);
  for (const int64_t relative_bias : {0, 6}) {
    Labeler model = SmallConditionedLabeler(
        7, 35, /*position_loss=*/0.0, /*cross_layers=*/0, relative_bias);
    ExpectPermutationEquivariant(model);
  }
}

TEST(ConditionedLabeler, PaddedSlotsGetNoAssignmentAndDoNotMatter) {
  torch::manual_seed(3);
  Labeler model = SmallConditionedLabeler(8);
  model->eval();
  torch::NoGradGuard no_grad;
  const torch::Tensor points = torch::randn({2, 9, 3});
  torch::Tensor q = RandomDescriptors(2, 8);
  torch::Tensor mask = torch::ones({2, 8}, torch::kBool);
  mask.index_put_({0, torch::indexing::Slice(5, 8)}, false);
  mask.index_put_({1, 0}, false);
  const LabelerOutput a = model->ForwardSlots(points, LabelSlots{q, mask});
  const torch::Tensor confidence = a.label_confidence;  // B x N x (L+1)
  EXPECT_LT(
      confidence
          .index({0, torch::indexing::Slice(), torch::indexing::Slice(5, 8)})
          .max()
          .item<double>(),
      1e-30);
  EXPECT_LT(
      confidence.index({1, torch::indexing::Slice(), 0}).max().item<double>(),
      1e-30);
  // A padded column's mass goes to the dustbin row: its column of exp(A')
  // holds the same mass as a real label's column.
  const torch::Tensor p = a.log_assignment.exp();
  EXPECT_NEAR(p[0].select(1, 6).sum().item<double>(),
              p[0].select(1, 1).sum().item<double>(),
              1e-4);
  EXPECT_GT(p[0][9][6].item<double>(),
            0.99 * p[0].select(1, 6).sum().item<double>());
  // No label id lands on a padded slot.
  EXPECT_TRUE(
      a.label_ids[0].lt(5).logical_or(a.label_ids[0].eq(8)).all().item<bool>());
  EXPECT_TRUE(a.label_ids[1].ne(0).all().item<bool>());
  // Whatever a padded slot holds does not change the output.
  torch::Tensor garbage = q.clone();
  garbage.index_put_({0, torch::indexing::Slice(5, 8)},
                     100 * torch::randn({3, kWidth}));
  garbage.index_put_({1, 0}, -50 * torch::ones({kWidth}));
  const LabelerOutput b =
      model->ForwardSlots(points, LabelSlots{garbage, mask});
  EXPECT_TRUE(torch::allclose(a.log_assignment, b.log_assignment, kTol, kTol));
}

// Central finite differences of a scalar function of the labeller's output
// against autograd, in float64, for descriptor entries and label-branch
// parameters.
// Without and with the rest-offset logit biases in the label encoder.
class LabelBranchGradients : public ::testing::TestWithParam<int64_t> {};

TEST_P(LabelBranchGradients, MatchFiniteDifferences) {
  torch::manual_seed(4);
  const int64_t relative_bias = GetParam();
  Labeler model = SmallConditionedLabeler(5,
                                          /*num_iters=*/10,
                                          /*position_loss=*/0.0,
                                          /*cross_layers=*/0,
                                          relative_bias);
  model->to(torch::kDouble);
  model->eval();  // BatchNorm on running statistics: a fixed function
  const torch::Tensor points = torch::randn({2, 7, 3}, torch::kDouble) * 0.5;
  const torch::Tensor q = torch::randn({2, 5, kWidth}, torch::kDouble);
  torch::Tensor mask = torch::ones({2, 5}, torch::kBool);
  mask.index_put_({1, 4}, false);
  const torch::Tensor weights = torch::randn({2, 8, 6}, torch::kDouble);
  auto objective = [&](const torch::Tensor& descriptors) {
    const LabelerOutput out =
        model->ForwardSlots(points, LabelSlots{descriptors, mask});
    // The padded column's entries are -inf-like constants: leave them out.
    return (out.log_assignment.clamp_min(-50) * weights).sum();
  };
  // d/dq.
  torch::Tensor x = q.clone().requires_grad_(true);
  objective(x).backward();
  const torch::Tensor grad_q = x.grad().clone();
  constexpr double kStep = 1e-6;
  int checked = 0;
  for (const auto& [b, l, c] : std::vector<std::tuple<int, int, int>>{
           {0, 0, 0}, {0, 3, 5}, {1, 2, 9}, {1, 1, 33}, {0, 4, 6}}) {
    torch::NoGradGuard no_grad;
    torch::Tensor plus = q.clone();
    torch::Tensor minus = q.clone();
    plus[b][l][c] += kStep;
    minus[b][l][c] -= kStep;
    const double fd =
        (objective(plus).item<double>() - objective(minus).item<double>()) /
        (2 * kStep);
    const double ad = grad_q[b][l][c].item<double>();
    EXPECT_NEAR(ad, fd, kGradTol * std::max(1.0, std::abs(fd)))
        << "q[" << b << "][" << l << "][" << c << "]";
    ++checked;
  }
  // The padded slot's descriptor has no gradient.
  EXPECT_EQ(grad_q[1][4].abs().max().item<double>(), 0.0);
  // d/dparameters of the label branch.
  std::vector<std::string> names = {
      "label_encoder.mlp.0.weight",
      "label_encoder.self_attention_layers.1.proj.1.weight",
      "label_head.label_proj.weight",
      "label_head.point_proj.bias",
      "label_head.log_scale"};
  if (relative_bias > 0) {
    names.push_back("label_encoder.relative_bias.0.0.weight");
    names.push_back("label_encoder.relative_bias.1.2.weight");
  }
  for (const std::string& name : names) {
    torch::Tensor param = model->named_parameters()[name];
    ASSERT_TRUE(param.defined()) << name;
    model->zero_grad();
    objective(q).backward();
    const torch::Tensor grad = param.grad().clone().reshape({-1});
    // A hidden unit of the small bias MLPs may be off for every pair: check
    // their entry of largest gradient.
    const int64_t index = name.find("relative_bias") != std::string::npos
                              ? grad.abs().argmax().item<int64_t>()
                              : param.numel() / 2;
    torch::NoGradGuard no_grad;
    torch::Tensor flat = param.view({-1});
    const double saved = flat[index].item<double>();
    flat[index] = saved + kStep;
    const double up = objective(q).item<double>();
    flat[index] = saved - kStep;
    const double down = objective(q).item<double>();
    flat[index] = saved;
    const double fd = (up - down) / (2 * kStep);
    EXPECT_NEAR(
        grad[index].item<double>(), fd, kGradTol * std::max(1.0, std::abs(fd)))
        << name;
    EXPECT_NE(fd, 0.0) << name;  // the check can fail: the entry matters
    ++checked;
  }
  EXPECT_EQ(checked, relative_bias > 0 ? 12 : 10);
}

INSTANTIATE_TEST_SUITE_P(ConditionedLabeler,
                         LabelBranchGradients,
                         ::testing::Values(int64_t{0}, int64_t{6}));

TEST(ConditionedLabeler, StoredLayoutIsTheDefaultSlots) {
  torch::manual_seed(5);
  Labeler model = SmallConditionedLabeler(4);
  model->eval();
  torch::NoGradGuard no_grad;
  const torch::Tensor points = torch::randn({3, 6, 3});
  EXPECT_THROW(model->forward(points), ConfigError);  // no layout yet
  const torch::Tensor q = RandomDescriptors(1, 4)[0];
  EXPECT_THROW(model->SetLayout(RandomDescriptors(1, 5)[0]), ShapeError);
  model->SetLayout(q);
  const LabelerOutput a = model->forward(points);
  const LabelerOutput b =
      model->ForwardSlots(points, LabelSlots{q.expand({3, 4, kWidth}), {}});
  EXPECT_TRUE(torch::allclose(a.log_assignment, b.log_assignment, kTol, kTol));
  // A smaller layout (a layout given at label time): its 3 labels fill the
  // first slots, the fourth is padded, as ForwardSlots with a mask.
  model->SetLayout(q.narrow(0, 0, 3));
  const LabelerOutput c = model->forward(points);
  const torch::Tensor padded =
      torch::cat({q.narrow(0, 0, 3), torch::zeros({1, kWidth})});
  const torch::Tensor mask = torch::tensor({true, true, true, false});
  const LabelerOutput d = model->ForwardSlots(
      points, LabelSlots{padded.expand({3, 4, kWidth}), mask.expand({3, 4})});
  EXPECT_TRUE(torch::allclose(c.log_assignment, d.log_assignment, kTol, kTol));
  EXPECT_FALSE(torch::allclose(c.log_assignment, a.log_assignment, kTol, kTol));
  EXPECT_TRUE(c.label_ids.ne(3).all().item<bool>());  // never the padded slot
  model->SetLayout(q);
  // The layout travels with the module's state (checkpoints).
  std::set<std::string> buffers;
  for (const auto& item : model->named_buffers()) buffers.insert(item.key());
  EXPECT_EQ(buffers.count("layout_descriptors"), 1u);
}

TEST(ConditionedLabeler, PointLabelAttentionKeepsTheLayoutContract) {
  torch::manual_seed(22);
  Labeler model = SmallConditionedLabeler(7, 35, 0.0, /*cross_layers=*/2);
  ASSERT_EQ(model->label_head->cross.size(), 2u);
  torch::NoGradGuard no_grad;
  model->eval();
  const torch::Tensor points = torch::randn({3, 10, 3});
  const torch::Tensor q = RandomDescriptors(3, 7);
  torch::Tensor mask = torch::ones({3, 7}, torch::kBool);
  mask.index_put_({0, torch::indexing::Slice(4, 7)}, false);
  mask.index_put_({2, 1}, false);
  // Untrained, the layers add nothing (their merge starts at zero): the
  // scores are the bilinear ones.
  const LabelerOutput init = model->ForwardSlots(points, LabelSlots{q, mask});
  {
    const torch::Tensor labels =
        model->label_encoder->EncodeSlots(q, mask);  // B x D x L
    const torch::Tensor bilinear =
        torch::matmul(init.point_keys.transpose(1, 2),
                      model->label_head->label_proj(labels)) *
        (model->label_head->log_scale.exp() / std::sqrt(12.0));
    EXPECT_TRUE(torch::allclose(
        init.scores,
        bilinear.masked_fill(mask.logical_not().unsqueeze(1), kPaddedSlotScore),
        kTol,
        kTol));
  }
  for (PointLabelAttention& layer : model->label_head->cross) {
    layer->merge->weight.normal_(0.0, 0.3);
    layer->merge->bias.normal_(0.0, 0.1);
  }
  const LabelerOutput a = model->ForwardSlots(points, LabelSlots{q, mask});
  EXPECT_GT((a.scores - init.scores).abs().max().item<double>(), 1e-3);
  // Permuting the layout permutes the columns (the attention pools over
  // the labels, whatever their order).
  const torch::Tensor perm = torch::randperm(7);
  const LabelerOutput b = model->ForwardSlots(
      points, LabelSlots{q.index_select(1, perm), mask.index_select(1, perm)});
  EXPECT_TRUE(
      torch::allclose(b.scores, a.scores.index_select(2, perm), kTol, kTol));
  // What a padded slot holds does not reach the points.
  torch::Tensor garbage = q.clone();
  garbage.index_put_({0, torch::indexing::Slice(4, 7)},
                     100 * torch::randn({3, kWidth}));
  garbage.index_put_({2, 1}, -50 * torch::ones({kWidth}));
  const LabelerOutput c =
      model->ForwardSlots(points, LabelSlots{garbage, mask});
  EXPECT_TRUE(torch::allclose(a.log_assignment, c.log_assignment, kTol, kTol));
  // The held layout (1 x L x Q) gives each frame what the repeated layout
  // gives it.
  model->SetLayout(q[1]);
  const LabelerOutput held = model->forward(points);
  const LabelerOutput repeated = model->ForwardSlots(
      points, LabelSlots{q[1].unsqueeze(0).expand({3, 7, kWidth}), {}});
  EXPECT_TRUE(torch::allclose(held.scores, repeated.scores, kTol, kTol));
}

TEST(ConditionedLabeler, PositionLossIsTheMeanSquaredErrorOfLabelledPoints) {
  torch::manual_seed(21);
  const int64_t b = 2, n = 5, l = 4;
  const double weight = 2.5;
  Labeler model = SmallConditionedLabeler(l, 35, weight);
  ASSERT_TRUE(model->position_head);
  model->to(torch::kDouble);
  const torch::Tensor keys = torch::randn({b, 12, n}, torch::kDouble);
  const LabelSlots slots{torch::randn({b, l, kWidth}, torch::kDouble),
                         torch::ones({b, l}, torch::kBool)};
  // Frame 0: points 0, 2 and 4 carry labels 3, 0 and 3 (a label may repeat:
  // the loss does not check assignments), 1 and 3 are null (id L); frame 1
  // has no labelled point and adds nothing.
  const torch::Tensor labels =
      torch::tensor(std::vector<int64_t>{3, l, 0, l, 3, l, l, l, l, l})
          .view({b, n});
  const torch::Tensor value = model->PositionLoss(keys, slots, labels);
  // By hand: P k + c per point, against the slot's descriptor columns 0-2.
  const torch::Tensor w = model->position_head->weight.squeeze(2);  // 3 x D
  const torch::Tensor c = model->position_head->bias;
  double sum = 0.0;
  const int64_t points[] = {0, 2, 4};
  for (int64_t i : points) {
    const int64_t label = labels[0][i].item<int64_t>();
    const torch::Tensor predicted = w.matmul(keys[0].select(1, i)) + c;
    const torch::Tensor target = slots.descriptors[0][label].narrow(0, 0, 3);
    sum += (predicted - target).square().sum().item<double>();
  }
  EXPECT_NEAR(value.item<double>(), weight * sum / 3.0, 1e-12);
  // The held layout (1 x L x Q, shared by the frames) gives the same value
  // as the layout repeated per frame.
  LabelSlots one{slots.descriptors.narrow(0, 0, 1), torch::Tensor()};
  LabelSlots repeated{one.descriptors.expand({b, l, kWidth}).contiguous(),
                      torch::Tensor()};
  EXPECT_NEAR(model->PositionLoss(keys, one, labels).item<double>(),
              model->PositionLoss(keys, repeated, labels).item<double>(),
              1e-12);
  // No weight, no loss and no head.
  Labeler plain = SmallConditionedLabeler(l);
  EXPECT_FALSE(plain->position_head);
  EXPECT_FALSE(
      plain
          ->PositionLoss(
              keys.to(torch::kFloat),
              LabelSlots{slots.descriptors.to(torch::kFloat), slots.mask},
              labels)
          .defined());
  // Only a conditioned labeller takes a weight.
  LabelerOptions options;
  options.num_labels = 4;
  options.position_loss = 1.0;
  EXPECT_THROW(options.Validate(), ConfigError);
}

TEST(ConditionedLabeler, PlainModelRejectsSlots) {
  LabelerOptions options;
  options.num_labels = 41;
  options.d_model = 12;
  options.hidden = 16;
  SelfAttentionOptions attention;
  attention.d_model = 12;
  attention.num_layers = 1;
  attention.num_heads = 3;
  Labeler plain(options, SelfAttention(attention).ptr(), Sinkhorn().ptr());
  EXPECT_FALSE(plain->conditioned());
  const std::string message = testing::ErrorMessage<ConfigError>([&] {
    plain->ForwardSlots(torch::randn({1, 5, 3}),
                        LabelSlots{RandomDescriptors(1, 41), {}});
  });
  EXPECT_NE(message.find("fixed layout of 41 labels"), std::string::npos)
      << message;
  EXPECT_THROW(plain->SetLayout(RandomDescriptors(1, 41)[0]), ConfigError);
}

TEST(BuildLabeler, SomaAnyLayoutFromConfig) {
  ConfigNode model = LoadConfig("model/soma_any_layout.yaml");
  model.SetPath("d_model", ConfigNode(int64_t{10}));
  model.SetPath("hidden", ConfigNode(int64_t{8}));
  model.SetPath("backbone.num_layers", ConfigNode(int64_t{1}));
  model.SetPath("backbone.num_heads", ConfigNode(int64_t{2}));
  model.SetPath("label_encoder.num_heads", ConfigNode(int64_t{2}));
  const ConfigNode norm = LoadConfig("normalization/sinkhorn.yaml");
  Labeler labeler = BuildLabeler(model, norm, 6);
  EXPECT_TRUE(labeler->conditioned());
  BuildContext ctx;
  EXPECT_TRUE(Instantiate<ModelSpec>(model, ctx)->conditioned());
  EXPECT_FALSE(Instantiate<ModelSpec>(LoadConfig("model/soma.yaml"), ctx)
                   ->conditioned());
  EXPECT_EQ(labeler->descriptor_width(), kWidth);
  std::set<std::string> prefixes;
  for (const auto& p : labeler->named_parameters()) {
    prefixes.insert(p.key().substr(0, p.key().find('.')));
  }
  EXPECT_EQ(prefixes,
            (std::set<std::string>{"encoder",
                                   "backbone",
                                   "label_encoder",
                                   "label_head",
                                   "normalization"}));
  // Neither the parameter count nor the names depend on L (no per-label
  // output layer).
  EXPECT_EQ(CountTrainableParameters(*labeler),
            CountTrainableParameters(*BuildLabeler(model, norm, 90)));
  // Invalid options are one-line ConfigErrors.
  EXPECT_THROW(
      BuildLabeler(model, LoadConfig("normalization/log_softmax.yaml"), 6),
      ConfigError);
  ConfigNode bad = model;
  bad.SetPath("label_encoder.num_heads", ConfigNode(int64_t{3}));
  EXPECT_THROW(BuildLabeler(bad, norm, 6), ConfigError);
  bad = model;
  bad.SetPath("label_encoder.depth", ConfigNode(int64_t{3}));
  EXPECT_THROW(BuildLabeler(bad, norm, 6), ConfigError);
  // `path` set to `value` is a one-line ConfigError naming its key.
  auto expect_one_line_error = [&](const std::string& path,
                                   const ConfigNode& value,
                                   const std::string& key) {
    ConfigNode invalid = model;
    invalid.SetPath(path, value);
    const std::string message = testing::ErrorMessage<ConfigError>(
        [&] { BuildLabeler(invalid, norm, 6); });
    EXPECT_NE(message.find(key), std::string::npos) << message;
    EXPECT_EQ(message.find('\n'), std::string::npos) << message;
  };
  expect_one_line_error(
      "label_encoder.fourier_bands", ConfigNode(int64_t{-2}), "fourier_bands");
  // Fourier features widen the first layer of the descriptor MLP only:
  // 6F more inputs of its `hidden` units.
  ConfigNode fourier = model;
  fourier.SetPath("label_encoder.fourier_bands", ConfigNode(int64_t{4}));
  EXPECT_EQ(CountTrainableParameters(*BuildLabeler(fourier, norm, 6)),
            CountTrainableParameters(*labeler) +
                24 * model.at("label_encoder").at("hidden").AsInt());
  // Rest-offset biases: per label self-attention layer an MLP 4 -> R ->
  // heads; a negative width is a one-line error.
  ConfigNode relative = model;
  relative.SetPath("label_encoder.relative_bias", ConfigNode(int64_t{8}));
  const int64_t heads = model.at("label_encoder").at("num_heads").AsInt();
  const int64_t label_layers =
      model.at("label_encoder").at("num_layers").AsInt();
  EXPECT_EQ(CountTrainableParameters(*BuildLabeler(relative, norm, 6)),
            CountTrainableParameters(*labeler) +
                label_layers * (4 * 8 + 8 + 8 * heads + heads));
  expect_one_line_error(
      "label_encoder.relative_bias", ConfigNode(int64_t{-1}), "relative_bias");
  // The position loss adds a linear map of the point keys to 3 coordinates,
  // and only when it is weighted; a negative weight is a one-line error.
  ConfigNode position = model;
  position.SetPath("position_loss", ConfigNode(0.5));
  Labeler positioned = BuildLabeler(position, norm, 6);
  EXPECT_EQ(positioned->options().position_loss, 0.5);
  EXPECT_EQ(CountTrainableParameters(*positioned),
            CountTrainableParameters(*labeler) + 10 * 3 + 3);
  EXPECT_FALSE(labeler->position_head);
  expect_one_line_error("position_loss", ConfigNode(-1.0), "position_loss");
  // Point-label attention layers: 4 convolutions D -> D each.
  ConfigNode cross = model;
  cross.SetPath("cross_layers", ConfigNode(int64_t{2}));
  EXPECT_EQ(CountTrainableParameters(*BuildLabeler(cross, norm, 6)),
            CountTrainableParameters(*labeler) + 2 * 4 * (10 * 10 + 10));
  bad = model;
  bad.SetPath("cross_layers", ConfigNode(int64_t{-1}));
  EXPECT_THROW(BuildLabeler(bad, norm, 6), ConfigError);
  // The plain model is unchanged: no label branch, a fixed head.
  ConfigNode soma = LoadConfig("model/soma.yaml");
  Labeler plain = BuildLabeler(soma, norm, 41);
  EXPECT_FALSE(plain->conditioned());
  EXPECT_EQ(CountTrainableParameters(*plain), 1425180 + 251 * 41);
}

}  // namespace
}  // namespace soma
