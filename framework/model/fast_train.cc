#include "framework/model/fast_train.h"

#include "framework/core/error.h"
#include "framework/model/fast_loss.h"
#include "framework/model/fast_parallel.h"
#include "framework/model/labeler.h"
#include "framework/model/layers.h"
#include "framework/model/normalization.h"

#include <ATen/Parallel.h>
#include <fmt/format.h>
#include <torch/optim/adam.h>
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
/// Rows per chunk of the elementwise passes.
constexpr int64_t kRowGrain = 64;
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

float* Grad(at::Tensor& parameter) {
  at::Tensor& grad = parameter.mutable_grad();
  if (!grad.defined() || !grad.sizes().equals(parameter.sizes())) {
    grad = torch::zeros_like(parameter);
  }
  SOMA_CHECK(grad.is_contiguous() && grad.scalar_type() == torch::kFloat)
      << "fast training needs contiguous float gradients";
  return grad.data_ptr<float>();
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

/// Head-major position `head * dh + d` -> interleaved channel `d * h + head`.
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

/// `y = max(x, 0)` elementwise (`rows x cols`).
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

/// `dy *= (mask > 0)` elementwise.
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

/// `y += x` elementwise over the first `cols` columns.
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

/// `y = a + b` elementwise over the first `cols` columns.
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
  if (ctx.bf16) {
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
  if (ctx.bf16) {
    // The bias gradient.
    db_ = ParallelColumnReduce(
        rows, out_, [&](int64_t begin, int64_t end, double* sums, float* tmp) {
          ColumnSums(dy + begin * ldy, ldy, end - begin, out_, sums, tmp);
        });
    // dW = dy^T x on AMX: x packed once (threads split its rows), then the
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
  if (ctx.bf16) {
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

/// Frames per chunk of the per-frame loops (attention, loss).
constexpr int64_t kFrameGrain = 4;

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

// ---------------------------------------------------------------------------
// Normalization + loss

namespace {

/// Per-thread scratch of the per-frame loss loops (grow-only).
struct ThreadScratch {
  internal::FrameLossScratch frame;
  std::vector<float> g;
  std::vector<float> w;
};

class SinkhornLossOp : public NormalizationLossOp {
 public:
  SinkhornLossOp(at::Tensor bin_score, int num_iters)
      : bin_score_(std::move(bin_score)), num_iters_(num_iters) {}

  double ForwardBackward(const Context& ctx,
                         const Mat& scores,
                         const int64_t* label_ids,
                         int64_t num_labels,
                         Mat& d_scores) override {
    const int64_t n = ctx.points;
    const int64_t l = num_labels;
    const double alpha = bin_score_.item<double>();
    d_scores.Resize(scores.rows, l);
    std::vector<double> loss(static_cast<size_t>(ctx.batch), 0.0);
    std::vector<double> dalpha(static_cast<size_t>(ctx.batch), 0.0);
    scratch_.resize(static_cast<size_t>(internal::FastParallelThreads()));
    internal::FastParallelFor(
        0, ctx.batch, kFrameGrain, [&](int64_t begin, int64_t end) {
          ThreadScratch& own = scratch_[static_cast<size_t>(
              internal::FastParallelThreadIndex())];
          internal::FrameLossScratch& scratch = own.frame;
          std::vector<float>& g = own.g;
          std::vector<float>& w = own.w;
          g.resize(static_cast<size_t>((n + 1) * (l + 1)));
          w.resize(g.size());
          for (int64_t f = begin; f < end; ++f) {
            internal::BuildFrameTargets(
                label_ids + f * n, n, l, true, g.data(), w.data());
            double da = 0.0;
            loss[static_cast<size_t>(f)] =
                internal::SinkhornLossFrame(scores.row(f * n),
                                            scores.ld,
                                            n,
                                            l,
                                            alpha,
                                            num_iters_,
                                            g.data(),
                                            w.data(),
                                            nullptr,
                                            d_scores.row(f * n),
                                            d_scores.ld,
                                            1.0,
                                            &da,
                                            scratch);
            dalpha[static_cast<size_t>(f)] = da;
          }
        });
    double total = 0.0, total_dalpha = 0.0;
    for (size_t f = 0; f < loss.size(); ++f) {
      total += loss[f];
      total_dalpha += dalpha[f];
    }
    *Grad(bin_score_) = static_cast<float>(total_dalpha);
    return total;
  }

 private:
  at::Tensor bin_score_;
  int num_iters_;
  std::vector<ThreadScratch> scratch_;
};

class LogSoftmaxLossOp : public NormalizationLossOp {
 public:
  explicit LogSoftmaxLossOp(const LabelingLossOptions& options)
      : options_(options) {}

  double ForwardBackward(const Context& ctx,
                         const Mat& scores,
                         const int64_t* label_ids,
                         int64_t num_labels,
                         Mat& d_scores) override {
    const int64_t n = ctx.points;
    const int64_t l = num_labels;
    d_scores.Resize(scores.rows, l + 1);
    std::vector<double> loss(static_cast<size_t>(ctx.batch), 0.0);
    scratch_.resize(static_cast<size_t>(internal::FastParallelThreads()));
    internal::FastParallelFor(
        0, ctx.batch, kFrameGrain, [&](int64_t begin, int64_t end) {
          ThreadScratch& own = scratch_[static_cast<size_t>(
              internal::FastParallelThreadIndex())];
          internal::FrameLossScratch& scratch = own.frame;
          std::vector<float>& g = own.g;
          std::vector<float>& w = own.w;
          g.resize(static_cast<size_t>((n + 1) * (l + 1)));
          w.resize(g.size());
          for (int64_t f = begin; f < end; ++f) {
            internal::BuildFrameTargets(
                label_ids + f * n, n, l, false, g.data(), w.data());
            loss[static_cast<size_t>(f)] =
                internal::LogSoftmaxLossFrame(scores.row(f * n),
                                              scores.ld,
                                              n,
                                              l,
                                              options_.quirk_probability_loss,
                                              g.data(),
                                              w.data(),
                                              nullptr,
                                              d_scores.row(f * n),
                                              d_scores.ld,
                                              1.0,
                                              scratch);
          }
        });
    double total = 0.0;
    for (double value : loss) total += value;
    return total;
  }

 private:
  LabelingLossOptions options_;
  std::vector<ThreadScratch> scratch_;
};

}  // namespace

std::unique_ptr<NormalizationLossOp> MakeSinkhornLossOp(at::Tensor bin_score,
                                                        int num_iters) {
  return std::make_unique<SinkhornLossOp>(std::move(bin_score), num_iters);
}

std::unique_ptr<NormalizationLossOp> MakeLogSoftmaxLossOp(
    const LabelingLossOptions& loss) {
  return std::make_unique<LogSoftmaxLossOp>(loss);
}

}  // namespace fast

// ---------------------------------------------------------------------------
// FastTrainer

std::unique_ptr<FastTrainer> FastTrainer::Create(
    LabelerImpl& model,
    const LabelingLoss& loss,
    const FastTrainerOptions& options,
    std::string* why_not) {
  std::string reason;
  if (options.bf16 && !internal::AmxBf16Available()) {
    if (why_not != nullptr) {
      *why_not =
          "bf16 products need AMX-BF16, which this CPU (or kernel) "
          "does not provide";
    }
    return nullptr;
  }
  std::unique_ptr<fast::BackboneOp> backbone;
  std::unique_ptr<fast::NormalizationLossOp> norm;
  try {
    backbone = model.backbone->MakeFastTrainOp(&reason);
    if (backbone != nullptr) {
      norm = model.normalization->MakeFastLossOp(loss, &reason);
    }
    if (backbone == nullptr || norm == nullptr) {
      if (why_not != nullptr) *why_not = reason;
      return nullptr;
    }
    return std::unique_ptr<FastTrainer>(
        new FastTrainer(model, std::move(backbone), std::move(norm), options));
  } catch (const InternalError& e) {
    if (why_not != nullptr) *why_not = e.what();
    return nullptr;
  }
}

FastTrainer::FastTrainer(LabelerImpl& model,
                         std::unique_ptr<fast::BackboneOp> backbone,
                         std::unique_ptr<fast::NormalizationLossOp> loss,
                         const FastTrainerOptions& options)
    : model_(model), backbone_(std::move(backbone)), loss_(std::move(loss)) {
  ctx_.isa = internal::ResolveIsa(options.isa);
  ctx_.bf16 = options.bf16;
  encoder_ = std::make_unique<fast::ResBlockOp>(*model.encoder->block,
                                                /*relu_out=*/true,
                                                1.0f);
  const float head_scale = static_cast<float>(
      1.0 / std::sqrt(static_cast<double>(model.options().d_model)));
  head_ = std::make_unique<fast::ResBlockOp>(*model.head->block,
                                             /*relu_out=*/true,
                                             head_scale);
  classifier_ = std::make_unique<fast::LinearOp>(model.head->classifier.get());
}

FastTrainer::~FastTrainer() = default;

double FastTrainer::Step(const at::Tensor& points,
                         const at::Tensor& label_ids) {
  SOMA_CHECK(points.dim() == 3 && points.size(2) == 3)
      << "FastTrainer: points must be B x N x 3";
  SOMA_CHECK(label_ids.dim() == 2 && label_ids.size(0) == points.size(0) &&
             label_ids.size(1) == points.size(1))
      << "FastTrainer: label ids must be B x N";
  const at::Tensor p = points.to(torch::kFloat).contiguous();
  const at::Tensor ids = label_ids.to(torch::kLong).contiguous();
  ctx_.batch = p.size(0);
  ctx_.points = p.size(1);
  const int64_t n = ctx_.points;
  const int64_t rows = ctx_.rows();
  const int64_t num_labels = model_.num_labels();
  torch::NoGradGuard no_grad;

  // Median centring (no gradient: the points are data).
  points_.Resize(rows, 3);
  const float* src = p.data_ptr<float>();
  internal::FastParallelFor(0, ctx_.batch, 16, [&](int64_t begin, int64_t end) {
    for (int64_t f = begin; f < end; ++f) {
      float offset[3];
      internal::MedianOffset(src + f * n * 3, n, offset);
      for (int64_t i = 0; i < n; ++i) {
        float* dst = points_.row(f * n + i);
        for (int c = 0; c < 3; ++c)
          dst[c] = src[(f * n + i) * 3 + c] - offset[c];
      }
    }
  });

  encoder_->Pack();
  backbone_->Pack();
  head_->Pack();
  classifier_->Pack();

  // Forward.
  encoder_->Forward(ctx_, points_, features_);
  backbone_->Forward(ctx_, features_, backbone_out_);
  fast::Relu(backbone_out_, head_in_);
  head_->Forward(ctx_, head_in_, head_out_);
  scores_.Resize(rows, classifier_->out_channels());
  classifier_->Forward(
      ctx_, head_out_.data(), head_out_.ld, rows, scores_.data(), scores_.ld);
  const double loss = loss_->ForwardBackward(
      ctx_, scores_, ids.data_ptr<int64_t>(), num_labels, d_scores_);

  // Backward.
  d_head_out_.Resize(rows, head_out_.cols);
  classifier_->Backward(ctx_,
                        head_out_.data(),
                        head_out_.ld,
                        d_scores_.data(),
                        d_scores_.ld,
                        rows,
                        d_head_out_.data(),
                        d_head_out_.ld,
                        false);
  head_->Backward(ctx_, head_in_, head_out_, d_head_out_, &d_head_in_, false);
  fast::ReluBackwardInPlace(backbone_out_, d_head_in_);
  backbone_->Backward(ctx_, d_head_in_, d_features_);
  encoder_->Backward(ctx_, points_, features_, d_features_, nullptr, false);
  return loss;
}

// ---------------------------------------------------------------------------
// Fused Adam

namespace {

/// One parameter's update: its tensors and step constants, at `offset` in
/// the concatenation of all parameters.
struct AdamSegment {
  float* w = nullptr;
  const float* g = nullptr;
  float* m = nullptr;
  float* v = nullptr;
  int64_t count = 0;
  int64_t offset = 0;
  float step_size = 0.0f;
  float inv_bc2_sqrt = 0.0f;
  float b1 = 0.0f;
  float b2 = 0.0f;
  float eps = 0.0f;
  float wd = 0.0f;
};

}  // namespace

bool FusedAdamStep(torch::optim::Optimizer& optimizer) {
  auto* adam = dynamic_cast<torch::optim::Adam*>(&optimizer);
  if (adam == nullptr) return false;
  for (const auto& group : adam->param_groups()) {
    const auto& options =
        static_cast<const torch::optim::AdamOptions&>(group.options());
    if (options.amsgrad()) return false;
  }
  torch::NoGradGuard no_grad;
  std::vector<AdamSegment> segments;
  int64_t total = 0;
  for (auto& group : adam->param_groups()) {
    const auto& options =
        static_cast<const torch::optim::AdamOptions&>(group.options());
    const double lr = options.lr();
    const double beta1 = std::get<0>(options.betas());
    const double beta2 = std::get<1>(options.betas());
    const float eps = static_cast<float>(options.eps());
    const float wd = static_cast<float>(options.weight_decay());
    for (at::Tensor& p : group.params()) {
      if (!p.grad().defined()) continue;
      const std::string key = c10::guts::to_string(p.unsafeGetTensorImpl());
      auto& states = adam->state();
      auto it = states.find(key);
      if (it == states.end()) {
        auto state = std::make_unique<torch::optim::AdamParamState>();
        state->step(0);
        state->exp_avg(torch::zeros_like(p, at::MemoryFormat::Preserve));
        state->exp_avg_sq(torch::zeros_like(p, at::MemoryFormat::Preserve));
        it = states.emplace(key, std::move(state)).first;
      }
      auto& state = static_cast<torch::optim::AdamParamState&>(*it->second);
      state.step(state.step() + 1);
      const double bc1 = 1.0 - std::pow(beta1, double(state.step()));
      const double bc2 = 1.0 - std::pow(beta2, double(state.step()));
      const float step_size = static_cast<float>(lr / bc1);
      const float inv_bc2_sqrt = static_cast<float>(1.0 / std::sqrt(bc2));
      const float b1 = static_cast<float>(beta1);
      const float b2 = static_cast<float>(beta2);
      SOMA_CHECK(p.is_contiguous() && p.grad().is_contiguous() &&
                 state.exp_avg().is_contiguous() &&
                 state.exp_avg_sq().is_contiguous() &&
                 p.scalar_type() == torch::kFloat)
          << "FusedAdamStep needs contiguous float tensors";
      AdamSegment segment;
      segment.w = p.data_ptr<float>();
      segment.g = p.grad().data_ptr<float>();
      segment.m = state.exp_avg().data_ptr<float>();
      segment.v = state.exp_avg_sq().data_ptr<float>();
      segment.count = p.numel();
      segment.step_size = step_size;
      segment.inv_bc2_sqrt = inv_bc2_sqrt;
      segment.b1 = b1;
      segment.b2 = b2;
      segment.eps = eps;
      segment.wd = wd;
      segment.offset = total;
      total += segment.count;
      segments.push_back(segment);
    }
  }
  // All parameters in one parallel loop over their concatenated elements.
  internal::FastParallelFor(0, total, 16384, [&](int64_t begin, int64_t end) {
    auto it = std::upper_bound(
        segments.begin(),
        segments.end(),
        begin,
        [](int64_t value, const AdamSegment& s) { return value < s.offset; });
    for (--it; it != segments.end() && it->offset < end; ++it) {
      const AdamSegment& s = *it;
      const int64_t i0 = std::max<int64_t>(begin - s.offset, 0);
      const int64_t i1 = std::min<int64_t>(end - s.offset, s.count);
      for (int64_t i = i0; i < i1; ++i) {
        const float grad = s.g[i] + s.wd * s.w[i];
        s.m[i] = s.m[i] * s.b1 + (1.0f - s.b1) * grad;
        s.v[i] = s.v[i] * s.b2 + (1.0f - s.b2) * grad * grad;
        const float denom = std::sqrt(s.v[i]) * s.inv_bc2_sqrt + s.eps;
        s.w[i] -= s.step_size * s.m[i] / denom;
      }
    }
  });
  return true;
}

}  // namespace soma
