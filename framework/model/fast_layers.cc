// The fast training engine's per-point layers (fast_train.h): LinearOp (the
// convolutions as GEMMs, dW and the bias gradient), BatchNormOp (training
// mode, batch statistics), ResBlockOp, and the elementwise helpers of
// fast_train_internal.h.
#include "framework/core/error.h"
#include "framework/model/fast_loss.h"
#include "framework/model/fast_parallel.h"
#include "framework/model/fast_train.h"
#include "framework/model/fast_train_internal.h"
#include "framework/model/labeler.h"
#include "framework/model/layers.h"
#include "framework/model/normalization.h"

#include <ATen/Parallel.h>
#include <fmt/format.h>
#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <utility>

namespace soma {
namespace fast {
namespace {

using internal::GemmEpilogue;
using internal::GemmPacked;
using internal::NumPanels;
using internal::RoundUp16;
using internal::WeightView;

/// Rows per dW accumulation chunk: the chunk of the input (the GEMM's
/// "weights") stays in L2 while every output row tile reads it.
constexpr int64_t kReductionChunk = 256;
/// Rows per chunk of the row-parallel GEMMs (a multiple of the micro-kernel's
/// row tiles, 8 and 6).
constexpr int64_t kGemmRowGrain = 96;
/// Row ranges of the column reductions (BatchNorm statistics, bias and
/// weight gradients): at most this many, of at least kReduceRows rows each.
/// The ranges depend on the row count only, so the sums do not depend on
/// the thread count or on which thread ran a range.
constexpr int64_t kMaxReduceChunks = 8;
constexpr int64_t kReduceRows = 512;

/// `f(begin, end)` over [0, n) in chunks of `grain`, on the engine's threads
/// (fast_parallel.h: chunks are claimed dynamically).
template <typename F>
void ParallelRows(int64_t n, int64_t grain, const F& f) {
  if (n <= 0) return;
  internal::FastParallelFor(0, n, grain, f);
}

int64_t ReduceChunks(int64_t n) {
  return std::max<int64_t>(1, std::min(kMaxReduceChunks, n / kReduceRows));
}

/// Per-column sums over the rows [0, n), in ReduceChunks(n) row ranges:
/// `f(begin, end, sums, tmp)` adds its range's sums into `sums` (`width`
/// doubles, zeroed) with `tmp` (`width` floats) as scratch. Returns the
/// totals, the ranges' sums added in range order.
template <typename F>
std::vector<double> ParallelColumnReduce(int64_t n, int64_t width, const F& f) {
  const int64_t chunks = ReduceChunks(n);
  std::vector<double> partial(static_cast<size_t>(chunks * width), 0.0);
  internal::FastParallelFor(0, chunks, 1, [&](int64_t begin, int64_t end) {
    std::vector<float> tmp(static_cast<size_t>(width));
    for (int64_t c = begin; c < end; ++c) {
      f(n * c / chunks,
        n * (c + 1) / chunks,
        partial.data() + c * width,
        tmp.data());
    }
  });
  std::vector<double> total(static_cast<size_t>(width), 0.0);
  for (int64_t c = 0; c < chunks; ++c) {
    const double* sums = partial.data() + c * width;
    for (size_t i = 0; i < total.size(); ++i) total[i] += sums[i];
  }
  return total;
}

GemmEpilogue OffsetEpilogue(const GemmEpilogue& ep, int64_t r0) {
  GemmEpilogue out = ep;
  if (ep.residual != nullptr) out.residual = ep.residual + r0 * ep.ld_residual;
  if (ep.row_scale != nullptr) out.row_scale = ep.row_scale + r0;
  return out;
}

const float* Data(const at::Tensor& parameter) {
  SOMA_CHECK(parameter.defined() && parameter.is_contiguous() &&
             parameter.scalar_type() == torch::kFloat &&
             parameter.device().is_cpu())
      << "fast training needs contiguous float CPU parameters";
  return parameter.data_ptr<float>();
}

std::vector<int64_t> Identity(int64_t n) {
  std::vector<int64_t> order(static_cast<size_t>(n));
  for (int64_t i = 0; i < n; ++i) order[static_cast<size_t>(i)] = i;
  return order;
}

}  // namespace

float* Grad(at::Tensor& parameter) {
  at::Tensor& grad = parameter.mutable_grad();
  if (!grad.defined() || !grad.sizes().equals(parameter.sizes())) {
    grad = torch::zeros_like(parameter);
  }
  SOMA_CHECK(grad.is_contiguous() && grad.scalar_type() == torch::kFloat)
      << "fast training needs contiguous float gradients";
  return grad.data_ptr<float>();
}

std::vector<int64_t> HeadMajorOrder(int64_t d_model, int64_t heads) {
  const int64_t dh = d_model / heads;
  std::vector<int64_t> order(static_cast<size_t>(d_model));
  for (int64_t head = 0; head < heads; ++head) {
    for (int64_t j = 0; j < dh; ++j) {
      order[static_cast<size_t>(head * dh + j)] = j * heads + head;
    }
  }
  return order;
}

void Relu(const Mat& x, Mat& y) {
  y.Resize(x.rows, x.cols);
  ParallelRows(x.rows, kRowGrain, [&](int64_t begin, int64_t end) {
    for (int64_t r = begin; r < end; ++r) {
      const float* s = x.row(r);
      float* d = y.row(r);
      for (int64_t c = 0; c < x.cols; ++c) d[c] = std::max(s[c], 0.0f);
    }
  });
}

void ReluBackwardInPlace(const Mat& mask, Mat& dy) {
  ParallelRows(dy.rows, kRowGrain, [&](int64_t begin, int64_t end) {
    for (int64_t r = begin; r < end; ++r) {
      const float* m = mask.row(r);
      float* d = dy.row(r);
      for (int64_t c = 0; c < dy.cols; ++c) {
        if (!(m[c] > 0.0f)) d[c] = 0.0f;
      }
    }
  });
}

void AddInPlace(const float* x,
                int64_t ldx,
                int64_t rows,
                int64_t cols,
                float* y,
                int64_t ldy) {
  ParallelRows(rows, kRowGrain, [&](int64_t begin, int64_t end) {
    for (int64_t r = begin; r < end; ++r) {
      const float* s = x + r * ldx;
      float* d = y + r * ldy;
      for (int64_t c = 0; c < cols; ++c) d[c] += s[c];
    }
  });
}

void AddColumns(const float* a,
                int64_t lda,
                const float* b,
                int64_t ldb,
                int64_t rows,
                int64_t cols,
                float* y,
                int64_t ldy) {
  ParallelRows(rows, kRowGrain, [&](int64_t begin, int64_t end) {
    for (int64_t r = begin; r < end; ++r) {
      const float* s = a + r * lda;
      const float* t = b + r * ldb;
      float* d = y + r * ldy;
      for (int64_t c = 0; c < cols; ++c) d[c] = s[c] + t[c];
    }
  });
}

void CopyColumns(const float* x,
                 int64_t ldx,
                 int64_t rows,
                 int64_t cols,
                 float* y,
                 int64_t ldy) {
  ParallelRows(rows, kRowGrain, [&](int64_t begin, int64_t end) {
    for (int64_t r = begin; r < end; ++r) {
      std::memcpy(y + r * ldy, x + r * ldx, sizeof(float) * cols);
    }
  });
}

namespace {

// The elementwise passes below are compiled twice (AVX-512 and the baseline
// ISA) and dispatched at load time; they accumulate in float over blocks of
// kSumBlock rows and in double across blocks.
#define SOMA_VECTOR_CLONES __attribute__((target_clones("avx512f", "default")))
constexpr int64_t kSumBlock = 32;
// The bias gradient sums dy per dW chunk in the same kSumBlock row blocks as
// a pass over whole row ranges would (LinearOp::Backward).
static_assert(kReductionChunk % kSumBlock == 0);

/// `sums[c] += sum_r x[r][c]`; `tmp` holds `cols` floats.
SOMA_VECTOR_CLONES void ColumnSums(const float* __restrict x,
                                   int64_t ldx,
                                   int64_t rows,
                                   int64_t cols,
                                   double* __restrict sums,
                                   float* __restrict tmp) {
  for (int64_t r0 = 0; r0 < rows; r0 += kSumBlock) {
    const int64_t r1 = std::min(rows, r0 + kSumBlock);
    for (int64_t c = 0; c < cols; ++c) tmp[c] = 0.0f;
    for (int64_t r = r0; r < r1; ++r) {
      const float* v = x + r * ldx;
      for (int64_t c = 0; c < cols; ++c) tmp[c] += v[c];
    }
    for (int64_t c = 0; c < cols; ++c) sums[c] += tmp[c];
  }
}

/// `s1[c] += sum_r (y - shift)`, `s2[c] += sum_r (y - shift)^2`; `tmp` holds
/// `2 * cols` floats.
SOMA_VECTOR_CLONES void ShiftedMoments(const float* __restrict y,
                                       int64_t ldy,
                                       int64_t rows,
                                       int64_t cols,
                                       const float* __restrict shift,
                                       double* __restrict s1,
                                       double* __restrict s2,
                                       float* __restrict tmp) {
  float* t1 = tmp;
  float* t2 = tmp + cols;
  for (int64_t r0 = 0; r0 < rows; r0 += kSumBlock) {
    const int64_t r1 = std::min(rows, r0 + kSumBlock);
    for (int64_t c = 0; c < cols; ++c) t1[c] = t2[c] = 0.0f;
    for (int64_t r = r0; r < r1; ++r) {
      const float* v = y + r * ldy;
      for (int64_t c = 0; c < cols; ++c) {
        const float d = v[c] - shift[c];
        t1[c] += d;
        t2[c] += d * d;
      }
    }
    for (int64_t c = 0; c < cols; ++c) {
      s1[c] += t1[c];
      s2[c] += t2[c];
    }
  }
}

/// `out = act(scale * (a * (y - m) + b + add))` with per-column `a`, `m`,
/// `b`.
SOMA_VECTOR_CLONES void AffineRows(const float* __restrict y,
                                   int64_t ldy,
                                   int64_t rows,
                                   int64_t cols,
                                   const float* __restrict m,
                                   const float* __restrict a,
                                   const float* __restrict b,
                                   const float* __restrict add,
                                   int64_t ldadd,
                                   float scale,
                                   bool relu,
                                   float* __restrict out,
                                   int64_t ldout) {
  const float lower = relu ? 0.0f : -std::numeric_limits<float>::infinity();
  for (int64_t r = 0; r < rows; ++r) {
    const float* v = y + r * ldy;
    float* o = out + r * ldout;
    if (add != nullptr) {
      const float* e = add + r * ldadd;
      for (int64_t c = 0; c < cols; ++c) {
        o[c] = std::max(scale * (a[c] * (v[c] - m[c]) + b[c] + e[c]), lower);
      }
    } else {
      for (int64_t c = 0; c < cols; ++c) {
        o[c] = std::max(scale * (a[c] * (v[c] - m[c]) + b[c]), lower);
      }
    }
  }
}

/// BatchNorm backward, pass 1: `g = dout * scale * relu'(out)` into `g` (and
/// `gadd`), `s1 += sum g`, `s2 += sum g * xhat` with `xhat = (y - mean) *
/// inv_std`; `tmp` holds `2 * cols` floats.
SOMA_VECTOR_CLONES void BatchNormGradPass(const float* __restrict y,
                                          int64_t ldy,
                                          const float* __restrict out,
                                          int64_t ldout,
                                          const float* dout,
                                          int64_t lddout,
                                          int64_t rows,
                                          int64_t cols,
                                          const float* __restrict inv_std,
                                          const float* __restrict mean,
                                          float scale,
                                          bool relu,
                                          float* g,
                                          int64_t ldg,
                                          float* __restrict gadd,
                                          int64_t ldgadd,
                                          double* __restrict s1,
                                          double* __restrict s2,
                                          float* __restrict tmp) {
  float* t1 = tmp;
  float* t2 = tmp + cols;
  for (int64_t r0 = 0; r0 < rows; r0 += kSumBlock) {
    const int64_t r1 = std::min(rows, r0 + kSumBlock);
    for (int64_t c = 0; c < cols; ++c) t1[c] = t2[c] = 0.0f;
    for (int64_t r = r0; r < r1; ++r) {
      const float* v = y + r * ldy;
      const float* o = out + r * ldout;
      const float* d = dout + r * lddout;
      float* gr = g + r * ldg;
      for (int64_t c = 0; c < cols; ++c) {
        const float value = (relu && !(o[c] > 0.0f)) ? 0.0f : d[c] * scale;
        gr[c] = value;
        t1[c] += value;
        t2[c] += value * ((v[c] - mean[c]) * inv_std[c]);
      }
      if (gadd != nullptr) {
        float* ga = gadd + r * ldgadd;
        for (int64_t c = 0; c < cols; ++c) ga[c] = gr[c];
      }
    }
    for (int64_t c = 0; c < cols; ++c) {
      s1[c] += t1[c];
      s2[c] += t2[c];
    }
  }
}

/// BatchNorm backward, pass 2: `g = k0 * (g - k1 - xhat * k2)`.
SOMA_VECTOR_CLONES void BatchNormGradApply(const float* __restrict y,
                                           int64_t ldy,
                                           int64_t rows,
                                           int64_t cols,
                                           const float* __restrict inv_std,
                                           const float* __restrict mean,
                                           const float* __restrict k0,
                                           const float* __restrict k1,
                                           const float* __restrict k2,
                                           float* __restrict g,
                                           int64_t ldg) {
  for (int64_t r = 0; r < rows; ++r) {
    const float* v = y + r * ldy;
    float* gr = g + r * ldg;
    for (int64_t c = 0; c < cols; ++c) {
      const float xhat = (v[c] - mean[c]) * inv_std[c];
      gr[c] = k0[c] * (gr[c] - k1[c] - xhat * k2[c]);
    }
  }
}

}  // namespace

// ---------------------------------------------------------------------------
// Mat

void Mat::Resize(int64_t num_rows, int64_t num_cols) {
  rows = num_rows;
  cols = num_cols;
  ld = RoundUp16(num_cols) + 16;
  buf.Resize(static_cast<size_t>(std::max<int64_t>(1, rows) * ld + 16));
}

// ---------------------------------------------------------------------------
// LinearOp

LinearOp::LinearOp(std::vector<Part> parts, std::vector<int64_t> in_order)
    : parts_(std::move(parts)), in_order_(std::move(in_order)) {
  SOMA_CHECK(!parts_.empty());
  for (Part& part : parts_) {
    SOMA_CHECK(part.conv != nullptr);
    const at::Tensor& w = part.conv->weight;
    SOMA_CHECK(w.dim() == 3 && w.size(2) == 1)
        << "fast training supports kernel-size-1 convolutions only";
    SOMA_CHECK(part.conv->bias.defined())
        << "fast training needs convolutions with a bias";
    if (in_ == 0) in_ = w.size(1);
    SOMA_CHECK_EQ(w.size(1), in_);
    if (part.out_order.empty()) part.out_order = Identity(w.size(0));
    SOMA_CHECK_EQ(static_cast<int64_t>(part.out_order.size()), w.size(0));
    out_ += w.size(0);
  }
  if (in_order_.empty()) in_order_ = Identity(in_);
  SOMA_CHECK_EQ(static_cast<int64_t>(in_order_.size()), in_);
}

void LinearOp::Pack() {
  fwd_packed_ = false;
  bwd_packed_ = false;
  const int64_t mp = RoundUp16(out_);
  const int64_t kp = RoundUp16(in_);
  wt_.Resize(static_cast<size_t>(in_ * mp + 16));
  bias_.Resize(static_cast<size_t>(mp));
  w_.Resize(static_cast<size_t>(out_ * kp + 16));
  int64_t row = 0;
  for (const Part& part : parts_) {
    const float* w = Data(part.conv->weight);
    const float* b = Data(part.conv->bias);
    const int64_t m = part.conv->weight.size(0);
    ParallelRows(m, 32, [&](int64_t begin, int64_t end) {
      for (int64_t i = begin; i < end; ++i) {
        const int64_t src = part.out_order[static_cast<size_t>(i)];
        const float* wr = w + src * in_;
        float* dst = w_.data() + (row + i) * kp;
        for (int64_t k = 0; k < in_; ++k) {
          const float value = wr[in_order_[static_cast<size_t>(k)]];
          dst[k] = value;
          wt_.data()[k * mp + row + i] = value;
        }
        bias_.data()[row + i] = b[src];
      }
    });
    row += m;
  }
}

void LinearOp::Forward(const Context& ctx,
                       const float* x,
                       int64_t ldx,
                       int64_t rows,
                       float* y,
                       int64_t ldy,
                       const GemmEpilogue& epilogue) {
  if (UsesBf16(ctx)) {
    SOMA_CHECK(epilogue.row_scale == nullptr && epilogue.relu_columns == 0)
        << "bf16 products support a residual epilogue only";
    if (!fwd_packed_) {
      // B(k, m) = W[m][k].
      internal::PrepareBf16B(in_, out_, &fwd_b_);
      internal::PackBf16B(w_.data(), 1, RoundUp16(in_), 0, in_, &fwd_b_);
      fwd_packed_ = true;
    }
    scratch_.resize(static_cast<size_t>(internal::FastParallelThreads()));
    ParallelRows(rows, kRowGrain, [&](int64_t begin, int64_t end) {
      const bool residual = epilogue.residual != nullptr;
      if (residual && epilogue.residual != y) {
        CopyColumns(epilogue.residual + begin * epilogue.ld_residual,
                    epilogue.ld_residual,
                    end - begin,
                    out_,
                    y + begin * ldy,
                    ldy);
      }
      internal::MatMulBf16(
          x + begin * ldx,
          ldx,
          1,
          end - begin,
          fwd_b_,
          bias_.data(),
          residual,
          y + begin * ldy,
          ldy,
          scratch_[static_cast<size_t>(internal::FastParallelThreadIndex())]);
    });
    return;
  }
  const WeightView w{wt_.data(), 16, RoundUp16(out_), bias_.data(), out_, in_};
  ParallelRows(rows, kGemmRowGrain, [&](int64_t begin, int64_t end) {
    GemmPacked(ctx.isa,
               x + begin * ldx,
               ldx,
               end - begin,
               w,
               y + begin * ldy,
               ldy,
               OffsetEpilogue(epilogue, begin),
               0,
               NumPanels(out_));
  });
}

void LinearOp::Backward(const Context& ctx,
                        const float* x,
                        int64_t ldx,
                        const float* dy,
                        int64_t ldy,
                        int64_t rows,
                        float* dx,
                        int64_t lddx,
                        bool accumulate) {
  const int64_t kp = RoundUp16(in_);
  dw_.Resize(static_cast<size_t>(out_ * kp + 16));
  if (UsesBf16(ctx)) {
    // The bias gradient.
    db_ = ParallelColumnReduce(
        rows, out_, [&](int64_t begin, int64_t end, double* sums, float* tmp) {
          ColumnSums(dy + begin * ldy, ldy, end - begin, out_, sums, tmp);
        });
    // dW = dy^T x in bf16: x packed once (threads split its rows), then the
    // output rows of dW in blocks of 32.
    internal::PrepareBf16B(rows, in_, &x_b_);
    const int64_t pairs = (x_b_.k_pad + 1) / 2;
    internal::FastParallelFor(0, pairs, 64, [&](int64_t begin, int64_t end) {
      internal::PackBf16B(x, ldx, 1, 2 * begin, std::min(rows, 2 * end), &x_b_);
    });
    scratch_.resize(static_cast<size_t>(internal::FastParallelThreads()));
    const int64_t blocks = (out_ + 31) / 32;
    internal::FastParallelFor(0, blocks, 1, [&](int64_t begin, int64_t end) {
      const int64_t m0 = begin * 32;
      const int64_t m1 = std::min(out_, end * 32);
      internal::MatMulBf16(
          dy + m0,
          1,
          ldy,
          m1 - m0,
          x_b_,
          nullptr,
          false,
          dw_.data() + m0 * kp,
          kp,
          scratch_[static_cast<size_t>(internal::FastParallelThreadIndex())]);
    });
  } else {
    // dW = dy^T x (dy read transposed in place): each of ReduceChunks(rows)
    // row ranges accumulates its partial dW over blocks of kReductionChunk
    // rows (the block of x stays in L2 while every output tile reads it);
    // the partials are then added in range order. The bias gradient's column
    // sums of each block of dy follow its GEMM while the block is in cache:
    // the same ranges and kSumBlock row blocks as ParallelColumnReduce, so
    // the same sums as a separate pass over dy.
    const int64_t ranges = ReduceChunks(rows);
    const int64_t size = out_ * kp;
    dw_partial_.Resize(static_cast<size_t>(ranges * size + 16));
    std::vector<double> db_partial(static_cast<size_t>(ranges * out_), 0.0);
    internal::FastParallelFor(0, ranges, 1, [&](int64_t begin, int64_t end) {
      std::vector<float> tmp(static_cast<size_t>(out_));
      for (int64_t c = begin; c < end; ++c) {
        const int64_t r0 = rows * c / ranges;
        const int64_t r1 = rows * (c + 1) / ranges;
        float* dw = ranges == 1 ? dw_.data() : dw_partial_.data() + c * size;
        double* db = db_partial.data() + c * out_;
        for (int64_t b0 = r0; b0 < r1; b0 += kReductionChunk) {
          const int64_t bn = std::min(kReductionChunk, r1 - b0);
          GemmEpilogue ep;
          if (b0 > r0) {
            ep.residual = dw;
            ep.ld_residual = kp;
          }
          internal::GemmPackedStrided(
              ctx.isa,
              dy + b0 * ldy,
              1,
              ldy,
              out_,
              WeightView{x + b0 * ldx, 16, ldx, nullptr, in_, bn},
              dw,
              kp,
              ep,
              0,
              NumPanels(in_));
          ColumnSums(dy + b0 * ldy, ldy, bn, out_, db, tmp.data());
        }
      }
    });
    db_.assign(static_cast<size_t>(out_), 0.0);
    for (int64_t c = 0; c < ranges; ++c) {
      const double* sums = db_partial.data() + c * out_;
      for (size_t i = 0; i < db_.size(); ++i) db_[i] += sums[i];
    }
    if (rows == 0) {
      std::fill(dw_.data(), dw_.data() + size, 0.0f);
    } else if (ranges > 1) {
      ParallelRows(out_, 8, [&](int64_t begin, int64_t end) {
        for (int64_t m = begin; m < end; ++m) {
          float* dst = dw_.data() + m * kp;
          for (int64_t k = 0; k < in_; ++k) dst[k] = 0.0f;
          for (int64_t c = 0; c < ranges; ++c) {
            const float* src = dw_partial_.data() + c * size + m * kp;
            for (int64_t k = 0; k < in_; ++k) dst[k] += src[k];
          }
        }
      });
    }
  }
  // Scatter into torch's layout.
  int64_t row = 0;
  for (Part& part : parts_) {
    float* gw = Grad(part.conv->weight);
    float* gb = Grad(part.conv->bias);
    const int64_t m = part.conv->weight.size(0);
    ParallelRows(m, 32, [&](int64_t begin, int64_t end) {
      for (int64_t i = begin; i < end; ++i) {
        const int64_t dst = part.out_order[static_cast<size_t>(i)];
        const float* src = dw_.data() + (row + i) * kp;
        float* gr = gw + dst * in_;
        for (int64_t k = 0; k < in_; ++k) {
          gr[in_order_[static_cast<size_t>(k)]] = src[k];
        }
        gb[dst] = static_cast<float>(db_[static_cast<size_t>(row + i)]);
      }
    });
    row += m;
  }
  if (dx == nullptr) return;
  if (UsesBf16(ctx)) {
    if (!bwd_packed_) {
      // B(m, k) = W[m][k].
      internal::PrepareBf16B(out_, in_, &bwd_b_);
      internal::PackBf16B(w_.data(), kp, 1, 0, out_, &bwd_b_);
      bwd_packed_ = true;
    }
    ParallelRows(rows, kRowGrain, [&](int64_t begin, int64_t end) {
      internal::MatMulBf16(
          dy + begin * ldy,
          ldy,
          1,
          end - begin,
          bwd_b_,
          nullptr,
          accumulate,
          dx + begin * lddx,
          lddx,
          scratch_[static_cast<size_t>(internal::FastParallelThreadIndex())]);
    });
    return;
  }
  // dx = dy W.
  const WeightView w{w_.data(), 16, kp, nullptr, in_, out_};
  ParallelRows(rows, kGemmRowGrain, [&](int64_t begin, int64_t end) {
    GemmEpilogue ep;
    if (accumulate) {
      ep.residual = dx + begin * lddx;
      ep.ld_residual = lddx;
    }
    GemmPacked(ctx.isa,
               dy + begin * ldy,
               ldy,
               end - begin,
               w,
               dx + begin * lddx,
               lddx,
               ep,
               0,
               NumPanels(in_));
  });
}

// ---------------------------------------------------------------------------
// BatchNormOp

BatchNormOp::BatchNormOp(torch::nn::BatchNorm1dImpl* bn) : bn_(bn) {
  SOMA_CHECK(bn_ != nullptr);
  const auto& options = bn_->options;
  SOMA_CHECK(options.affine() && options.track_running_stats())
      << "fast training needs affine BatchNorm with running statistics";
  SOMA_CHECK(options.momentum().has_value())
      << "fast training needs a BatchNorm momentum (not a cumulative average)";
  channels_ = options.num_features();
  eps_ = options.eps();
  momentum_ = *options.momentum();
}

void BatchNormOp::Forward(const Context& /*ctx*/,
                          const float* y,
                          int64_t ldy,
                          int64_t rows,
                          const float* add,
                          int64_t ldadd,
                          bool relu,
                          float scale,
                          float* out,
                          int64_t ldout) {
  SOMA_CHECK(rows > 1) << "BatchNorm in training mode needs more than one "
                          "value per channel (got "
                       << rows << " points in the batch)";
  const int64_t c_count = channels_;
  relu_ = relu;
  scale_ = scale;
  // Batch statistics, shifted by the first row against cancellation.
  const std::vector<double> moments = ParallelColumnReduce(
      rows,
      2 * c_count,
      [&](int64_t begin, int64_t end, double* sums, float* tmp) {
        ShiftedMoments(y + begin * ldy,
                       ldy,
                       end - begin,
                       c_count,
                       y,
                       sums,
                       sums + c_count,
                       tmp);
      });
  mean_.resize(static_cast<size_t>(c_count));
  inv_std_.resize(static_cast<size_t>(c_count));
  gamma_.resize(static_cast<size_t>(c_count));
  beta_.resize(static_cast<size_t>(c_count));
  const float* weight = Data(bn_->weight);
  const float* bias = Data(bn_->bias);
  float* running_mean = bn_->running_mean.data_ptr<float>();
  float* running_var = bn_->running_var.data_ptr<float>();
  const double n = static_cast<double>(rows);
  for (int64_t c = 0; c < c_count; ++c) {
    const double s1 = moments[static_cast<size_t>(c)];
    const double s2 = moments[static_cast<size_t>(c_count + c)];
    const double shifted_mean = s1 / n;
    const double var = std::max(0.0, s2 / n - shifted_mean * shifted_mean);
    const double mean = shifted_mean + y[c];
    const size_t i = static_cast<size_t>(c);
    mean_[i] = static_cast<float>(mean);
    inv_std_[i] = static_cast<float>(1.0 / std::sqrt(var + eps_));
    gamma_[i] = weight[c];
    beta_[i] = bias[c];
    running_mean[c] = static_cast<float>((1.0 - momentum_) * running_mean[c] +
                                         momentum_ * mean);
    running_var[c] = static_cast<float>((1.0 - momentum_) * running_var[c] +
                                        momentum_ * var * n / (n - 1.0));
  }
  if (bn_->num_batches_tracked.defined()) bn_->num_batches_tracked.add_(1);
  // Normalise, affine, addend, scale, ReLU.
  std::vector<float> a(static_cast<size_t>(c_count));
  for (size_t c = 0; c < a.size(); ++c) a[c] = gamma_[c] * inv_std_[c];
  ParallelRows(rows, kRowGrain, [&](int64_t begin, int64_t end) {
    AffineRows(y + begin * ldy,
               ldy,
               end - begin,
               c_count,
               mean_.data(),
               a.data(),
               beta_.data(),
               add != nullptr ? add + begin * ldadd : nullptr,
               ldadd,
               scale,
               relu,
               out + begin * ldout,
               ldout);
  });
}

void BatchNormOp::Backward(const Context& /*ctx*/,
                           const float* y,
                           int64_t ldy,
                           const float* out,
                           int64_t ldout,
                           const float* dout,
                           int64_t lddout,
                           int64_t rows,
                           float* dy,
                           int64_t lddy,
                           float* dadd,
                           int64_t lddadd) {
  const int64_t c_count = channels_;
  const float scale = scale_;
  const bool relu = relu_;
  // Pass 1: g = dout * scale * relu'(out) into dy (and dadd); per-channel
  // sums of g and g * xhat.
  const std::vector<double> moments = ParallelColumnReduce(
      rows,
      2 * c_count,
      [&](int64_t begin, int64_t end, double* sums, float* tmp) {
        BatchNormGradPass(y + begin * ldy,
                          ldy,
                          out + begin * ldout,
                          ldout,
                          dout + begin * lddout,
                          lddout,
                          end - begin,
                          c_count,
                          inv_std_.data(),
                          mean_.data(),
                          scale,
                          relu,
                          dy + begin * lddy,
                          lddy,
                          dadd != nullptr ? dadd + begin * lddadd : nullptr,
                          lddadd,
                          sums,
                          sums + c_count,
                          tmp);
      });
  std::vector<float> k1(static_cast<size_t>(c_count));
  std::vector<float> k2(static_cast<size_t>(c_count));
  std::vector<float> k0(static_cast<size_t>(c_count));
  float* dgamma = Grad(bn_->weight);
  float* dbeta = Grad(bn_->bias);
  const double n = static_cast<double>(rows);
  for (int64_t c = 0; c < c_count; ++c) {
    const double s1 = moments[static_cast<size_t>(c)];
    const double s2 = moments[static_cast<size_t>(c_count + c)];
    dgamma[c] = static_cast<float>(s2);
    dbeta[c] = static_cast<float>(s1);
    const size_t i = static_cast<size_t>(c);
    k0[i] = gamma_[i] * inv_std_[i];
    k1[i] = static_cast<float>(s1 / n);
    k2[i] = static_cast<float>(s2 / n);
  }
  // Pass 2: dy = gamma / sigma * (g - mean(g) - xhat * mean(g * xhat)).
  ParallelRows(rows, kRowGrain, [&](int64_t begin, int64_t end) {
    BatchNormGradApply(y + begin * ldy,
                       ldy,
                       end - begin,
                       c_count,
                       inv_std_.data(),
                       mean_.data(),
                       k0.data(),
                       k1.data(),
                       k2.data(),
                       dy + begin * lddy,
                       lddy);
  });
}

// ---------------------------------------------------------------------------
// ResBlockOp

namespace {

std::vector<LinearOp::Part> FirstParts(ResConv1DBlockImpl& block) {
  std::vector<LinearOp::Part> parts{{block.conv1.get(), {}}};
  if (block.has_shortcut_conv()) {
    parts.push_back({block.shortcut_conv.get(), {}});
  }
  return parts;
}

}  // namespace

ResBlockOp::ResBlockOp(ResConv1DBlockImpl& block,
                       bool relu_out,
                       float out_scale)
    : hidden_(block.conv1->weight.size(0)),
      out_(block.out_channels()),
      shortcut_(block.has_shortcut_conv()),
      relu_out_(relu_out),
      out_scale_(out_scale),
      first_(FirstParts(block)),
      second_(block.conv2.get()),
      bn1_(block.bn1.get()),
      bn2_(block.bn2.get()) {
  if (shortcut_) {
    bn_short_ = std::make_unique<BatchNormOp>(block.shortcut_bn.get());
  }
}

void ResBlockOp::Pack() {
  first_.Pack();
  second_.Pack();
}

void ResBlockOp::Forward(const Context& ctx, const Mat& x, Mat& y) {
  const int64_t rows = x.rows;
  z_.Resize(rows, first_.out_channels());
  a_.Resize(rows, hidden_);
  z2_.Resize(rows, out_);
  y.Resize(rows, out_);
  first_.Forward(ctx, x.data(), x.ld, rows, z_.data(), z_.ld);
  bn1_.Forward(ctx,
               z_.data(),
               z_.ld,
               rows,
               nullptr,
               0,
               /*relu=*/true,
               1.0f,
               a_.data(),
               a_.ld);
  const float* add = x.data();
  int64_t ldadd = x.ld;
  if (shortcut_) {
    s_.Resize(rows, out_);
    bn_short_->Forward(ctx,
                       z_.data() + hidden_,
                       z_.ld,
                       rows,
                       nullptr,
                       0,
                       /*relu=*/false,
                       1.0f,
                       s_.data(),
                       s_.ld);
    add = s_.data();
    ldadd = s_.ld;
  }
  second_.Forward(ctx, a_.data(), a_.ld, rows, z2_.data(), z2_.ld);
  bn2_.Forward(ctx,
               z2_.data(),
               z2_.ld,
               rows,
               add,
               ldadd,
               relu_out_,
               out_scale_,
               y.data(),
               y.ld);
}

void ResBlockOp::Backward(const Context& ctx,
                          const Mat& x,
                          const Mat& y,
                          Mat& dy,
                          Mat* dx,
                          bool accumulate) {
  const int64_t rows = x.rows;
  g_.Resize(rows, out_);  // gradient of the addend (shortcut path)
  dz_.Resize(rows, first_.out_channels());
  // dy -> dz2 (in place) and g = d(addend).
  bn2_.Backward(ctx,
                z2_.data(),
                z2_.ld,
                y.data(),
                y.ld,
                dy.data(),
                dy.ld,
                rows,
                dy.data(),
                dy.ld,
                g_.data(),
                g_.ld);
  // conv2: da into the hidden columns of dz.
  second_.Backward(ctx,
                   a_.data(),
                   a_.ld,
                   dy.data(),
                   dy.ld,
                   rows,
                   dz_.data(),
                   dz_.ld,
                   /*accumulate=*/false);
  bn1_.Backward(ctx,
                z_.data(),
                z_.ld,
                a_.data(),
                a_.ld,
                dz_.data(),
                dz_.ld,
                rows,
                dz_.data(),
                dz_.ld,
                nullptr,
                0);
  if (shortcut_) {
    bn_short_->Backward(ctx,
                        z_.data() + hidden_,
                        z_.ld,
                        s_.data(),
                        s_.ld,
                        g_.data(),
                        g_.ld,
                        rows,
                        dz_.data() + hidden_,
                        dz_.ld,
                        nullptr,
                        0);
  }
  if (dx != nullptr) dx->Resize(rows, x.cols);
  first_.Backward(ctx,
                  x.data(),
                  x.ld,
                  dz_.data(),
                  dz_.ld,
                  rows,
                  dx != nullptr ? dx->data() : nullptr,
                  dx != nullptr ? dx->ld : 0,
                  accumulate);
  if (dx != nullptr && !shortcut_) {
    AddInPlace(g_.data(), g_.ld, rows, out_, dx->data(), dx->ld);
  }
}

}  // namespace fast
}  // namespace soma
