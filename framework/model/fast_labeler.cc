#include "framework/model/fast_labeler.h"

#include "framework/core/error.h"
#include "framework/model/labeler.h"
#include "framework/model/torch_utils.h"

#include <ATen/Parallel.h>
#include <fmt/format.h>
#include <torch/torch.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <mutex>
#include <utility>
#include <vector>

namespace soma {
namespace {

using internal::AlignedFloats;
using internal::AttentionScratch;
using internal::GemmEpilogue;
using internal::KernelIsa;
using internal::PackedWeights;
using internal::RoundUp16;

// ---------------------------------------------------------------------------
// Weight folding (double precision, then packed as float).

/// y = w x + b with `w`: M x K, `b`: M (double tensors).
struct Affine {
  torch::Tensor w;
  torch::Tensor b;
};

Affine ConvAffine(const torch::nn::Conv1d& conv) {
  SOMA_CHECK(conv->weight.dim() == 3 && conv->weight.size(2) == 1)
      << "FastLabeler supports kernel-size-1 convolutions only";
  Affine a;
  a.w = conv->weight.detach().to(torch::kDouble).squeeze(-1);
  a.b = conv->bias.defined() ? conv->bias.detach().to(torch::kDouble)
                             : torch::zeros({a.w.size(0)}, torch::kDouble);
  return a;
}

/// BatchNorm (running statistics) after `a`: y = s (w x + b - mean) + beta.
Affine FoldBatchNorm(const Affine& a, const torch::nn::BatchNorm1d& bn) {
  SOMA_CHECK(bn->running_mean.defined() && bn->running_var.defined())
      << "FastLabeler needs BatchNorm running statistics";
  const torch::Tensor mean = bn->running_mean.detach().to(torch::kDouble);
  const torch::Tensor var = bn->running_var.detach().to(torch::kDouble);
  torch::Tensor scale = torch::rsqrt(var + bn->options.eps());
  torch::Tensor shift = torch::zeros_like(mean);
  if (bn->weight.defined())
    scale = scale * bn->weight.detach().to(torch::kDouble);
  if (bn->bias.defined()) shift = bn->bias.detach().to(torch::kDouble);
  return {a.w * scale.unsqueeze(1), scale * (a.b - mean) + shift};
}

PackedWeights Pack(const Affine& a) {
  const torch::Tensor w = a.w.to(torch::kFloat).contiguous();
  const torch::Tensor b = a.b.to(torch::kFloat).contiguous();
  return internal::PackWeights(
      w.data_ptr<float>(), b.data_ptr<float>(), w.size(0), w.size(1));
}

/// The layout-conditioned score head's point projection and its product with
/// the held layout's label keys as one classifier (model=soma_any_layout): the
/// torch forward computes S = s (F W_p^T + b_p) K with K = label_proj(E) the
/// keys of the layout's label embeddings E and s = exp(log_scale) / sqrt(D);
/// at inference the layout is fixed, so S = F (s K^T W_p)^T + s K^T b_p, one
/// GEMM of L rows like the fixed head's classifier. Padded slots get w = 0
/// and b = kPaddedSlotScore, the torch forward's masked_fill.
Affine ConditionedClassifier(const LabelerImpl& model) {
  SOMA_CHECK(!model.is_training())
      << "FastLabeler: a layout-conditioned labeler must be in eval mode";
  // Eval mode: the label branch's forward reads its parameters and running
  // statistics and writes nothing, so the const snapshot holds.
  auto& labeler = const_cast<LabelerImpl&>(model);
  const LabelSlots slots = labeler.LayoutSlots();
  const torch::Tensor mask = CheckLabelSlots(
      slots, model.num_labels(), model.descriptor_width(), 1);  // 1 x L
  const torch::Tensor embeddings = labeler.label_encoder(
      slots.descriptors.to(torch::kFloat), mask);  // 1 x D x L
  const torch::Tensor keys = labeler.label_head->label_proj(embeddings)
                                 .squeeze(0)
                                 .to(torch::kDouble);  // D x L
  const double scale = std::exp(model.label_head->log_scale.item<double>()) /
                       std::sqrt(static_cast<double>(model.options().d_model));
  const Affine point_proj = ConvAffine(model.label_head->point_proj);
  Affine classifier;
  classifier.w = keys.t().matmul(point_proj.w) * scale;  // L x 2D
  classifier.b = keys.t().matmul(point_proj.b) * scale;  // L
  const torch::Tensor padded = mask.squeeze(0).logical_not();
  classifier.w.index_put_({padded}, 0.0);
  classifier.b.index_put_({padded}, kPaddedSlotScore);
  return classifier;
}

/// A ResConv1DBlock as two GEMMs: first = [conv1+BN ; shortcut+BN] on the
/// input (ReLU on the first `hidden` outputs), second = conv2+BN on the
/// hidden part with the shortcut part as residual.
struct FoldedResBlock {
  int64_t hidden = 0;
  int64_t out = 0;
  PackedWeights first;
  PackedWeights second;
};

FoldedResBlock FoldResBlock(const ResConv1DBlockImpl& block) {
  const Affine first = FoldBatchNorm(ConvAffine(block.conv1), block.bn1);
  const Affine second = FoldBatchNorm(ConvAffine(block.conv2), block.bn2);
  Affine shortcut;
  if (block.has_shortcut_conv()) {
    shortcut =
        FoldBatchNorm(ConvAffine(block.shortcut_conv), block.shortcut_bn);
  } else {
    shortcut = {torch::eye(block.out_channels(), torch::kDouble),
                torch::zeros({block.out_channels()}, torch::kDouble)};
  }
  FoldedResBlock folded;
  folded.hidden = first.w.size(0);
  folded.out = second.w.size(0);
  folded.first = Pack({torch::cat({first.w, shortcut.w}, 0),
                       torch::cat({first.b, shortcut.b})});
  folded.second = Pack(second);
  return folded;
}

struct FoldedAttentionLayer {
  PackedWeights qkv;  // 3D x D, head-major, q pre-scaled
  PackedWeights mix;  // 2D x 2D on [o | x], BN folded, ReLU after
  PackedWeights out;  // D x 2D, residual
};

FoldedAttentionLayer FoldAttentionLayer(const MultiHeadAttentionImpl& mha) {
  const int64_t d = mha.d_model();
  const int64_t h = mha.num_heads();
  const int64_t dh = d / h;
  // Head-major row r = head * dh + j comes from interleaved channel j*h+head.
  std::vector<int64_t> order(static_cast<size_t>(d));
  for (int64_t head = 0; head < h; ++head) {
    for (int64_t j = 0; j < dh; ++j)
      order[static_cast<size_t>(head * dh + j)] = j * h + head;
  }
  const torch::Tensor index = torch::tensor(order, torch::kLong);
  const double scale = 1.0 / std::sqrt(static_cast<double>(dh));
  const Affine q = ConvAffine(mha.query);
  const Affine k = ConvAffine(mha.key);
  const Affine v = ConvAffine(mha.value);
  FoldedAttentionLayer folded;
  folded.qkv = Pack({torch::cat({q.w.index_select(0, index) * scale,
                                 k.w.index_select(0, index),
                                 v.w.index_select(0, index)},
                                0),
                     torch::cat({q.b.index_select(0, index) * scale,
                                 k.b.index_select(0, index),
                                 v.b.index_select(0, index)})});
  const Affine merge = ConvAffine(mha.merge);
  const Affine post1 = ConvAffine(mha.post_conv1);
  const torch::Tensor w1a = post1.w.narrow(1, 0, d);
  const torch::Tensor w1b = post1.w.narrow(1, d, d);
  const torch::Tensor merge_w =
      merge.w.index_select(1, index);  // head-major inputs
  const Affine mix{torch::cat({w1a.mm(merge_w), w1b}, 1),
                   w1a.mv(merge.b) + post1.b};
  folded.mix = Pack(FoldBatchNorm(mix, mha.post_bn));
  folded.out = Pack(ConvAffine(mha.post_conv2));
  return folded;
}

struct FoldedConvBlock {
  FoldedResBlock expand;  // D -> wide, ReLU after
  PackedWeights reduce;   // wide -> D, BN folded, ReLU after
  PackedWeights out;      // D -> D, residual
};

/// Per-call buffers of one thread (grow-only; reused through the pool).
struct Workspace {
  AlignedFloats points;  // rows x 3, centred
  AlignedFloats xb;      // rows x ld_xb: [attention output o | features x]
  AlignedFloats qkv;     // rows x ld_qkv
  AlignedFloats z;       // rows x ld_z
  AlignedFloats hs;      // rows x ld_hs: ResConv1DBlock [hidden | shortcut]
  AlignedFloats t;       // rows x ld_t (conv backbone inner width)
  AlignedFloats u;       // rows x ld_u
  AlignedFloats scores;  // rows x ld_scores
  AttentionScratch attention;
  std::vector<double> sinkhorn;
};

}  // namespace

struct FastLabeler::Impl {
  FastLabelerOptions options;
  KernelIsa isa = KernelIsa::kPortable;
  int64_t d = 0;
  int64_t num_labels = 0;
  int64_t score_columns = 0;
  bool sinkhorn = true;
  int num_iters = 0;
  double alpha = 0.0;
  bool attention = true;
  int64_t heads = 0;
  int64_t head_dim = 0;
  int64_t wide = 0;

  FoldedResBlock encoder;
  std::vector<FoldedAttentionLayer> layers;
  std::vector<FoldedConvBlock> blocks;
  FoldedResBlock head;
  PackedWeights classifier;

  // Row strides of the workspace buffers.
  int64_t ld_xb = 0, ld_qkv = 0, ld_z = 0, ld_hs = 0, ld_t = 0, ld_u = 0,
          ld_scores = 0;

  mutable std::mutex mutex;
  mutable std::vector<std::unique_ptr<Workspace>> pool;

  std::vector<std::unique_ptr<Workspace>> Acquire(size_t count) const {
    std::vector<std::unique_ptr<Workspace>> out;
    std::lock_guard<std::mutex> lock(mutex);
    while (out.size() < count) {
      if (pool.empty()) {
        out.push_back(std::make_unique<Workspace>());
      } else {
        out.push_back(std::move(pool.back()));
        pool.pop_back();
      }
    }
    return out;
  }
  void Release(std::vector<std::unique_ptr<Workspace>>& workspaces) const {
    std::lock_guard<std::mutex> lock(mutex);
    for (auto& w : workspaces) pool.push_back(std::move(w));
    workspaces.clear();
  }

  /// Runs a GEMM, splitting its output panels over threads if `parallel`.
  void RunGemm(bool parallel,
               const float* x,
               int64_t ldx,
               int64_t rows,
               const PackedWeights& w,
               float* y,
               int64_t ldy,
               const GemmEpilogue& ep = {}) const {
    if (!parallel) {
      internal::Gemm(isa, x, ldx, rows, w, y, ldy, ep);
      return;
    }
    at::parallel_for(0, w.num_panels(), 1, [&](int64_t begin, int64_t end) {
      internal::GemmPacked(isa, x, ldx, rows, w.view(), y, ldy, ep, begin, end);
    });
  }

  /// `y = ReLU?(block(x))`, using `ws.hs` for the hidden/shortcut part.
  void RunResBlock(bool parallel,
                   const FoldedResBlock& block,
                   const float* x,
                   int64_t ldx,
                   int64_t rows,
                   float* y,
                   int64_t ldy,
                   bool relu,
                   Workspace& ws) const {
    GemmEpilogue first;
    first.relu_columns = block.hidden;
    RunGemm(parallel, x, ldx, rows, block.first, ws.hs.data(), ld_hs, first);
    GemmEpilogue second;
    second.residual = ws.hs.data() + block.hidden;
    second.ld_residual = ld_hs;
    second.relu_columns = relu ? block.out : 0;
    RunGemm(parallel, ws.hs.data(), ld_hs, rows, block.second, y, ldy, second);
  }

  /// Runs frames [f0, f1) of `points` (`B x N x 3`) end to end. With
  /// `parallel`, GEMM panels, heads and frames are split over threads using
  /// `workspaces[thread]` scratch; otherwise everything uses workspaces[0].
  void RunFrames(const float* points,
                 int64_t n,
                 int64_t f0,
                 int64_t f1,
                 bool parallel,
                 Workspace* const* workspaces,
                 size_t num_workspaces,
                 float* scores_out,
                 float* log_assignment,
                 float* confidence,
                 int64_t* label_ids) const {
    Workspace& ws = *workspaces[0];
    // Per-thread scratch inside parallel regions.
    auto thread_workspace = [&]() -> Workspace& {
      const size_t thread = static_cast<size_t>(at::get_thread_num());
      return *workspaces[std::min(thread, num_workspaces - 1)];
    };
    const int64_t frames = f1 - f0;
    const int64_t rows = frames * n;
    if (rows == 0) return;
    const size_t r = static_cast<size_t>(rows);
    ws.points.Resize(r * 3);
    ws.xb.Resize(r * ld_xb);
    ws.qkv.Resize(attention ? r * ld_qkv : 0);
    ws.z.Resize(r * ld_z);
    ws.hs.Resize(r * ld_hs);
    ws.t.Resize(attention ? 0 : r * ld_t);
    ws.u.Resize(r * ld_u);
    ws.scores.Resize(r * ld_scores);

    // Median centring (REFERENCE 1.1).
    for (int64_t f = 0; f < frames; ++f) {
      const float* p = points + (f0 + f) * n * 3;
      float offset[3];
      internal::MedianOffset(p, n, offset);
      float* dst = ws.points.data() + f * n * 3;
      for (int64_t i = 0; i < n; ++i) {
        for (int c = 0; c < 3; ++c) dst[3 * i + c] = p[3 * i + c] - offset[c];
      }
    }
    // Encoder: ReLU(ResConv1DBlock(3 -> D)) into the x part of xb.
    float* x = ws.xb.data() + d;
    RunResBlock(parallel,
                encoder,
                ws.points.data(),
                3,
                rows,
                x,
                ld_xb,
                /*relu=*/true,
                ws);

    if (attention) {
      for (const FoldedAttentionLayer& layer : layers) {
        RunGemm(parallel, x, ld_xb, rows, layer.qkv, ws.qkv.data(), ld_qkv);
        auto run_heads = [&](int64_t begin,
                             int64_t end,
                             AttentionScratch& scratch) {
          for (int64_t task = begin; task < end; ++task) {
            const int64_t f = task / heads;
            const int64_t hd = task % heads;
            const float* base = ws.qkv.data() + f * n * ld_qkv + hd * head_dim;
            internal::AttentionHead(
                isa,
                base,
                base + d,
                base + 2 * d,
                ld_qkv,
                n,
                head_dim,
                ws.xb.data() + f * n * ld_xb + hd * head_dim,
                ld_xb,
                scratch);
          }
        };
        if (parallel) {
          at::parallel_for(
              0, frames * heads, 1, [&](int64_t begin, int64_t end) {
                run_heads(begin, end, thread_workspace().attention);
              });
        } else {
          run_heads(0, frames * heads, ws.attention);
        }
        GemmEpilogue mix;
        mix.relu_columns = 2 * d;
        RunGemm(parallel,
                ws.xb.data(),
                ld_xb,
                rows,
                layer.mix,
                ws.z.data(),
                ld_z,
                mix);
        GemmEpilogue residual;
        residual.residual = x;
        residual.ld_residual = ld_xb;
        RunGemm(
            parallel, ws.z.data(), ld_z, rows, layer.out, x, ld_xb, residual);
      }
    } else {
      for (const FoldedConvBlock& block : blocks) {
        RunResBlock(parallel,
                    block.expand,
                    x,
                    ld_xb,
                    rows,
                    ws.t.data(),
                    ld_t,
                    true,
                    ws);
        GemmEpilogue reduce;
        reduce.relu_columns = d;
        RunGemm(parallel,
                ws.t.data(),
                ld_t,
                rows,
                block.reduce,
                ws.u.data(),
                ld_u,
                reduce);
        GemmEpilogue residual;
        residual.residual = x;
        residual.ld_residual = ld_xb;
        RunGemm(
            parallel, ws.u.data(), ld_u, rows, block.out, x, ld_xb, residual);
      }
    }

    // Head: ReLU -> ResConv1DBlock(D -> 2D) -> ReLU -> classifier (1/sqrt(D)
    // folded in; a layout-conditioned head's point projection and label keys
    // are the classifier, ConditionedClassifier).
    for (int64_t i = 0; i < rows; ++i) {
      const float* src = x + i * ld_xb;
      float* dst = ws.u.data() + i * ld_u;
      for (int64_t c = 0; c < d; ++c) dst[c] = std::max(src[c], 0.0f);
    }
    RunResBlock(
        parallel, head, ws.u.data(), ld_u, rows, ws.z.data(), ld_z, true, ws);
    RunGemm(parallel,
            ws.z.data(),
            ld_z,
            rows,
            classifier,
            ws.scores.data(),
            ld_scores);

    // Normalization, confidences and label ids per frame.
    const int64_t cols = num_labels + 1;
    const int64_t out_rows = sinkhorn ? n + 1 : n;
    auto normalize = [&](int64_t begin,
                         int64_t end,
                         std::vector<double>& scratch) {
      for (int64_t f = begin; f < end; ++f) {
        const int64_t frame = f0 + f;
        const float* s = ws.scores.data() + f * n * ld_scores;
        float* so = scores_out + frame * n * score_columns;
        for (int64_t i = 0; i < n; ++i) {
          std::copy(s + i * ld_scores,
                    s + i * ld_scores + score_columns,
                    so + i * score_columns);
        }
        float* la = log_assignment + frame * out_rows * cols;
        if (sinkhorn) {
          internal::SinkhornFrame(
              isa, s, ld_scores, n, num_labels, alpha, num_iters, la, scratch);
        } else {
          internal::LogSoftmaxFrame(s, ld_scores, n, score_columns, la);
        }
        float* conf = confidence + frame * n * cols;
        int64_t* ids = label_ids + frame * n;
        for (int64_t i = 0; i < n; ++i) {
          const float* row = la + i * cols;
          int64_t best = 0;
          for (int64_t j = 1; j < cols; ++j) {
            if (row[j] > row[best]) best = j;
          }
          ids[i] = best;
        }
        std::copy(la, la + n * cols, conf);
        internal::ExpInPlace(isa, conf, n * cols);
      }
    };
    if (parallel) {
      at::parallel_for(0, frames, 1, [&](int64_t begin, int64_t end) {
        normalize(begin, end, thread_workspace().sinkhorn);
      });
    } else {
      normalize(0, frames, ws.sinkhorn);
    }
  }
};

bool FastLabeler::Supports(const LabelerImpl& model) {
  // A layout-conditioned labeler scores against the embeddings of the layout
  // it holds (ConditionedClassifier), with Sinkhorn, when its scores are
  // bilinear (no point-label attention); without a layout the torch forward
  // gives the error.
  if (model.conditioned()) {
    if (model.label_head.is_empty() || !model.label_head->Bilinear() ||
        dynamic_cast<const SinkhornImpl*>(model.normalization.get()) ==
            nullptr ||
        !model.HoldsLayout()) {
      return false;
    }
  } else if (model.head.is_empty()) {
    return false;
  }
  const bool backbone =
      dynamic_cast<const SelfAttentionImpl*>(model.backbone.get()) != nullptr ||
      dynamic_cast<const Conv1dBackboneImpl*>(model.backbone.get()) != nullptr;
  const bool norm =
      dynamic_cast<const SinkhornImpl*>(model.normalization.get()) != nullptr ||
      dynamic_cast<const LogSoftmaxImpl*>(model.normalization.get()) != nullptr;
  return backbone && norm;
}

FastLabeler::FastLabeler(const LabelerImpl& model,
                         const FastLabelerOptions& options)
    : impl_(std::make_unique<Impl>()) {
  SOMA_CHECK(Supports(model))
      << "FastLabeler: unsupported backbone or normalization";
  SOMA_CHECK(options.frames_per_block > 0)
      << "frames_per_block = " << options.frames_per_block;
  torch::NoGradGuard no_grad;
  Impl& m = *impl_;
  m.options = options;
  m.isa = internal::ResolveIsa(options.isa);
  m.d = model.options().d_model;
  m.num_labels = model.num_labels();
  m.encoder = FoldResBlock(*model.encoder->block);
  if (const auto* attention =
          dynamic_cast<const SelfAttentionImpl*>(model.backbone.get())) {
    m.attention = true;
    m.heads = attention->options().num_heads;
    m.head_dim = m.d / m.heads;
    for (const MultiHeadAttention& layer : attention->layers()) {
      m.layers.push_back(FoldAttentionLayer(*layer));
    }
  } else {
    const auto* conv =
        dynamic_cast<const Conv1dBackboneImpl*>(model.backbone.get());
    m.attention = false;
    m.wide = conv->options().width_multiplier * m.d;
    for (const Conv1dBackboneImpl::Block& block : conv->blocks()) {
      FoldedConvBlock folded;
      folded.expand = FoldResBlock(*block.expand);
      folded.reduce = Pack(FoldBatchNorm(ConvAffine(block.reduce), block.bn));
      folded.out = Pack(ConvAffine(block.out));
      m.blocks.push_back(std::move(folded));
    }
  }
  if (model.conditioned()) {
    m.head = FoldResBlock(*model.label_head->block);
    m.classifier = Pack(ConditionedClassifier(model));
  } else {
    m.head = FoldResBlock(*model.head->block);
    Affine classifier = ConvAffine(model.head->classifier);
    classifier.w = classifier.w / std::sqrt(static_cast<double>(m.d));
    m.classifier = Pack(classifier);
  }
  m.score_columns = m.classifier.rows;
  if (const auto* sinkhorn =
          dynamic_cast<const SinkhornImpl*>(model.normalization.get())) {
    m.sinkhorn = true;
    m.num_iters = sinkhorn->options().num_iters;
    m.alpha = sinkhorn->bin_score.detach().to(torch::kDouble).item<double>();
  } else {
    m.sinkhorn = false;
  }
  m.ld_xb = RoundUp16(2 * m.d);
  // The attention heads read v 16 channels at a time (fast_kernels.h).
  m.ld_qkv = RoundUp16(3 * m.d);
  if (m.attention) {
    m.ld_qkv = std::max(m.ld_qkv,
                        RoundUp16(2 * m.d + (m.heads - 1) * m.head_dim +
                                  RoundUp16(m.head_dim)));
  }
  m.ld_z = RoundUp16(2 * m.d);
  m.ld_t = RoundUp16(m.wide);
  m.ld_u = RoundUp16(m.d);
  m.ld_scores = RoundUp16(m.score_columns);
  int64_t hs = m.encoder.first.rows;
  hs = std::max(hs, m.head.first.rows);
  for (const FoldedConvBlock& block : m.blocks)
    hs = std::max(hs, block.expand.first.rows);
  m.ld_hs = RoundUp16(hs);
}

FastLabeler::~FastLabeler() = default;
FastLabeler::FastLabeler(FastLabeler&&) noexcept = default;
FastLabeler& FastLabeler::operator=(FastLabeler&&) noexcept = default;

int64_t FastLabeler::num_labels() const { return impl_->num_labels; }
bool FastLabeler::has_dustbin_row() const { return impl_->sinkhorn; }
internal::KernelIsa FastLabeler::isa() const { return impl_->isa; }

LabelerOutput FastLabeler::Forward(const at::Tensor& points_in) const {
  if (points_in.dim() != 3 || points_in.size(2) != 3) {
    throw ShapeError(
        fmt::format("FastLabeler: points must be B x N x 3, got {}",
                    ShapeString(points_in)));
  }
  SOMA_CHECK(points_in.device().is_cpu()) << "FastLabeler runs on CPU tensors";
  const Impl& m = *impl_;
  const torch::Tensor points = points_in.to(torch::kFloat).contiguous();
  const int64_t batch = points.size(0);
  const int64_t n = points.size(1);
  const int64_t cols = m.num_labels + 1;
  LabelerOutput out;
  out.scores = torch::empty({batch, n, m.score_columns}, torch::kFloat);
  out.log_assignment =
      torch::empty({batch, m.sinkhorn ? n + 1 : n, cols}, torch::kFloat);
  out.label_confidence = torch::empty({batch, n, cols}, torch::kFloat);
  out.label_ids = torch::empty({batch, n}, torch::kLong);
  if (batch == 0) return out;
  const float* p = points.data_ptr<float>();
  float* scores = out.scores.data_ptr<float>();
  float* log_assignment = out.log_assignment.data_ptr<float>();
  float* confidence = out.label_confidence.data_ptr<float>();
  int64_t* ids = out.label_ids.data_ptr<int64_t>();
  if (n == 0) {
    // No points: only the (label-side) dustbin row remains.
    if (m.sinkhorn) {
      std::vector<double> scratch;
      for (int64_t b = 0; b < batch; ++b) {
        internal::SinkhornFrame(m.isa,
                                scores,
                                0,
                                0,
                                m.num_labels,
                                m.alpha,
                                m.num_iters,
                                log_assignment + b * cols,
                                scratch);
      }
    }
    return out;
  }
  const int threads =
      std::max(1,
               m.options.num_threads > 0 ? m.options.num_threads
                                         : at::get_num_threads());
  auto workspaces =
      m.Acquire(static_cast<size_t>(std::max(threads, at::get_num_threads())));
  std::vector<Workspace*> ws;
  for (auto& w : workspaces) ws.push_back(w.get());
  try {
    if (threads == 1 || batch >= threads) {
      // Frames in blocks of at most frames_per_block (the block count a
      // multiple of the thread count, sizes balanced); threads take blocks
      // from a shared counter, so a thread slowed down by other processes
      // takes fewer blocks.
      const int64_t per_block = m.options.frames_per_block;
      int64_t blocks = (batch + per_block - 1) / per_block;
      blocks = (blocks + threads - 1) / threads * threads;
      blocks = std::min<int64_t>(blocks, batch);
      std::atomic<int64_t> next{0};
      at::parallel_for(0, threads, 1, [&](int64_t begin, int64_t end) {
        for (int64_t t = begin; t < end; ++t) {
          for (int64_t b = next++; b < blocks; b = next++) {
            m.RunFrames(p,
                        n,
                        batch * b / blocks,
                        batch * (b + 1) / blocks,
                        /*parallel=*/false,
                        &ws[static_cast<size_t>(t)],
                        1,
                        scores,
                        log_assignment,
                        confidence,
                        ids);
          }
        }
      });
    } else {
      // Fewer frames than threads: split GEMM panels, heads and frames.
      m.RunFrames(p,
                  n,
                  0,
                  batch,
                  /*parallel=*/true,
                  ws.data(),
                  ws.size(),
                  scores,
                  log_assignment,
                  confidence,
                  ids);
    }
  } catch (...) {
    m.Release(workspaces);
    throw;
  }
  m.Release(workspaces);
  return out;
}

}  // namespace soma
