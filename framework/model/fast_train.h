// The hand-written training engine of the SOMA labeler (`train.engine=fast`):
// forward and backward of the whole model on the kernels of fast_kernels.h,
// writing the gradients into the torch parameters' `.grad()` so that the
// optimizer, the checkpoints and the torch engine see the same tensors.
//
// What it computes is exactly LabelerImpl::forward in training mode followed
// by the labelling loss and autograd's backward:
// - per-point convs are GEMMs on point-major activations (`rows = B * N`,
//   channels contiguous); the weights are re-packed from the torch tensors
//   at every step (O(parameters), negligible next to the GEMMs);
// - BatchNorm uses the batch statistics over all B * N points (biased
//   variance), updates the running statistics as torch does (momentum,
//   unbiased variance, num_batches_tracked), and its backward is the exact
//   batch-statistics gradient;
// - attention runs per frame and head; the interleaved head channels
//   (`c = d * h + head`) are reordered head-major inside the packed weights
//   and the gradients are scattered back to torch's order;
// - the normalization (Sinkhorn with dustbins, unrolled backward; or
//   log-softmax) and the loss run per frame in double precision
//   (fast_loss.h).
// Gradients are checked against autograd per layer and for the whole model
// (tests/model/fast_train_test.cc).
//
// With `FastTrainerOptions::bf16` (`train.precision=bf16`) the per-point
// convolutions' products (forward, dX, dW) run in bf16 with fp32 accumulation
// on AMX or AVX512_BF16 (bf16_gemm.h), except the products over the 3 point
// coordinates and the classifier that makes the scores; weights, optimizer
// state, BatchNorm, attention, Sinkhorn and the loss stay fp32/double.
//
// A layout-conditioned labeller (model=soma_any_layout) trains on the same
// kernels for its point side and on torch autograd for its label side (see
// FastTrainer::Step), whose label encoder runs once per distinct label set of
// the batch (LabelEncoderImpl::EncodeSlots), not once per frame.
//
// Every component declares its own fast path: BackboneImpl::MakeFastTrainOp
// and NormalizationImpl::MakeFastLossOp return nullptr with a reason when a
// component has none, and FastTrainer::Create reports that reason, so a new
// backbone or normalization falls back to the torch engine with one log
// line, never silently.
#pragma once

#include "framework/model/bf16_gemm.h"
#include "framework/model/fast_kernels.h"
#include "framework/model/loss.h"

#include <ATen/core/Tensor.h>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace torch::nn {
class BatchNorm1dImpl;
class Conv1dImpl;
}  // namespace torch::nn

namespace torch::optim {
class Optimizer;
}  // namespace torch::optim

namespace soma {

class LabelerImpl;
struct LabelSlots;
class SelfAttentionImpl;
class Conv1dBackboneImpl;
class ResConv1DBlockImpl;
class MultiHeadAttentionImpl;

namespace fast {

/// A point-major activation matrix: `rows x cols`, row stride `ld` (a
/// multiple of 16 with at least 16 spare floats, so kernels may read whole
/// 16-lane vectors past `cols`).
struct Mat {
  internal::AlignedFloats buf;
  int64_t rows = 0;
  int64_t cols = 0;
  int64_t ld = 0;
  /// Sizes the matrix (contents unspecified).
  void Resize(int64_t num_rows, int64_t num_cols);
  float* row(int64_t r) { return buf.data() + r * ld; }
  const float* row(int64_t r) const { return buf.data() + r * ld; }
  float* data() { return buf.data(); }
  const float* data() const { return buf.data(); }
};

/// What every op of one step shares.
struct Context {
  internal::KernelIsa isa = internal::KernelIsa::kPortable;
  /// Per-point convolutions' products in bf16 (bf16_gemm.h, fp32
  /// accumulation; LinearOp::UsesBf16 says which); the rest stays
  /// fp32/double.
  bool bf16 = false;
  int64_t batch = 0;   // B frames
  int64_t points = 0;  // N points per frame
  int64_t rows() const { return batch * points; }
};

/// A stack of kernel-size-1 convolutions that read the same input, as one
/// GEMM: the outputs are the parts' outputs one after the other. A part may
/// reorder its output channels (`out_order[i]` = the torch output channel of
/// stacked channel i) and all parts may reorder the input channels
/// (`in_order[k]` = the torch input channel of packed input k).
class LinearOp {
 public:
  struct Part {
    torch::nn::Conv1dImpl* conv = nullptr;
    std::vector<int64_t> out_order;  // empty = identity
  };
  explicit LinearOp(std::vector<Part> parts,
                    std::vector<int64_t> in_order = {});
  /// One convolution in torch's channel order.
  explicit LinearOp(torch::nn::Conv1dImpl* conv)
      : LinearOp(std::vector<Part>{Part{conv, {}}}) {}
  int64_t in_channels() const { return in_; }
  int64_t out_channels() const { return out_; }
  /// Whether this op's products run in bf16 under `ctx`: a product over
  /// fewer than 16 inputs (the input embedding's 3 point coordinates) stays
  /// fp32, since bf16 would round the coordinates to 8 significant bits (~4
  /// mm at 1 m) and gains nothing there (its k pads to 32).
  bool UsesBf16(const Context& ctx) const { return ctx.bf16 && in_ >= 16; }

  /// Re-packs the weights from the torch parameters (after an update).
  void Pack();
  /// `y = x W^T + b` (+ epilogue) for `rows` rows.
  void Forward(const Context& ctx,
               const float* x,
               int64_t ldx,
               int64_t rows,
               float* y,
               int64_t ldy,
               const internal::GemmEpilogue& epilogue = {});
  /// Writes dL/dW and dL/db into the torch `.grad()` tensors (overwriting)
  /// and, if `dx` is not null, `dx = dy W` (`accumulate`: `dx += dy W`).
  void Backward(const Context& ctx,
                const float* x,
                int64_t ldx,
                const float* dy,
                int64_t ldy,
                int64_t rows,
                float* dx,
                int64_t lddx,
                bool accumulate);

 private:
  std::vector<Part> parts_;
  std::vector<int64_t> in_order_;
  int64_t in_ = 0;
  int64_t out_ = 0;
  internal::AlignedFloats wt_;          // in x RoundUp16(out): forward view
  internal::AlignedFloats bias_;        // RoundUp16(out)
  internal::AlignedFloats w_;           // out x RoundUp16(in): backward view
  internal::AlignedFloats dw_;          // out x RoundUp16(in)
  internal::AlignedFloats dw_partial_;  // per row range: out x RoundUp16(in)
  std::vector<double> db_;
  // bf16 path: packed operands and per-thread scratch.
  internal::PackedBf16 fwd_b_;  // W^T
  internal::PackedBf16 bwd_b_;  // W
  internal::PackedBf16 x_b_;    // the input, for dW
  bool fwd_packed_ = false;
  bool bwd_packed_ = false;
  std::vector<internal::Bf16Scratch> scratch_;
};

/// BatchNorm1d in training mode on a `rows x C` matrix, with an optional
/// addend after the affine map, ReLU and a final scale:
/// `out = act(scale * (gamma * (y - mean) / sqrt(var + eps) + beta + add))`.
class BatchNormOp {
 public:
  explicit BatchNormOp(torch::nn::BatchNorm1dImpl* bn);
  /// Batch statistics of `y`, running-statistics update, then `out`.
  /// `add` may be null; `out` may not alias `y`.
  void Forward(const Context& ctx,
               const float* y,
               int64_t ldy,
               int64_t rows,
               const float* add,
               int64_t ldadd,
               bool relu,
               float scale,
               float* out,
               int64_t ldout);
  /// Given `dout` (and `out` for the ReLU mask), writes `dy` (may alias
  /// `dout`) and, if not null, `dadd` (the gradient of the addend); writes
  /// dL/dgamma and dL/dbeta into the torch gradients.
  void Backward(const Context& ctx,
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
                int64_t lddadd);
  int64_t channels() const { return channels_; }

 private:
  torch::nn::BatchNorm1dImpl* bn_;
  int64_t channels_ = 0;
  double eps_ = 1e-5;
  double momentum_ = 0.1;
  bool relu_ = false;
  float scale_ = 1.0f;
  std::vector<float> mean_;
  std::vector<float> inv_std_;
  std::vector<float> gamma_;
  std::vector<float> beta_;
};

/// ResConv1DBlock (layers.h) with an optional ReLU and scale on its output.
class ResBlockOp {
 public:
  ResBlockOp(ResConv1DBlockImpl& block, bool relu_out, float out_scale);
  void Pack();
  /// `x`: rows x Cin -> `y`: rows x Cout (keeps what Backward needs).
  void Forward(const Context& ctx, const Mat& x, Mat& y);
  /// Given the Forward's `x` and `y` (unchanged since), `dy` (overwritten)
  /// -> `dx` (if not null; `accumulate` adds to it).
  void Backward(const Context& ctx,
                const Mat& x,
                const Mat& y,
                Mat& dy,
                Mat* dx,
                bool accumulate);

 private:
  int64_t hidden_ = 0;
  int64_t out_ = 0;
  bool shortcut_ = false;
  bool relu_out_ = false;
  float out_scale_ = 1.0f;
  LinearOp first_;  // [conv1 ; shortcut conv]
  LinearOp second_;
  BatchNormOp bn1_;
  BatchNormOp bn2_;
  std::unique_ptr<BatchNormOp> bn_short_;
  Mat z_;   // first GEMM output: [hidden | shortcut]
  Mat a_;   // ReLU(BN1(hidden))
  Mat s_;   // BN(shortcut) (shortcut conv only)
  Mat z2_;  // conv2 output
  Mat g_;   // gradient of the addend (shortcut path)
  Mat dz_;  // gradient of the first GEMM's output
};

/// A backbone's fast training path: `rows x D` features in and out.
class BackboneOp {
 public:
  virtual ~BackboneOp() = default;
  virtual void Pack() = 0;
  virtual void Forward(const Context& ctx, const Mat& x, Mat& y) = 0;
  /// `dy` (may be overwritten) -> `dx`.
  virtual void Backward(const Context& ctx, Mat& dy, Mat& dx) = 0;
};

/// The stacked self-attention backbone (SelfAttentionImpl).
class SelfAttentionOp : public BackboneOp {
 public:
  explicit SelfAttentionOp(SelfAttentionImpl& backbone);
  ~SelfAttentionOp() override;
  void Pack() override;
  void Forward(const Context& ctx, const Mat& x, Mat& y) override;
  void Backward(const Context& ctx, Mat& dy, Mat& dx) override;

 private:
  struct Layer;
  int64_t d_ = 0;
  int64_t heads_ = 0;
  std::vector<std::unique_ptr<Layer>> layers_;
  Mat dxcat_, dz_, dqkv_, do_;
};

/// The no-transformer ablation backbone (Conv1dBackboneImpl).
class Conv1dBackboneOp : public BackboneOp {
 public:
  explicit Conv1dBackboneOp(Conv1dBackboneImpl& backbone);
  ~Conv1dBackboneOp() override;
  void Pack() override;
  void Forward(const Context& ctx, const Mat& x, Mat& y) override;
  void Backward(const Context& ctx, Mat& dy, Mat& dx) override;

 private:
  struct Block;
  std::vector<std::unique_ptr<Block>> blocks_;
  std::vector<const Mat*> inputs_;  // each block's input (Forward)
  Mat dt_, du_;
};

/// Which label slots of each frame hold a label (a layout-conditioned
/// labeller's padded slots do not): `data` null (all do), or bool rows of
/// `num_labels`, `frame_stride` apart (0: one row shared by every frame).
/// A padded slot's loss weight is zero (its column, "not available", stays
/// in G', as the trainer's targets).
struct LabelMask {
  const bool* data = nullptr;
  int64_t frame_stride = 0;
};

/// A normalization and the loss on its output, per frame: scores `rows x
/// C` -> the batch loss (sum over frames) and d loss / d scores.
class NormalizationLossOp {
 public:
  virtual ~NormalizationLossOp() = default;
  /// Also writes the normalization's own parameter gradients. A `mask`
  /// with data needs the Sinkhorn op (InternalError otherwise).
  virtual double ForwardBackward(const Context& ctx,
                                 const Mat& scores,
                                 const int64_t* label_ids,
                                 int64_t num_labels,
                                 const LabelMask& mask,
                                 Mat& d_scores) = 0;
};

/// Sinkhorn with dustbins (SinkhornImpl) + the SOMA loss.
std::unique_ptr<NormalizationLossOp> MakeSinkhornLossOp(at::Tensor bin_score,
                                                        int num_iters);
/// Log-softmax (LogSoftmaxImpl) + the SOMA loss.
std::unique_ptr<NormalizationLossOp> MakeLogSoftmaxLossOp(
    const LabelingLossOptions& loss);

}  // namespace fast

/// Options of the fast engine.
struct FastTrainerOptions {
  internal::KernelIsa isa = internal::KernelIsa::kAuto;
  /// The per-point convolutions' products in bf16 on
  /// internal::DefaultBf16Backend() (AMX or AVX512_BF16; Create fails with
  /// the reason when there is neither).
  bool bf16 = false;
};

/// The training engine: one call computes the batch loss and every gradient.
class FastTrainer {
 public:
  /// The engine for `model` trained with `loss`, or nullptr with the reason
  /// in `*why_not` when a component has no fast path.
  static std::unique_ptr<FastTrainer> Create(LabelerImpl& model,
                                             const LabelingLoss& loss,
                                             const FastTrainerOptions& options,
                                             std::string* why_not);
  ~FastTrainer();

  /// Forward in training mode, loss and backward on one batch: `points` `B
  /// x N x 3` float, `label_ids` `B x N` int64 (L = null). Overwrites the
  /// parameters' gradients and updates the BatchNorm running statistics
  /// (as torch's forward in training mode). Returns the batch loss (the sum
  /// over frames, as the torch engine).
  ///
  /// A layout-conditioned labeller (model=soma_any_layout) takes the batch's
  /// label `slots` (LabelerImpl::ForwardSlots; null: the layout it holds,
  /// LabelerImpl::LayoutSlots) and the trainer's loss targets (padded slots
  /// weigh zero). Its point side (encoder, backbone, the score head's block
  /// and point projection) runs on the kernels; its label side (label
  /// encoder, label projection, the scaled product, the padded slots'
  /// scores) on torch autograd (LabelerImpl::ConditionedScores), fed the
  /// point keys and handing their gradient back; Sinkhorn and the loss on
  /// the kernels again. Its position loss (LabelerImpl::PositionLoss),
  /// when weighted, is added to the returned loss and its gradient to the
  /// point keys', on torch autograd. A plain labeller given slots:
  /// InternalError.
  double Step(const at::Tensor& points,
              const at::Tensor& label_ids,
              const LabelSlots* slots = nullptr);

  internal::KernelIsa isa() const { return ctx_.isa; }
  bool bf16() const { return ctx_.bf16; }

 private:
  FastTrainer(LabelerImpl& model,
              std::unique_ptr<fast::BackboneOp> backbone,
              std::unique_ptr<fast::NormalizationLossOp> loss,
              const FastTrainerOptions& options);

  /// A conditioned labeller's label side (FastTrainer::Step): from the
  /// point keys `keys_` to the scores on torch autograd, Sinkhorn and the
  /// loss on the kernels, then the gradients back to `d_keys_` and the
  /// label side's parameters; with a position loss
  /// (LabelerImpl::PositionLoss) that too, on torch autograd. `labels`
  /// `B x N` int64, contiguous. Returns the batch loss.
  double LabelSideLoss(const at::Tensor& labels, const LabelSlots* slots);

  LabelerImpl& model_;
  fast::Context ctx_;
  std::unique_ptr<fast::ResBlockOp> encoder_;
  std::unique_ptr<fast::BackboneOp> backbone_;
  // The score head's block, then its classifier (plain) or point
  // projection (conditioned: the point keys).
  std::unique_ptr<fast::ResBlockOp> head_;
  std::unique_ptr<fast::LinearOp> classifier_;
  /// A conditioned labeller's parameters trained on torch autograd (label
  /// encoder, the score head's label side, the position head), collected
  /// once: LabelSideLoss overwrites their gradients each step.
  std::vector<at::Tensor> autograd_parameters_;
  std::unique_ptr<fast::NormalizationLossOp> loss_;
  fast::Mat points_, features_, backbone_out_, head_in_, head_out_, scores_;
  fast::Mat d_scores_, d_head_out_, d_head_in_, d_features_;
  fast::Mat keys_, d_keys_;  // conditioned: point keys (rows x D)
};

/// One Adam step (torch::optim::Adam semantics: classic L2 weight decay,
/// bias corrections, no amsgrad) fused into one pass per parameter, on the
/// optimizer's own state tensors (exp_avg, exp_avg_sq, step), so checkpoints
/// and resumes see exactly what torch's step would leave. Returns false
/// (doing nothing) when `optimizer` is not a plain Adam; the caller then runs
/// `optimizer.step()`.
bool FusedAdamStep(torch::optim::Optimizer& optimizer);

}  // namespace soma
