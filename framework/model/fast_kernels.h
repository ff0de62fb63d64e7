// CPU kernels of the optimised labeler forward (fast_labeler.h) and of the
// training engine (fast_train.h): a GEMM against pre-packed weights with a
// fused epilogue (bias, residual, ReLU) that can also read its left operand
// transposed in place, row softmax, one attention head, and the per-frame
// output normalisations (Sinkhorn optimal transport, log-softmax). No torch
// dependency.
//
// Layout convention: activations are point-major (`rows x channels`, one row
// per point, channels contiguous, row stride `ld`), so a per-point conv is
// `Y = X W^T + b`. Weights are packed once into panels of 16 output channels
// (k-major: `panel[k * 16 + j] = W[16 p + j][k]`), so the micro-kernel streams
// 16-wide weight vectors and broadcasts activations. On AVX-512 machines the
// micro-kernel keeps an 8-row x 48-column tile in registers; elsewhere a
// portable loop implementation with the same results up to rounding is used.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

namespace soma::internal {

/// Instruction set used by the kernels.
enum class KernelIsa {
  kAuto,      // AVX-512 when the CPU has it, else portable
  kPortable,  // plain C++ loops (any CPU)
  kAvx512,    // AVX-512F intrinsics (throws InternalError if unsupported)
};

/// Resolves kAuto against the running CPU.
KernelIsa ResolveIsa(KernelIsa isa);

/// A grow-only, 64-byte aligned float buffer.
class AlignedFloats {
 public:
  AlignedFloats() = default;
  explicit AlignedFloats(size_t size) { Resize(size); }
  /// Ensures capacity for `size` floats (contents are not preserved when it
  /// grows; new memory is zeroed).
  void Resize(size_t size);
  float* data() { return data_.get(); }
  const float* data() const { return data_.get(); }
  size_t size() const { return size_; }

 private:
  struct Free {
    void operator()(float* p) const;
  };
  std::unique_ptr<float[], Free> data_;
  size_t size_ = 0;
};

/// Number of 16-wide panels for `m` output channels.
inline int64_t NumPanels(int64_t m) { return (m + 15) / 16; }
/// `m` rounded up to a multiple of 16 (row strides of the activations).
inline int64_t RoundUp16(int64_t m) { return NumPanels(m) * 16; }

/// Weights as the micro-kernel reads them: output channel `16 p + j`,
/// input channel `k` is `data[p * panel_stride + k * k_stride + j]`; `bias`
/// (may be nullptr) has `NumPanels(rows) * 16` entries. Lanes of the last
/// panel past `rows` are read (must be readable) but never stored.
struct WeightView {
  const float* data = nullptr;
  int64_t panel_stride = 0;
  int64_t k_stride = 16;
  const float* bias = nullptr;
  int64_t rows = 0;  // M, output channels
  int64_t cols = 0;  // K, input channels
};

/// A weight matrix W (`rows x cols` = `M x K`) and bias packed for the GEMM:
/// panels of 16 output channels, k-major; rows beyond M are zero.
struct PackedWeights {
  int64_t rows = 0;      // M, output channels
  int64_t cols = 0;      // K, input channels
  AlignedFloats panels;  // NumPanels(M) * K * 16
  AlignedFloats bias;    // NumPanels(M) * 16 (zero-padded)
  int64_t num_panels() const { return NumPanels(rows); }
  WeightView view() const {
    return {panels.data(), cols * 16, 16, bias.data(), rows, cols};
  }
};

/// Packs row-major `w` (`m x k`) and `bias` (length m, or nullptr = 0).
PackedWeights PackWeights(const float* w,
                          const float* bias,
                          int64_t m,
                          int64_t k);

/// What is applied to `acc = sum + bias` before storing, in order:
/// `acc * row_scale[r]` (per output row; nullptr = 1), `+ residual` (same
/// shape as the output, may alias it), ReLU on output columns
/// `[0, relu_columns)`.
struct GemmEpilogue {
  const float* row_scale = nullptr;
  const float* residual = nullptr;
  int64_t ld_residual = 0;
  int64_t relu_columns = 0;
};

/// `Y[r][m] = epilogue(sum_k X[r][k] * W[m][k] + b[m])` for `r < rows` and
/// the output channels of panels `[panel_begin, panel_end)` of `w` (channels
/// >= M are not written). Different panel ranges may run concurrently.
void GemmPacked(KernelIsa isa,
                const float* x,
                int64_t ldx,
                int64_t rows,
                const WeightView& w,
                float* y,
                int64_t ldy,
                const GemmEpilogue& epilogue,
                int64_t panel_begin,
                int64_t panel_end);

/// GemmPacked with `X[r][k]` read at `x[r * ldx + k * x_k_stride]`: with
/// `ldx = 1, x_k_stride = ld` it multiplies by a transposed matrix in place
/// (the training engine's `dW = dY^T X` and the attention's `P^T dO`).
void GemmPackedStrided(KernelIsa isa,
                       const float* x,
                       int64_t ldx,
                       int64_t x_k_stride,
                       int64_t rows,
                       const WeightView& w,
                       float* y,
                       int64_t ldy,
                       const GemmEpilogue& epilogue,
                       int64_t panel_begin,
                       int64_t panel_end);

/// `dst[c * ldd + r] = src[r * lds + c]` for `rows x cols` (AVX-512: 16 x 16
/// tiles transposed in registers, with masked loads and stores at the edges).
void Transpose(KernelIsa isa,
               const float* src,
               int64_t lds,
               int64_t rows,
               int64_t cols,
               float* dst,
               int64_t ldd);

/// GemmPacked over all panels of `w`.
void Gemm(KernelIsa isa,
          const float* x,
          int64_t ldx,
          int64_t rows,
          const PackedWeights& w,
          float* y,
          int64_t ldy,
          const GemmEpilogue& epilogue = {});

/// Softmax of the first `n` entries of each of `rows` rows, in place. With
/// `inv_sums` (length rows) the rows are left unnormalised (exp(s - max))
/// and `inv_sums[r]` receives 1 / sum_r.
void SoftmaxRows(KernelIsa isa,
                 float* s,
                 int64_t ld,
                 int64_t rows,
                 int64_t n,
                 float* inv_sums = nullptr);

/// `x[i] = exp(x[i])` for `i < n` (AVX-512: polynomial, ~1 ulp float,
/// < 1e-14 relative double).
void ExpInPlace(KernelIsa isa, float* x, int64_t n);
void ExpInPlace(KernelIsa isa, double* x, int64_t n);

/// Keys per head up to which AttentionProbs and AttentionScoresGrad keep a
/// whole score row in registers (AVX-512); longer rows take the GEMM +
/// separate softmax path (same results up to rounding).
inline constexpr int64_t kMaxFusedKeys = 48;

/// One head's attention probabilities on `n` points: `p[r][j] = softmax_j(
/// scale * sum_d q[r][d] kt[d][j])` for `r, j < n`, with `kt` the keys
/// transposed (`dh x n`, row stride `ldkt`, each row readable for
/// RoundUp16(n) floats). Writes the first n entries of each of the n rows of
/// `p` (row stride `ldp`).
void AttentionProbs(KernelIsa isa,
                    const float* q,
                    int64_t ldq,
                    const float* kt,
                    int64_t ldkt,
                    int64_t n,
                    int64_t dh,
                    float scale,
                    float* p,
                    int64_t ldp);

/// The scores' gradient of one head from its probabilities `p` (`n x n`):
/// `dp = dout v^T` with `vt` the values transposed (`dh x n`, row stride
/// `ldvt`, rows readable for RoundUp16(n) floats), then `ds[r][j] = p[r][j]
/// (dp[r][j] - sum_j' dp[r][j'] p[r][j']) * scale` (softmax backward with the
/// score scale), first n entries of n rows of `ds` (row stride `lds`).
void AttentionScoresGrad(KernelIsa isa,
                         const float* dout,
                         int64_t ldo,
                         const float* vt,
                         int64_t ldvt,
                         const float* p,
                         int64_t ldp,
                         int64_t n,
                         int64_t dh,
                         float scale,
                         float* ds,
                         int64_t lds);

/// Scratch of one attention head (reused across calls).
struct AttentionScratch {
  AlignedFloats keys;      // packed keys, NumPanels(n) * dh * 16
  AlignedFloats scores;    // n x RoundUp16(n)
  AlignedFloats inv_sums;  // n softmax normalisers
};

/// One head of scaled dot-product self-attention on `n` points:
/// `out = softmax(q k^T) v` where q, k, v are `n x dh` (row stride `ld_qkv`;
/// the 1/sqrt(dh) scale must already be folded into q). Writes `n x dh` to
/// `out` (row stride `ld_out`). v is read in place 16 channels at a time, so
/// each v row must be readable for RoundUp16(dh) floats.
void AttentionHead(KernelIsa isa,
                   const float* q,
                   const float* k,
                   const float* v,
                   int64_t ld_qkv,
                   int64_t n,
                   int64_t dh,
                   float* out,
                   int64_t ld_out,
                   AttentionScratch& scratch);

/// Sinkhorn frames whose couplings span at most this many nats (max - min of
/// the scores and alpha) use the exp-domain (scaling) form; wider or
/// non-finite ones the log-domain (log-sum-exp) form (SinkhornFrame and the
/// training loss's SinkhornLossFrame, fast_loss.h).
constexpr double kSinkhornScalingMaxSpan = 200.0;

/// Couplings more than this many nats below the largest are exact zeros of
/// the exp-domain kernel (e^-745 is below the smallest double) and do not
/// count in the span, so that a frame with padded label slots (score
/// kPaddedSlotScore = -1e4, label_encoder.h) stays on the exp-domain path.
/// The dustbin score alpha always counts, and every row and column holds it,
/// so no row or column of the kernel is all zero; what the log-domain form
/// would add for such an entry is below e^-545 of its row's and column's
/// sums, under double rounding.
constexpr double kSinkhornUnderflowNats = 745.0;

/// The exp-domain Sinkhorn kernel of couplings `z` (`rows x cols`,
/// contiguous): `kernel` (`rows x cols_p`) = exp(z - zmax), exact zeros for
/// couplings kSinkhornUnderflowNats below `zmax`, zero padding, and its
/// transpose `kernel_t` (`cols x rows_p`).
void SinkhornScalingKernel(KernelIsa isa,
                           const double* z,
                           int64_t rows,
                           int64_t cols,
                           int64_t rows_p,
                           int64_t cols_p,
                           double zmax,
                           double* kernel,
                           double* kernel_t);

/// Log-domain optimal transport with dustbins for one frame (REFERENCE 1.4),
/// computed in double precision: `scores` is `n x l` (row stride
/// `ld_scores`), alpha the dustbin score; writes the `(n+1) x (l+1)` log
/// assignment (row-major, contiguous) to `out`. Uses the equivalent
/// exp-domain (scaling) iteration when the couplings span at most
/// kSinkhornScalingMaxSpan nats (not counting those kSinkhornUnderflowNats
/// below the largest), else log-sum-exp updates; both follow u-then-v
/// updates from u=v=0.
void SinkhornFrame(KernelIsa isa,
                   const float* scores,
                   int64_t ld_scores,
                   int64_t n,
                   int64_t l,
                   double alpha,
                   int num_iters,
                   float* out,
                   std::vector<double>& scratch);

/// Row-wise log_softmax of `n x c` scores into `out` (`n x c`, contiguous).
void LogSoftmaxFrame(
    const float* scores, int64_t ld_scores, int64_t n, int64_t c, float* out);

/// Per-coordinate lower median of the non-zero points of one frame (`n x
/// 3`, contiguous), (0,0,0) if none (REFERENCE 1.1).
void MedianOffset(const float* points, int64_t n, float offset[3]);

}  // namespace soma::internal
