// The optimised inference path must match the libtorch forward (eval mode)
// to 1e-4, for every supported architecture, kernel ISA and threading mode.
#include "framework/model/fast_labeler.h"

#include "framework/core/error.h"
#include "framework/model/fast_kernels.h"
#include "framework/model/label_encoder.h"
#include "framework/model/labeler.h"
#include "framework/model/torch_utils.h"

#include <gtest/gtest.h>
#include <torch/torch.h>

#include "tests/model/conditioned_labeler.h"
#include <cmath>
#include <limits>
#include <vector>

namespace soma {
namespace {

using internal::KernelIsa;

constexpr double kTol = 1e-4;

/// Random parameters and BatchNorm statistics everywhere, so that no folding
/// step can hide behind identity BN or zero biases.
void Randomize(LabelerImpl& model, double bin_score) {
  torch::NoGradGuard no_grad;
  for (auto& item : model.named_parameters()) {
    // Small noise: BN scales stay near 1, zero-initialised biases become
    // non-zero.
    torch::Tensor p = item.value();
    p.add_(torch::randn_like(p) * 0.05);
  }
  for (auto& item : model.named_buffers()) {
    torch::Tensor b = item.value();
    if (item.key().find("running_mean") != std::string::npos)
      b.copy_(torch::randn_like(b) * 0.2);
    if (item.key().find("running_var") != std::string::npos) {
      b.copy_(torch::rand_like(b) * 1.5 + 0.5);
    }
  }
  if (auto* sinkhorn = model.normalization->as<SinkhornImpl>()) {
    sinkhorn->bin_score.fill_(bin_score);
  }
}

Labeler MakeModel(bool attention,
                  bool sinkhorn,
                  int64_t d,
                  int64_t layers,
                  int64_t heads,
                  int64_t hidden,
                  int64_t num_labels,
                  int iters = 35) {
  LabelerOptions options;
  options.num_labels = num_labels;
  options.d_model = d;
  options.hidden = hidden;
  std::shared_ptr<BackboneImpl> backbone;
  if (attention) {
    SelfAttentionOptions o;
    o.d_model = d;
    o.num_layers = layers;
    o.num_heads = heads;
    backbone = SelfAttention(o).ptr();
  } else {
    Conv1dBackboneOptions o;
    o.d_model = d;
    o.num_layers = layers;
    o.hidden = hidden;
    backbone = Conv1dBackbone(o).ptr();
  }
  std::shared_ptr<NormalizationImpl> norm;
  if (sinkhorn) {
    SinkhornOptions o;
    o.num_iters = iters;
    norm = Sinkhorn(o).ptr();
  } else {
    norm = LogSoftmax().ptr();
  }
  Labeler model(options, backbone, norm);
  Randomize(*model, 0.7);
  model->eval();
  return model;
}

/// Frames with missing (zero) points and a zero-padded tail.
torch::Tensor MakePoints(int64_t batch, int64_t n) {
  torch::Tensor points = torch::randn({batch, n, 3}) * 0.5;
  for (int64_t b = 0; b < batch; ++b) {
    points[b][(b * 3) % n].zero_();
    if (n > 4) points[b][n - 1].zero_();
  }
  return points;
}

void ExpectMatches(Labeler& model,
                   const FastLabeler& fast,
                   const torch::Tensor& points) {
  torch::NoGradGuard no_grad;
  const LabelerOutput expected = model(points);
  const LabelerOutput actual = fast.Forward(points);
  ASSERT_EQ(actual.log_assignment.sizes(), expected.log_assignment.sizes());
  EXPECT_TRUE(torch::allclose(actual.scores, expected.scores, kTol, kTol))
      << (actual.scores - expected.scores).abs().max().item<float>();
  EXPECT_TRUE(torch::allclose(
      actual.log_assignment, expected.log_assignment, kTol, kTol))
      << (actual.log_assignment - expected.log_assignment)
             .abs()
             .max()
             .item<float>();
  EXPECT_TRUE(torch::allclose(
      actual.label_confidence, expected.label_confidence, kTol, kTol));
  // Label ids agree wherever the top two confidences are not a near tie.
  const torch::Tensor top2 = std::get<0>(expected.label_confidence.topk(2, -1));
  const torch::Tensor clear =
      (top2.select(-1, 0) - top2.select(-1, 1)).gt(1e-3);
  EXPECT_TRUE(actual.label_ids.eq(expected.label_ids)
                  .logical_or(clear.logical_not())
                  .all()
                  .item<bool>());
}

std::vector<KernelIsa> Isas() {
  std::vector<KernelIsa> isas = {KernelIsa::kPortable};
  if (internal::ResolveIsa(KernelIsa::kAuto) == KernelIsa::kAvx512) {
    isas.push_back(KernelIsa::kAvx512);
  }
  return isas;
}

TEST(FastLabeler, MatchesTorchSelfAttentionSinkhorn) {
  torch::manual_seed(11);
  Labeler model = MakeModel(true, true, 20, 2, 4, 24, 7);
  const torch::Tensor points = MakePoints(5, 13);
  for (KernelIsa isa : Isas()) {
    FastLabelerOptions options;
    options.isa = isa;
    options.frames_per_block = 2;
    const FastLabeler fast(*model, options);
    ExpectMatches(model, fast, points);
    // More points than one 48-key tile; a multiple of 16; after the above
    // (reused scratch of another size).
    ExpectMatches(model, fast, MakePoints(2, 70));
    ExpectMatches(model, fast, MakePoints(2, 32));
  }
}

TEST(FastLabeler, MatchesTorchLogSoftmaxAndConvBackbone) {
  torch::manual_seed(12);
  Labeler log_softmax = MakeModel(true, false, 18, 2, 3, 20, 6);
  Labeler conv_ot = MakeModel(false, true, 16, 2, 1, 20, 5);
  Labeler conv_ls = MakeModel(false, false, 16, 1, 1, 12, 4);
  const torch::Tensor points = MakePoints(3, 21);
  for (KernelIsa isa : Isas()) {
    FastLabelerOptions options;
    options.isa = isa;
    ExpectMatches(log_softmax, FastLabeler(*log_softmax, options), points);
    ExpectMatches(conv_ot, FastLabeler(*conv_ot, options), points);
    ExpectMatches(conv_ls, FastLabeler(*conv_ls, options), points);
  }
}

TEST(FastLabeler, MatchesTorchAtThePaperConfiguration) {
  // d_model 125, 8 layers, 5 heads, 35 Sinkhorn iterations, L = 41, N = 44.
  torch::manual_seed(13);
  Labeler model = MakeModel(true, true, 125, 8, 5, 256, 41);
  const torch::Tensor points = MakePoints(3, 44);
  FastLabeler fast(*model);
  ExpectMatches(model, fast, points);
  EXPECT_EQ(fast.num_labels(), 41);
  EXPECT_TRUE(fast.has_dustbin_row());
}

TEST(FastLabeler, MatchesTorchForTheLayoutConditionedLabeler) {
  // model=soma_any_layout: 9 label slots, a held layout of 6 labels (3
  // padded slots), random parameters and statistics in the label branch too.
  torch::manual_seed(15);
  Labeler model = testing::SmallConditionedLabeler(9);
  EXPECT_FALSE(FastLabeler::Supports(*model)) << "no layout held yet";
  Randomize(*model, 0.4);
  torch::Tensor descriptors =
      torch::randn({6, testing::kConditionedDescriptorWidth});
  model->SetLayout(descriptors);
  model->train();
  EXPECT_THROW(FastLabeler{*model}, InternalError) << "training mode";
  model->eval();
  ASSERT_TRUE(FastLabeler::Supports(*model));
  const torch::Tensor points = MakePoints(4, 15);
  for (KernelIsa isa : Isas()) {
    FastLabelerOptions options;
    options.isa = isa;
    const FastLabeler fast(*model, options);
    EXPECT_EQ(fast.num_labels(), 9);
    ExpectMatches(model, fast, points);
  }
  // A full layout (no padded slot), and the snapshot follows SetLayout only
  // when rebuilt.
  model->SetLayout(torch::randn({9, testing::kConditionedDescriptorWidth}));
  ExpectMatches(model, FastLabeler(*model), points);
}

TEST(FastLabeler, ThreadingModesAgree) {
  torch::manual_seed(14);
  Labeler model = MakeModel(true, true, 20, 2, 4, 16, 6);
  const int previous = TorchThreads();
  SetTorchThreads(2);
  FastLabelerOptions options;
  options.num_threads = 2;
  options.frames_per_block = 3;
  FastLabeler fast(*model, options);
  // Batch 1 splits panels and heads; batch 7 splits frames.
  ExpectMatches(model, fast, MakePoints(1, 17));
  ExpectMatches(model, fast, MakePoints(7, 17));
  // Repeated calls reuse workspaces and give identical results.
  const torch::Tensor points = MakePoints(4, 9);
  EXPECT_TRUE(torch::equal(fast.Forward(points).log_assignment,
                           fast.Forward(points).log_assignment));
  SetTorchThreads(previous);
}

TEST(FastLabeler, EmptyAndAllZeroFrames) {
  torch::manual_seed(15);
  Labeler model = MakeModel(true, true, 12, 1, 3, 8, 4);
  FastLabeler fast(*model);
  EXPECT_EQ(fast.Forward(torch::zeros({0, 5, 3})).label_ids.size(0), 0);
  ExpectMatches(model, fast, torch::zeros({2, 6, 3}));
}

TEST(FastKernels, GemmMatchesReference) {
  torch::manual_seed(16);
  for (KernelIsa isa : Isas()) {
    for (const auto& [rows, m, k] :
         std::vector<std::tuple<int64_t, int64_t, int64_t>>{
             {1, 1, 1}, {7, 17, 5}, {9, 48, 33}, {20, 50, 3}, {44, 125, 250}}) {
      SCOPED_TRACE(std::to_string(rows) + "x" + std::to_string(m) + "x" +
                   std::to_string(k));
      const torch::Tensor x = torch::randn({rows, k});
      const torch::Tensor w = torch::randn({m, k});
      const torch::Tensor b = torch::randn({m});
      const torch::Tensor residual = torch::randn({rows, m});
      const internal::PackedWeights packed =
          internal::PackWeights(w.data_ptr<float>(), b.data_ptr<float>(), m, k);
      const int64_t relu = m / 2;
      torch::Tensor expected = x.matmul(w.t()) + b + residual;
      expected.narrow(1, 0, relu).clamp_min_(0);
      // Output written in place over the residual (as the backbone does).
      torch::Tensor y = residual.clone();
      internal::GemmEpilogue ep;
      ep.residual = y.data_ptr<float>();
      ep.ld_residual = m;
      ep.relu_columns = relu;
      internal::Gemm(isa,
                     x.data_ptr<float>(),
                     k,
                     rows,
                     packed,
                     y.data_ptr<float>(),
                     m,
                     ep);
      EXPECT_TRUE(torch::allclose(y, expected, 1e-4, 1e-4));
    }
  }
}

TEST(FastKernels, SoftmaxAndAttentionHead) {
  torch::manual_seed(17);
  for (KernelIsa isa : Isas()) {
    // v rows must be readable for RoundUp16(dh) = 32 floats.
    const int64_t n = 19, dh = 21, ld = 2 * dh + 32 + 3;
    const torch::Tensor qkv = torch::randn({n, ld});
    const torch::Tensor q = qkv.narrow(1, 0, dh), k = qkv.narrow(1, dh, dh),
                        v = qkv.narrow(1, 2 * dh, dh);
    const torch::Tensor expected = torch::softmax(q.matmul(k.t()), 1).matmul(v);
    torch::Tensor out = torch::zeros({n, dh + 3});
    internal::AttentionScratch scratch;
    const float* base = qkv.data_ptr<float>();
    internal::AttentionHead(isa,
                            base,
                            base + dh,
                            base + 2 * dh,
                            ld,
                            n,
                            dh,
                            out.data_ptr<float>(),
                            dh + 3,
                            scratch);
    EXPECT_TRUE(torch::allclose(out.narrow(1, 0, dh), expected, 1e-5, 1e-5));
    EXPECT_EQ(out.narrow(1, dh, 3).abs().max().item<float>(), 0.0f);
    // Softmax with large magnitudes stays finite and normalised.
    torch::Tensor s = torch::randn({3, 40}) * 60;
    const torch::Tensor s_expected = torch::softmax(s.narrow(1, 0, 37), 1);
    internal::SoftmaxRows(isa, s.data_ptr<float>(), 40, 3, 37);
    EXPECT_TRUE(torch::allclose(s.narrow(1, 0, 37), s_expected, 1e-5, 1e-6));
  }
}

TEST(FastKernels, AttentionProbsAndScoresGradMatchReference) {
  // Row lengths below, at and above one 16-lane vector, the paper's 44, the
  // fused path's limit (48) and one past it (the GEMM + softmax path).
  torch::manual_seed(21);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (KernelIsa isa : Isas()) {
    for (const int64_t n : {5, 16, 19, 44, 48, 53}) {
      SCOPED_TRACE("n=" + std::to_string(n));
      const int64_t dh = 25, ld = internal::RoundUp16(n) + 3;
      const float scale = 0.2f;
      const torch::Tensor q = torch::randn({n, dh});
      const torch::Tensor k = torch::randn({n, dh}) * 2;
      const torch::Tensor v = torch::randn({n, dh});
      const torch::Tensor dout = torch::randn({n, dh});
      // Transposed keys and values; the padding lanes past n hold NaN (they
      // are read but must not reach a result).
      torch::Tensor kt = torch::full({dh, ld}, nan);
      kt.narrow(1, 0, n).copy_(k.t());
      torch::Tensor vt = torch::full({dh, ld}, nan);
      vt.narrow(1, 0, n).copy_(v.t());
      torch::Tensor p = torch::full({n, ld}, 7.0f);
      internal::AttentionProbs(isa,
                               q.data_ptr<float>(),
                               dh,
                               kt.data_ptr<float>(),
                               ld,
                               n,
                               dh,
                               scale,
                               p.data_ptr<float>(),
                               ld);
      const torch::Tensor qd = q.to(torch::kDouble);
      const torch::Tensor expected_p =
          torch::softmax(qd.matmul(k.to(torch::kDouble).t()) * scale, 1);
      EXPECT_TRUE(torch::allclose(
          p.narrow(1, 0, n).to(torch::kDouble), expected_p, 1e-5, 1e-6));
      EXPECT_TRUE(p.narrow(1, n, ld - n).eq(7.0f).all().item<bool>());
      torch::Tensor ds = torch::full({n, ld}, 7.0f);
      internal::AttentionScoresGrad(isa,
                                    dout.data_ptr<float>(),
                                    dh,
                                    vt.data_ptr<float>(),
                                    ld,
                                    p.data_ptr<float>(),
                                    ld,
                                    n,
                                    dh,
                                    scale,
                                    ds.data_ptr<float>(),
                                    ld);
      const torch::Tensor pd = p.narrow(1, 0, n).to(torch::kDouble);
      const torch::Tensor dp =
          dout.to(torch::kDouble).matmul(v.to(torch::kDouble).t());
      const torch::Tensor expected_ds =
          pd * (dp - (dp * pd).sum(1, true)) * scale;
      EXPECT_TRUE(torch::allclose(
          ds.narrow(1, 0, n).to(torch::kDouble), expected_ds, 1e-5, 1e-5))
          << (ds.narrow(1, 0, n).to(torch::kDouble) - expected_ds)
                 .abs()
                 .max()
                 .item<double>();
      EXPECT_TRUE(ds.narrow(1, n, ld - n).eq(7.0f).all().item<bool>());
    }
  }
}

TEST(FastKernels, SinkhornScalingAndLogDomainAgree) {
  // Moderate scores take the scaling branch; a 300-nat spread forces the
  // log-domain branch; padded label slots (kPaddedSlotScore, a layout-
  // conditioned labeller's) take the scaling branch with exact zeros in the
  // kernel (kSinkhornUnderflowNats). All must match LogOptimalTransport in
  // double.
  torch::manual_seed(18);
  for (double spread : {3.0, 300.0, -3.0}) {
    const bool padded = spread < 0;
    spread = std::abs(spread);
    const int64_t n = 9, l = 6;
    torch::Tensor scores = torch::randn({n, l}) * spread / 6.0;
    scores[0][0] = spread / 2;
    scores[1][1] = -spread / 2;
    if (padded) {
      scores.select(1, 2).fill_(kPaddedSlotScore);
      scores.select(1, 5).fill_(kPaddedSlotScore);
    }
    const torch::Tensor expected =
        LogOptimalTransport(scores.to(torch::kDouble).unsqueeze(0),
                            torch::tensor(0.4, torch::kDouble),
                            20)[0];
    for (KernelIsa isa : Isas()) {
      std::vector<float> out(static_cast<size_t>((n + 1) * (l + 1)));
      std::vector<double> scratch;
      internal::SinkhornFrame(
          isa, scores.data_ptr<float>(), l, n, l, 0.4, 20, out.data(), scratch);
      const torch::Tensor actual =
          torch::from_blob(out.data(), {n + 1, l + 1}).to(torch::kDouble);
      EXPECT_TRUE(torch::allclose(actual, expected, 1e-5, 1e-4 * spread / 3))
          << spread << ": " << (actual - expected).abs().max().item<double>();
    }
  }
}

TEST(FastKernels, VectorisedExp) {
  const torch::Tensor x = torch::linspace(-100.0, 80.0, 1001, torch::kDouble);
  for (KernelIsa isa : Isas()) {
    torch::Tensor d = x.clone();
    internal::ExpInPlace(isa, d.data_ptr<double>(), d.numel());
    EXPECT_TRUE(torch::allclose(d, x.exp(), 1e-13, 0));
    torch::Tensor f = x.to(torch::kFloat);
    internal::ExpInPlace(isa, f.data_ptr<float>(), f.numel());
    EXPECT_TRUE(torch::allclose(f, x.to(torch::kFloat).exp(), 1e-6, 1e-38));
  }
}

TEST(FastKernels, MedianOffsetIsTheLowerMedian) {
  const float points[5][3] = {
      {3, 1, 0}, {0, 0, 0}, {1, 5, 2}, {2, 2, 9}, {4, 3, -1}};
  float offset[3];
  internal::MedianOffset(&points[0][0], 5, offset);
  EXPECT_EQ(offset[0], 2.0f);  // {3,1,2,4} -> lower median 2
  EXPECT_EQ(offset[1], 2.0f);  // {1,5,2,3} -> 2
  EXPECT_EQ(offset[2], 0.0f);  // {0,2,9,-1} -> 0
  const float zeros[2][3] = {};
  internal::MedianOffset(&zeros[0][0], 2, offset);
  EXPECT_EQ(offset[0], 0.0f);
  EXPECT_EQ(offset[2], 0.0f);
}

}  // namespace
}  // namespace soma
