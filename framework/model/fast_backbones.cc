// The fast training engine's backbones (fast_train.h): SelfAttentionOp
// (per-frame, per-head attention on fast_kernels.h's tiles) and
// Conv1dBackboneOp.
#include "framework/core/error.h"
#include "framework/model/fast_loss.h"
#include "framework/model/fast_parallel.h"
#include "framework/model/fast_train.h"
#include "framework/model/fast_train_internal.h"
#include "framework/model/labeler.h"
#include "framework/model/layers.h"
#include "framework/model/normalization.h"

#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <utility>

namespace soma {
namespace fast {
namespace {

using internal::GemmEpilogue;
using internal::GemmPacked;
using internal::NumPanels;
using internal::RoundUp16;
using internal::WeightView;

}  // namespace

// ---------------------------------------------------------------------------
// SelfAttentionOp

struct SelfAttentionOp::Layer {
  using Part = LinearOp::Part;

  Layer(MultiHeadAttentionImpl& mha, const std::vector<int64_t>& order)
      : qkv(std::vector<Part>{Part{mha.query.get(), order},
                              Part{mha.key.get(), order},
                              Part{mha.value.get(), order}}),
        merge(std::vector<Part>{Part{mha.merge.get(), {}}}, order),
        post1(mha.post_conv1.get()),
        bn(mha.post_bn.get()),
        post2(mha.post_conv2.get()) {}

  void Pack() {
    qkv.Pack();
    merge.Pack();
    post1.Pack();
    post2.Pack();
  }

  LinearOp qkv;
  LinearOp merge;
  LinearOp post1;
  BatchNormOp bn;
  LinearOp post2;
  Mat xcat;   // [merged | x]: the layer's input lives in columns [D, 2D)
  Mat q;      // [q | k | v], head-major within each
  Mat probs;  // softmax(q k^T / sqrt(dh)), (frame, head, query) rows
  Mat o;      // attention output, head-major
  Mat z1;     // post_conv1 output
  Mat a1;     // ReLU(BN(z1))
};

namespace {

/// Per-thread scratch of the attention kernels.
struct HeadScratch {
  internal::AlignedFloats t0;
  internal::AlignedFloats t1;
  internal::AlignedFloats t2;
};

}  // namespace

SelfAttentionOp::SelfAttentionOp(SelfAttentionImpl& backbone)
    : d_(backbone.options().d_model), heads_(backbone.options().num_heads) {
  const std::vector<int64_t> order = HeadMajorOrder(d_, heads_);
  for (const MultiHeadAttention& layer : backbone.layers()) {
    layers_.push_back(std::make_unique<Layer>(*layer.ptr(), order));
  }
}

SelfAttentionOp::~SelfAttentionOp() = default;

void SelfAttentionOp::Pack() {
  for (auto& layer : layers_) layer->Pack();
}

void SelfAttentionOp::Forward(const Context& ctx, const Mat& x, Mat& y) {
  const int64_t rows = x.rows;
  const int64_t d = d_;
  const int64_t h = heads_;
  const int64_t dh = d / h;
  const int64_t n = ctx.points;
  const int64_t np = RoundUp16(n);
  const float scale = static_cast<float>(1.0 / std::sqrt(double(dh)));
  y.Resize(rows, d);
  if (layers_.empty()) {
    CopyColumns(x.data(), x.ld, rows, d, y.data(), y.ld);
    return;
  }
  for (auto& layer : layers_) layer->xcat.Resize(rows, 2 * d);
  CopyColumns(x.data(),
              x.ld,
              rows,
              d,
              layers_[0]->xcat.data() + d,
              layers_[0]->xcat.ld);
  for (size_t i = 0; i < layers_.size(); ++i) {
    Layer& L = *layers_[i];
    const float* in = L.xcat.data() + d;
    const int64_t ld_in = L.xcat.ld;
    L.q.Resize(rows, 3 * d);
    L.probs.Resize(ctx.batch * h * n, n);
    L.o.Resize(rows, d);
    L.z1.Resize(rows, 2 * d);
    L.a1.Resize(rows, 2 * d);
    L.qkv.Forward(ctx, in, ld_in, rows, L.q.data(), L.q.ld);
    internal::FastParallelFor(
        0, ctx.batch, kFrameGrain, [&](int64_t begin, int64_t end) {
          HeadScratch scratch;
          scratch.t0.Resize(static_cast<size_t>(dh * np + 16));
          for (int64_t f = begin; f < end; ++f) {
            for (int64_t head = 0; head < h; ++head) {
              const float* q = L.q.row(f * n) + head * dh;
              const float* k = q + d;
              const float* v = q + 2 * d;
              float* kt = scratch.t0.data();
              internal::Transpose(ctx.isa, k, L.q.ld, n, dh, kt, np);
              float* p = L.probs.row((f * h + head) * n);
              // Scores, scale and softmax with each row in registers.
              internal::AttentionProbs(
                  ctx.isa, q, L.q.ld, kt, np, n, dh, scale, p, L.probs.ld);
              GemmPacked(ctx.isa,
                         p,
                         L.probs.ld,
                         n,
                         WeightView{v, 16, L.q.ld, nullptr, dh, n},
                         L.o.row(f * n) + head * dh,
                         L.o.ld,
                         {},
                         0,
                         NumPanels(dh));
            }
          }
        });
    L.merge.Forward(ctx, L.o.data(), L.o.ld, rows, L.xcat.data(), L.xcat.ld);
    L.post1.Forward(ctx, L.xcat.data(), L.xcat.ld, rows, L.z1.data(), L.z1.ld);
    L.bn.Forward(ctx,
                 L.z1.data(),
                 L.z1.ld,
                 rows,
                 nullptr,
                 0,
                 /*relu=*/true,
                 1.0f,
                 L.a1.data(),
                 L.a1.ld);
    float* out =
        i + 1 < layers_.size() ? layers_[i + 1]->xcat.data() + d : y.data();
    const int64_t ld_out =
        i + 1 < layers_.size() ? layers_[i + 1]->xcat.ld : y.ld;
    GemmEpilogue residual;
    residual.residual = in;
    residual.ld_residual = ld_in;
    L.post2.Forward(ctx, L.a1.data(), L.a1.ld, rows, out, ld_out, residual);
  }
}

void SelfAttentionOp::Backward(const Context& ctx, Mat& dy, Mat& dx) {
  const int64_t rows = dy.rows;
  const int64_t d = d_;
  const int64_t h = heads_;
  const int64_t dh = d / h;
  const int64_t n = ctx.points;
  const int64_t np = RoundUp16(n);
  const float scale = static_cast<float>(1.0 / std::sqrt(double(dh)));
  dx.Resize(rows, d);
  if (layers_.empty()) {
    CopyColumns(dy.data(), dy.ld, rows, d, dx.data(), dx.ld);
    return;
  }
  dz_.Resize(rows, 2 * d);
  dxcat_.Resize(rows, 2 * d);
  dqkv_.Resize(rows, 3 * d);
  do_.Resize(rows, d);
  Mat* grad_out = &dy;  // gradient w.r.t. the current layer's output
  Mat* grad_in = &dx;
  for (size_t idx = layers_.size(); idx-- > 0;) {
    Layer& L = *layers_[idx];
    const float* in = L.xcat.data() + d;
    const int64_t ld_in = L.xcat.ld;
    // post2 (residual handled at the end), BN + ReLU, post1.
    L.post2.Backward(ctx,
                     L.a1.data(),
                     L.a1.ld,
                     grad_out->data(),
                     grad_out->ld,
                     rows,
                     dz_.data(),
                     dz_.ld,
                     false);
    L.bn.Backward(ctx,
                  L.z1.data(),
                  L.z1.ld,
                  L.a1.data(),
                  L.a1.ld,
                  dz_.data(),
                  dz_.ld,
                  rows,
                  dz_.data(),
                  dz_.ld,
                  nullptr,
                  0);
    L.post1.Backward(ctx,
                     L.xcat.data(),
                     L.xcat.ld,
                     dz_.data(),
                     dz_.ld,
                     rows,
                     dxcat_.data(),
                     dxcat_.ld,
                     false);
    // merge: d(merged) = dxcat[:, :D] -> d(o).
    L.merge.Backward(ctx,
                     L.o.data(),
                     L.o.ld,
                     dxcat_.data(),
                     dxcat_.ld,
                     rows,
                     do_.data(),
                     do_.ld,
                     false);
    // Attention heads, per frame.
    internal::FastParallelFor(
        0, ctx.batch, kFrameGrain, [&](int64_t begin, int64_t end) {
          HeadScratch scratch;
          scratch.t0.Resize(static_cast<size_t>(np * np + 16));  // dP / dS
          scratch.t2.Resize(static_cast<size_t>(dh * np + 16));  // v^T
          for (int64_t f = begin; f < end; ++f) {
            for (int64_t head = 0; head < h; ++head) {
              const float* q = L.q.row(f * n) + head * dh;
              const float* k = q + d;
              const float* v = q + 2 * d;
              const int64_t ldq = L.q.ld;
              const float* p = L.probs.row((f * h + head) * n);
              const int64_t ldp = L.probs.ld;
              const float* dout = do_.row(f * n) + head * dh;
              float* dq = dqkv_.row(f * n) + head * dh;
              float* dk = dq + d;
              float* dv = dq + 2 * d;
              float* ds = scratch.t0.data();
              float* vt = scratch.t2.data();
              // dP = dO v^T, then dS = P * (dP - rowsum(dP * P)) /
              // sqrt(dh), each row in registers.
              internal::Transpose(ctx.isa, v, ldq, n, dh, vt, np);
              internal::AttentionScoresGrad(
                  ctx.isa, dout, do_.ld, vt, np, p, ldp, n, dh, scale, ds, np);
              // dV = P^T dO (P read transposed in place).
              internal::GemmPackedStrided(
                  ctx.isa,
                  p,
                  1,
                  ldp,
                  n,
                  WeightView{dout, 16, do_.ld, nullptr, dh, n},
                  dv,
                  dqkv_.ld,
                  {},
                  0,
                  NumPanels(dh));
              // dQ = dS k; dK = dS^T q.
              GemmPacked(ctx.isa,
                         ds,
                         np,
                         n,
                         WeightView{k, 16, ldq, nullptr, dh, n},
                         dq,
                         dqkv_.ld,
                         {},
                         0,
                         NumPanels(dh));
              internal::GemmPackedStrided(
                  ctx.isa,
                  ds,
                  1,
                  np,
                  n,
                  WeightView{q, 16, ldq, nullptr, dh, n},
                  dk,
                  dqkv_.ld,
                  {},
                  0,
                  NumPanels(dh));
            }
          }
        });
    // The residual and the [merged | x] concatenation paths, then qkv's.
    AddColumns(grad_out->data(),
               grad_out->ld,
               dxcat_.data() + d,
               dxcat_.ld,
               rows,
               d,
               grad_in->data(),
               grad_in->ld);
    L.qkv.Backward(ctx,
                   in,
                   ld_in,
                   dqkv_.data(),
                   dqkv_.ld,
                   rows,
                   grad_in->data(),
                   grad_in->ld,
                   /*accumulate=*/true);
    if (idx > 0) {
      // The next (lower) layer's output gradient is this layer's input one.
      if (grad_out == &dy) {
        grad_out = &dx;
        grad_in = &dy;
      } else {
        grad_out = &dy;
        grad_in = &dx;
      }
      grad_in->Resize(rows, d);
    }
  }
  if (grad_in != &dx) std::swap(dx, dy);
}

// ---------------------------------------------------------------------------
// Conv1dBackboneOp

struct Conv1dBackboneOp::Block {
  explicit Block(const Conv1dBackboneImpl::Block& block)
      : expand(*block.expand.ptr(), /*relu_out=*/true, 1.0f),
        reduce(block.reduce.ptr().get()),
        bn(block.bn.ptr().get()),
        out(block.out.ptr().get()) {}
  ResBlockOp expand;
  LinearOp reduce;
  BatchNormOp bn;
  LinearOp out;
  Mat t;  // expand output
  Mat z;  // reduce output
  Mat a;  // ReLU(BN(z))
  Mat y;  // block output
};

Conv1dBackboneOp::Conv1dBackboneOp(Conv1dBackboneImpl& backbone) {
  for (const Conv1dBackboneImpl::Block& block : backbone.blocks()) {
    blocks_.push_back(std::make_unique<Block>(block));
  }
}

Conv1dBackboneOp::~Conv1dBackboneOp() = default;

void Conv1dBackboneOp::Pack() {
  for (auto& block : blocks_) {
    block->expand.Pack();
    block->reduce.Pack();
    block->out.Pack();
  }
}

void Conv1dBackboneOp::Forward(const Context& ctx, const Mat& x, Mat& y) {
  const int64_t rows = x.rows;
  const Mat* in = &x;
  for (auto& block : blocks_) {
    Block& b = *block;
    b.expand.Forward(ctx, *in, b.t);
    b.z.Resize(rows, b.reduce.out_channels());
    b.a.Resize(rows, b.reduce.out_channels());
    b.y.Resize(rows, x.cols);
    b.reduce.Forward(ctx, b.t.data(), b.t.ld, rows, b.z.data(), b.z.ld);
    b.bn.Forward(ctx,
                 b.z.data(),
                 b.z.ld,
                 rows,
                 nullptr,
                 0,
                 true,
                 1.0f,
                 b.a.data(),
                 b.a.ld);
    GemmEpilogue residual;
    residual.residual = in->data();
    residual.ld_residual = in->ld;
    b.out.Forward(ctx, b.a.data(), b.a.ld, rows, b.y.data(), b.y.ld, residual);
    in = &b.y;
  }
  y.Resize(rows, x.cols);
  CopyColumns(in->data(), in->ld, rows, x.cols, y.data(), y.ld);
  inputs_.clear();
  inputs_.push_back(&x);
  for (size_t i = 0; i + 1 < blocks_.size(); ++i) {
    inputs_.push_back(&blocks_[i]->y);
  }
}

void Conv1dBackboneOp::Backward(const Context& ctx, Mat& dy, Mat& dx) {
  const int64_t rows = dy.rows;
  const int64_t d = dy.cols;
  dx.Resize(rows, d);
  if (blocks_.empty()) {
    CopyColumns(dy.data(), dy.ld, rows, d, dx.data(), dx.ld);
    return;
  }
  Mat* grad_out = &dy;
  Mat* grad_in = &dx;
  for (size_t idx = blocks_.size(); idx-- > 0;) {
    Block& b = *blocks_[idx];
    const Mat& in = *inputs_[idx];
    du_.Resize(rows, b.reduce.out_channels());
    dt_.Resize(rows, b.reduce.in_channels());
    b.out.Backward(ctx,
                   b.a.data(),
                   b.a.ld,
                   grad_out->data(),
                   grad_out->ld,
                   rows,
                   du_.data(),
                   du_.ld,
                   false);
    b.bn.Backward(ctx,
                  b.z.data(),
                  b.z.ld,
                  b.a.data(),
                  b.a.ld,
                  du_.data(),
                  du_.ld,
                  rows,
                  du_.data(),
                  du_.ld,
                  nullptr,
                  0);
    b.reduce.Backward(ctx,
                      b.t.data(),
                      b.t.ld,
                      du_.data(),
                      du_.ld,
                      rows,
                      dt_.data(),
                      dt_.ld,
                      false);
    b.expand.Backward(ctx, in, b.t, dt_, grad_in, false);
    AddInPlace(
        grad_out->data(), grad_out->ld, rows, d, grad_in->data(), grad_in->ld);
    if (idx > 0) {
      if (grad_out == &dy) {
        grad_out = &dx;
        grad_in = &dy;
      } else {
        grad_out = &dy;
        grad_in = &dx;
      }
    }
  }
  if (grad_in != &dx) std::swap(dx, dy);
}

}  // namespace fast
}  // namespace soma
