// Torch-free per-frame output normalisation + labelling loss of the labeler,
// forward and backward (REFERENCE 1.4, 1.5, 2): the targets G', W of one
// frame (as BuildAugmentedTargets), Sinkhorn optimal transport with dustbins
// unrolled over T iterations followed by the weighted NLL (as
// LogOptimalTransport + ComputeLabelingLoss), and the log-softmax variant.
// Everything is computed in double precision; the gradients are those of the
// unrolled iteration (what torch autograd gives), not implicit ones.
//
// Conventions: matrices are row-major with an explicit row stride (`ld_*`);
// the loss of a batch is the sum of the per-frame losses, so a caller that
// sums frames passes `grad_scale = 1` (or d loss_total / d loss_frame).
#pragma once

#include "framework/model/fast_kernels.h"

#include <cstdint>
#include <vector>

namespace soma::internal {

// kSinkhornScalingMaxSpan and kSinkhornUnderflowNats (fast_kernels.h) choose
// between SinkhornLossFrame's exp-domain and log-domain forms, as
// SinkhornFrame's.

/// Reusable per-thread scratch of the frame-loss kernels (grow-only: no
/// allocation after the first frame of a given size). Not thread-safe; use
/// one per thread.
struct FrameLossScratch {
  std::vector<double> data;
};

/// Builds G' and W of one frame from its per-point label ids (`label_ids`,
/// n ints in [0, l], l = null: ghosts and zero points) exactly like
/// BuildAugmentedTargets (REFERENCE 2.1, 2.2): point rows one-hot over l+1
/// classes; the dustbin row has 1 in every label column whose label no point
/// carries and `(l+1) - #not_available` in the corner; null point rows and
/// the dustbin row weigh `1/n_null` (1 if n_null == 0), real rows 1. Writes
/// `(n+1) x (l+1)` (row-major, contiguous) to `g` and `w`;
/// `with_dustbin_row = false` writes only the `n x (l+1)` point rows (the
/// log-softmax loss). Throws InternalError if `l < 1`, an id is out of range
/// or a real label is carried by two points.
void BuildFrameTargets(const int64_t* label_ids,
                       int64_t n,
                       int64_t l,
                       bool with_dustbin_row,
                       float* g,
                       float* w);

/// Sinkhorn optimal transport with dustbins (REFERENCE 1.4) and the loss of
/// one frame (REFERENCE 2.3), forward and backward through the `num_iters`
/// unrolled iterations, in double precision.
///
/// `scores` is `n x l` (row stride `ld_scores`), `alpha` the dustbin score;
/// `g`, `w` are the frame's `(n+1) x (l+1)` G' and W (contiguous, e.g. from
/// BuildFrameTargets). Returns
///   loss_f = -sum_ij G'_ij W_ij A'_ij / sum_ij G'_ij.
/// If `log_assignment` != nullptr, writes A' (`(n+1) x (l+1)`, row-major,
/// contiguous). If `d_scores` != nullptr, writes `grad_scale * dloss_f/dS`
/// (`n x l`, row stride `ld_d`) and adds `grad_scale * dloss_f/dalpha` to
/// `*d_alpha` (if `d_alpha` != nullptr). Uses the exp-domain form when the
/// couplings are finite and span at most kSinkhornScalingMaxSpan nats (not
/// counting those kSinkhornUnderflowNats below the largest), else log-sum-exp
/// updates. `isa` selects the kernels (kAuto: AVX-512 when the
/// CPU has it). Requires n >= 1, l >= 1, num_iters >= 0 (InternalError).
double SinkhornLossFrame(const float* scores,
                         int64_t ld_scores,
                         int64_t n,
                         int64_t l,
                         double alpha,
                         int num_iters,
                         const float* g,
                         const float* w,
                         float* log_assignment,
                         float* d_scores,
                         int64_t ld_d,
                         double grad_scale,
                         double* d_alpha,
                         FrameLossScratch& scratch,
                         KernelIsa isa = KernelIsa::kAuto);

/// Row-wise log-softmax normalisation (REFERENCE 1.5) and the loss of one
/// frame over the point rows (REFERENCE 2.3), forward and backward, in double
/// precision. `scores` is `n x (l+1)` (row stride `ld_scores`); `g`, `w` are
/// the frame's point rows of G' and W (`n x (l+1)` contiguous; the rows of a
/// `(n+1) x (l+1)` matrix work too). Returns
///   loss_f = -sum_ij G_ij W_ij f(A'_ij) / sum_ij G_ij,
/// f = exp if `quirk_probability_loss` (LabelingLossOptions), else identity.
/// If `log_assignment` != nullptr, writes A' (`n x (l+1)`, contiguous); if
/// `d_scores` != nullptr, writes `grad_scale * dloss_f/dS` (`n x (l+1)`, row
/// stride `ld_d`). `isa` selects the exp kernel. Requires n >= 1, l >= 1
/// (InternalError).
double LogSoftmaxLossFrame(const float* scores,
                           int64_t ld_scores,
                           int64_t n,
                           int64_t l,
                           bool quirk_probability_loss,
                           const float* g,
                           const float* w,
                           float* log_assignment,
                           float* d_scores,
                           int64_t ld_d,
                           double grad_scale,
                           FrameLossScratch& scratch,
                           KernelIsa isa = KernelIsa::kAuto);

}  // namespace soma::internal
