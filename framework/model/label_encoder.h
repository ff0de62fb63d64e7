// The label branch of the layout-conditioned labeller (model=soma_any_layout;
// issue #25 item 1, docs/any_layout_design.md): label descriptors q_l
// (framework/body/vertex_descriptors.h) -> label embeddings E, and the score
// head that matches point features against them.
//
//   LabelEncoder          q_l (B x L x Q) -> [q_l, Fourier features of its
//                         rest position] -> MLP (Q + 6F -> hidden -> D) -> k_l
//                         masked self-attention layers over the L label
//                         tokens (the MultiHeadAttention layers of the point
//                         backbone, no positional input; optionally a bias of
//                         each attention logit from the two labels' rest
//                         offset) -> E (B x D x L).
//   ConditionedScoreHead  S = exp(log_scale) (F' W_p)(E W_l)^T / sqrt(D)
//                         (B x N x L), F' = ReLU(ResConv1DBlock(D->2D)(ReLU
//                         F)) as in ScoreHead; padded label slots get
//                         kPaddedSlotScore so that Sinkhorn sends their
//                         column mass to the dustbin row only.
//
// Label slots carry a mask (true = the label exists in the frame's layout).
// A padded slot is invisible to the other labels (masked as an attention
// key) and receives no point mass. Order: nothing depends on the order of
// the slots (no positional input), so permuting a layout permutes the score
// columns.
#pragma once

#include "framework/body/body_model.h"
#include "framework/body/marker_layout.h"
#include "framework/io/mocap_dataset.h"
#include "framework/model/layers.h"

#include <torch/nn/module.h>
#include <torch/nn/modules/container/sequential.h>
#include <torch/nn/modules/linear.h>
#include <torch/nn/pimpl.h>

#include <cstdint>
#include <vector>

namespace soma {

/// Score of a padded label slot before Sinkhorn (exp of it is 0 in float).
inline constexpr double kPaddedSlotScore = -1e4;

/// Options of the label branch.
struct LabelEncoderOptions {
  int64_t descriptor_width = 0;  // Q (LabelDescriptorWidth of the body)
  int64_t d_model = 125;         // D, the point features' width
  int64_t hidden = 256;          // the MLP's hidden width
  int64_t num_layers = 2;        // k_l label self-attention layers
  int64_t num_heads = 5;         // heads; must divide d_model
  /// F: the rest position p (descriptor columns 0-2, body frame / height)
  /// also enters the MLP as sin(2^k pi p), cos(2^k pi p), k = 0..F-1 (6F
  /// more inputs; periods from 2 body heights down to 2^(2-F)), so that
  /// labels a few centimetres apart get separable embeddings. 0 = none.
  int64_t fourier_bands = 0;
  /// R: each label self-attention layer adds to the logit of query label i
  /// and key label j, per head, an MLP (4 -> R -> heads, ReLU) of their rest
  /// offset RelativeOffsets(p)_ij, so that a label's embedding can say where
  /// its neighbours sit (the ankle 7 cm below the shin marker) rather than
  /// leave it to dot products of absolute positions. The MLP's last layer
  /// starts at zero (plain attention). 0 = none.
  int64_t relative_bias = 0;
  void Validate() const;  // ConfigError on violation
  /// The MLP's input width: descriptor_width + 6 * fourier_bands.
  int64_t InputWidth() const { return descriptor_width + 6 * fourier_bands; }
};

/// Upper bound of LabelEncoderOptions::fourier_bands (the finest period,
/// 2^-14 body heights, is far below any marker spacing).
inline constexpr int64_t kMaxFourierBands = 16;

/// `descriptors` `... x Q` -> `... x (Q + 6F)`: the descriptors followed by
/// sin(2^k pi p) for the 3 coordinates of p (coordinate-major: x at k =
/// 0..F-1, then y, then z), then cos in the same order; p = columns 0-2.
/// Returns `descriptors` itself when `bands` is 0.
torch::Tensor WithFourierFeatures(const torch::Tensor& descriptors,
                                  int64_t bands);

/// Length unit of RelativeOffsets, in body heights (~8.5 cm on a 1.7 m
/// body): the spacing of neighbouring markers, so that the MLP's inputs are
/// of order 1 between neighbours.
inline constexpr double kRelativeOffsetScale = 0.05;

/// `descriptors` `B x L x Q` -> `B x L x L x 4`: entry (b, i, j) holds
/// (p_j - p_i) / s and |p_j - p_i| / s, p = columns 0-2 (the rest position,
/// body frame / height), s = kRelativeOffsetScale.
torch::Tensor RelativeOffsets(const torch::Tensor& descriptors);

/// The label slots of a batch: `descriptors` `B x L x Q` float (or `1 x L x
/// Q`, shared by every frame), `mask` `B x L` (or `1 x L`) bool, true where
/// the slot holds a label; undefined = every slot holds one.
struct LabelSlots {
  torch::Tensor descriptors;
  torch::Tensor mask;
};

/// The label slots of layout-sampled frames (LabeledFrames::slots, rows of
/// `table`, -1 padded): `B x S x Q` descriptors (padded slots zero) and the
/// `B x S` mask. InternalError when `table` has no rows.
LabelSlots GatherLabelSlots(const LabeledFrames& frames,
                            const SlotTable& table);

/// The label slots of `layout` on `body` (LayoutDescriptors of
/// vertex_descriptors.h at the body's template) as an `L x Q` float tensor,
/// for LabelerImpl::SetLayout. ConfigError when Q differs from
/// `descriptor_width` (the model's: `model.label_encoder.num_joints` is not
/// the body's joint count).
torch::Tensor LayoutSlotDescriptors(const BodyModel& body,
                                    const MarkerLayout& layout,
                                    int64_t descriptor_width);

/// Checks `slots` against `num_labels` slots of width `width` and a batch
/// of `batch` frames (ShapeError naming the tensor otherwise); returns the
/// mask, all true when undefined.
torch::Tensor CheckLabelSlots(const LabelSlots& slots,
                              int64_t num_labels,
                              int64_t width,
                              int64_t batch);

/// The distinct label sets of a batch's slots (CompactLabelSlots). A
/// training batch holds a few layouts many times over (one per placement
/// block, each in its own slot order) padded to L_max slots, and the label
/// encoder gives a labelled slot an embedding that depends only on its own
/// descriptor and the set of the frame's labels (there is no positional
/// input, and padded slots are masked as keys), and every padded slot of a
/// frame the same one (a zero descriptor that sees the frame's labels and
/// itself). So it needs each distinct set once: row u holds one set, its
/// rows in a canonical order (by the bytes of the descriptor row), then,
/// masked, the set's padding token (when a frame with the set has padded
/// slots), then masked filler. `weights` counts the batch's slots each
/// token stands for (0 at the filler), so that the batch norms' statistics
/// over the compact tokens equal those over the batch's B x L
/// (LabelEncoderImpl::forward); `index` maps slot (b, l) to token u * C + c.
/// Encoding the compact slots and gathering by `index` is the encoder of
/// the whole batch, its values, gradients and running statistics, up to the
/// order of float sums.
struct CompactSlots {
  torch::Tensor descriptors;  // U x C x Q, the slots' dtype
  torch::Tensor mask;         // U x C bool
  torch::Tensor weights;      // U x C float
  torch::Tensor index;        // B * L int64, into U * C
};

/// `slots` (checked: CheckLabelSlots' shapes, a batch of B >= 1 frames) ->
/// its distinct label sets. Padded slots' descriptors are ignored.
CompactSlots CompactLabelSlots(const LabelSlots& slots);

/// Multi-head self-attention update of `layer` (MultiHeadAttentionImpl's
/// computation) with keys masked: `x` `B x D x L`, `key_mask` `B x L` bool
/// (false keys get no attention; a token always sees itself, so that a
/// padded token's softmax is defined). `weights` `B x L` (undefined: 1
/// each): in training, the batch norm's statistics weigh token (b, l) by
/// it (CompactSlots). `logit_bias` `B x h x L x L` (undefined: none) is
/// added to the attention logits before the mask (LabelEncoderOptions::
/// relative_bias). Returns the `B x D x L` update.
torch::Tensor MaskedAttentionUpdate(MultiHeadAttentionImpl& layer,
                                    const torch::Tensor& x,
                                    const torch::Tensor& key_mask,
                                    const torch::Tensor& weights = {},
                                    const torch::Tensor& logit_bias = {});

/// Label descriptors -> label embeddings. Children: `mlp.{0,2}` (Linear),
/// `self_attention_layers.{i}` (MultiHeadAttention), and with
/// `relative_bias` > 0 `relative_bias.{i}.{0,2}` (Linear 4 -> R -> heads).
class LabelEncoderImpl : public torch::nn::Module {
 public:
  explicit LabelEncoderImpl(const LabelEncoderOptions& options);
  /// `descriptors` `B x L x Q`, `mask` `B x L` bool -> `B x D x L`.
  /// `weights` `B x L`: the batch norms' token weights (MaskedAttentionUpdate;
  /// undefined: 1 each).
  torch::Tensor forward(const torch::Tensor& descriptors,
                        const torch::Tensor& mask,
                        const torch::Tensor& weights = {});
  /// forward(descriptors, mask) computed once per distinct label set of the
  /// batch (CompactLabelSlots) and gathered back to `B x D x L`: the same
  /// embeddings, gradients and running statistics, at the cost of the
  /// batch's distinct layouts instead of its B x L slots. Descriptors that
  /// require a gradient are encoded whole (forward).
  torch::Tensor EncodeSlots(const torch::Tensor& descriptors,
                            const torch::Tensor& mask);
  const LabelEncoderOptions& options() const { return options_; }

  torch::nn::Linear input{nullptr};   // Q + 6F -> hidden
  torch::nn::Linear output{nullptr};  // hidden -> D
  std::vector<MultiHeadAttention> layers;
  /// Per layer, the MLP of the rest offsets to the heads' logit biases
  /// (empty when `relative_bias` is 0).
  std::vector<torch::nn::Sequential> relative;

 private:
  LabelEncoderOptions options_;
};
TORCH_MODULE(LabelEncoder);

/// One layer in which the point keys attend to the label embeddings of
/// their frame's layout (LabelerOptions::cross_layers): per head, softmax
/// over the frame's present labels of (W_q k_i)^T (W_k e_l) / sqrt(D / h),
/// the values W_v e_l averaged by it, merged by W_o and added to k_i. W_o
/// starts at zero, so that an untrained layer leaves the keys as they are.
/// Children: `query`, `key`, `value`, `merge` (1x1 convolutions D -> D).
class PointLabelAttentionImpl : public torch::nn::Module {
 public:
  PointLabelAttentionImpl(int64_t d_model, int64_t num_heads);
  /// `point_keys` `B x D x N`, `labels` `B x D x L` or `1 x D x L`, `mask`
  /// `B x L` or `1 x L` bool (true = present; at least one per frame) ->
  /// the updated keys `B x D x N`.
  torch::Tensor forward(const torch::Tensor& point_keys,
                        const torch::Tensor& labels,
                        const torch::Tensor& mask);

  torch::nn::Conv1d query{nullptr};
  torch::nn::Conv1d key{nullptr};
  torch::nn::Conv1d value{nullptr};
  torch::nn::Conv1d merge{nullptr};

 private:
  int64_t d_model_;
  int64_t num_heads_;
};
TORCH_MODULE(PointLabelAttention);

/// Point features x label embeddings -> scores. Children: `block`
/// (ResConv1DBlock D->2D), `point_proj` (2D->D), `label_proj` (D->D),
/// `cross{i}` (PointLabelAttention, `cross_layers` of them), parameter
/// `log_scale` (0-dim, initialised to 0).
class ConditionedScoreHeadImpl : public torch::nn::Module {
 public:
  ConditionedScoreHeadImpl(int64_t d_model,
                           int64_t hidden,
                           int64_t cross_layers = 0,
                           int64_t num_heads = 1);
  /// `features` `B x D x N`, `labels` `B x D x L` or `1 x D x L`, `mask`
  /// `B x L` or `1 x L` bool -> scores `B x N x L`:
  /// Scores(PointKeys(features), labels, mask).
  torch::Tensor forward(const torch::Tensor& features,
                        const torch::Tensor& labels,
                        const torch::Tensor& mask);
  /// The point side, F W_p: `B x D x N` -> `B x D x N` (what the fast
  /// training engine computes with its own kernels).
  torch::Tensor PointKeys(const torch::Tensor& features);
  /// The label side and the scaled product: `point_keys` `B x D x N` (from
  /// PointKeys) pass the `cross` layers, then meet the projected labels;
  /// `labels` and `mask` as forward() -> scores `B x N x L`.
  torch::Tensor Scores(const torch::Tensor& point_keys,
                       const torch::Tensor& labels,
                       const torch::Tensor& mask);
  /// True when the scores are the point keys times fixed label keys (no
  /// `cross` layers), which FastLabeler folds into one classifier.
  bool Bilinear() const { return cross.empty(); }

  ResConv1DBlock block{nullptr};
  torch::nn::Conv1d point_proj{nullptr};
  torch::nn::Conv1d label_proj{nullptr};
  std::vector<PointLabelAttention> cross;
  torch::Tensor log_scale;

 private:
  int64_t d_model_;
};
TORCH_MODULE(ConditionedScoreHead);

}  // namespace soma
