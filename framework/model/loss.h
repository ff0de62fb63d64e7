// The SOMA labelling loss (paper Eq. 6; REFERENCE 2.1-2.3): a weighted
// negative log-likelihood of the augmented ground-truth assignment G' under
// the predicted augmented log assignment A', with per-frame class weights W
// that down-weight the null class by the reciprocal of its frequency.
#pragma once

#include <ATen/core/Tensor.h>

#include <cstdint>
#include <string_view>

namespace soma {

/// G' and W for a batch (REFERENCE 2.1, 2.2), both `B x (N+1) x (L+1)` float.
struct AugmentedTargets {
  /// G': point rows are one-hot over L+1 classes (null = L); the dustbin row
  /// has 1 in every label column whose label is not available in the frame
  /// and `(L+1) - #not_available` in the corner. Every label column sums to
  /// 1 and the total is N + L + 1.
  at::Tensor assignment;
  /// W: 1 on rows of real labels, `1/n_null` on null rows and on the whole
  /// dustbin row (`n_null` = null point rows of the frame; 1 if none).
  at::Tensor weights;
};

/// Builds G' and W from per-point label ids `label_ids` (`B x N` int64 in
/// [0, L], L = null: ghosts and every zero point) for `num_labels` labels.
/// `label_available` (`B x L` bool, optional) is the per-frame availability
/// (label in the sampled layout and not occluded); when given it must agree
/// with the ids (a label is available iff exactly one point carries it).
/// Without it availability is derived from the ids. Throws ShapeError on bad
/// shapes and InternalError on inconsistent labels (a real label on two
/// points, ids out of range, availability disagreeing with the ids).
AugmentedTargets BuildAugmentedTargets(
    const at::Tensor& label_ids,
    int64_t num_labels,
    const at::Tensor& label_available = at::Tensor());

/// Options of the labelling loss.
struct LabelingLossOptions {
  /// Log-softmax ablation only (A' without dustbin row): true reproduces the
  /// released trainer, which feeds *probabilities* exp(A') instead of log
  /// probabilities into the weighted sum over the N point rows (REFERENCE 2.3
  /// quirk; the paper's "Log-Softmax Instead of Sinkhorn" number was trained
  /// this way, hence the default). false gives the proper weighted NLL over
  /// the point rows. Has no effect on the optimal-transport loss.
  bool quirk_probability_loss = true;
};

/// The labelling loss summed over the batch (not averaged):
///   optimal transport (A' is `B x (N+1) x (L+1)`):
///     L = sum_b -sum_ij G'_ij W_ij A'_ij / sum_ij G'_ij        (Eq. 6)
///   log-softmax (A' is `B x N x (L+1)`), over the point rows G, W only:
///     L = sum_b -sum_ij G_ij W_ij f(A'_ij) / sum_ij G_ij
///   with f = exp under `quirk_probability_loss`, identity otherwise.
/// Returns a 0-dim tensor (differentiable w.r.t. `log_assignment`).
at::Tensor ComputeLabelingLoss(const at::Tensor& log_assignment,
                               const AugmentedTargets& targets,
                               const LabelingLossOptions& options = {});

/// A labelling loss selected from the `loss` config group. Registry kind
/// "loss".
class LabelingLoss {
 public:
  static constexpr std::string_view kRegistryName = "loss";
  virtual ~LabelingLoss() = default;
  /// The batch loss (0-dim) of A' (`log_assignment`) against `targets`.
  virtual at::Tensor Compute(const at::Tensor& log_assignment,
                             const AugmentedTargets& targets) const = 0;
  /// True if the hand-written training engine (fast_train.h) computes this
  /// loss, with its options in `*options`; false (the default) otherwise.
  virtual bool FastOptions(LabelingLossOptions* /*options*/) const {
    return false;
  }
};

/// `name: soma`: ComputeLabelingLoss with LabelingLossOptions.
class SomaLabelingLoss : public LabelingLoss {
 public:
  explicit SomaLabelingLoss(const LabelingLossOptions& options = {})
      : options_(options) {}
  at::Tensor Compute(const at::Tensor& log_assignment,
                     const AugmentedTargets& targets) const override;
  bool FastOptions(LabelingLossOptions* options) const override {
    *options = options_;
    return true;
  }
  const LabelingLossOptions& options() const { return options_; }

 private:
  LabelingLossOptions options_;
};

}  // namespace soma
