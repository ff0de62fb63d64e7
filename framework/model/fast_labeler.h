// Optimised CPU inference path of the SOMA labeler.
//
// FastLabeler snapshots an (eval-mode) Labeler's weights and folds them for
// inference:
// - every BatchNorm is folded into the preceding conv (running statistics);
// - q, k, v are one GEMM, with the 1/sqrt(dh) scale folded into q and the
//   interleaved head channels (c = d*h + head) reordered head-major;
// - the merge conv is folded into the first post-merge conv (both linear):
//   conv1(cat[merge(o), x]) = (W1a Wm) o + W1b x + (W1a bm + b1), so each
//   attention layer is three GEMMs (qkv, [o|x] -> 2D, 2D -> D) plus the
//   heads, with bias, ReLU and residual fused into the GEMM epilogue;
// - a ResConv1DBlock is two GEMMs: [conv1; shortcut conv] on the shared
//   input, then conv2 with the shortcut output added in the epilogue;
// - attention heads use the same micro-kernel (keys packed per head, values
//   read in place) with the softmax normalisation applied to P v;
// - the 1/sqrt(D) score scaling is folded into the classifier; for the
//   layout-conditioned labeler (model=soma_any_layout) the classifier is its
//   score head's point projection times the keys of the layout it holds
//   (the label branch runs once, in torch, when the snapshot is taken);
// - the GEMMs run on a register-tiled AVX-512 micro-kernel against packed
//   weights (portable fallback elsewhere), on point-major activations kept in
//   reused, aligned buffers (no allocation per call after the first);
// - Sinkhorn runs per frame in double precision in scaling form (a matrix-
//   vector product per half-iteration instead of log-sum-exps);
// - frames are split across torch's intra-op threads (at::parallel_for;
//   fast_labeler.cc is compiled with OpenMP, libtorch's backend) in blocks of
//   frames_per_block taken from a shared counter; with fewer frames than
//   threads, GEMM panels, attention heads and frames are split instead.
// Results match LabelerImpl::forward in eval mode to ~1e-5 (tested to 1e-4).
// The snapshot does not follow later weight updates: rebuild after training.
#pragma once

#include "framework/model/fast_kernels.h"
#include "framework/model/labeler_output.h"

#include <ATen/core/Tensor.h>

#include <cstdint>
#include <memory>

namespace soma {

class LabelerImpl;

/// Options of the optimised forward.
struct FastLabelerOptions {
  /// Kernel instruction set (kAuto: AVX-512 when available).
  internal::KernelIsa isa = internal::KernelIsa::kAuto;
  /// Frames whose activations are processed together by one thread (bounds
  /// the working set to the L2 cache).
  int frames_per_block = 8;
  /// Threads; <= 0: torch's intra-op thread count (at::get_num_threads()).
  int num_threads = 0;
};

/// The folded, optimised inference model (see the file comment).
class FastLabeler {
 public:
  /// Snapshots `model`'s parameters and BatchNorm running statistics (and a
  /// layout-conditioned labeler's held layout: after SetLayout, rebuild).
  /// Supports the `self_attention` and `conv1d` backbones and the `sinkhorn`
  /// and `log_softmax` normalizations, and the layout-conditioned labeler
  /// in eval mode with Sinkhorn and a held layout; throws InternalError
  /// otherwise.
  explicit FastLabeler(const LabelerImpl& model,
                       const FastLabelerOptions& options = {});
  ~FastLabeler();
  FastLabeler(FastLabeler&&) noexcept;
  FastLabeler& operator=(FastLabeler&&) noexcept;

  /// True if `model`'s backbone and normalization are supported.
  static bool Supports(const LabelerImpl& model);

  /// `points`: `B x N x 3` float CPU tensor (zero points = missing). Returns
  /// scores, log_assignment, label_confidence and label_ids like the eval-mode
  /// LabelerImpl::forward (no attention weights). Thread-safe.
  LabelerOutput Forward(const at::Tensor& points) const;

  int64_t num_labels() const;
  /// True when A' has the dustbin row (Sinkhorn).
  bool has_dustbin_row() const;
  /// The kernel instruction set in use.
  internal::KernelIsa isa() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace soma
