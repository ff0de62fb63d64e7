// The SOMA labeler (paper Fig. 3, Sec. 4.1-4.2, Appendix B; REFERENCE 1):
// median centring -> point encoder -> backbone (stacked self-attention by
// default) -> score head -> normalization (log-domain optimal transport by
// default).
//
// Build one from configs with
//
//   Labeler model = BuildLabeler(cfg.at("model"), cfg.at("normalization"),
//                                layout.num_labels());
//
// The number of labels L comes from the marker layout at build time, never
// from the YAML. At d_model 125, 8 layers, 5 heads and L = 41 the model has
// 1,435,471 trainable parameters (REFERENCE 1.8).
//
// Parameter names: `encoder.block.*`, `backbone.self_attention_layers.{i}.*`
// (or `backbone.res_conv1d_blocks.{i}.*`), `head.block.*`,
// `head.classifier.*`, `normalization.bin_score`. The released checkpoint
// (REFERENCE 1.7) maps by prefix: `score_predictor.score_predictor_b1.1.` ->
// `encoder.block.`, `score_predictor.point_attention.` -> `backbone.`,
// `score_predictor.conv1d_block.` -> `backbone.`,
// `score_predictor.score_predictor_b2.1.` -> `head.block.`,
// `score_predictor.score_predictor_b2.4.` -> `head.classifier.`, `bin_score`
// -> `normalization.bin_score`.
#pragma once

#include "framework/config/node.h"
#include "framework/model/label_encoder.h"
#include "framework/model/labeler_output.h"
#include "framework/model/layers.h"
#include "framework/model/normalization.h"

#include <torch/nn/module.h>
#include <torch/nn/modules/conv.h>
#include <torch/nn/pimpl.h>

#include <cstdint>
#include <memory>
#include <string_view>

namespace soma {

class BuildContext;

/// Architecture options of the labeler shared by every backbone.
struct LabelerOptions {
  int64_t num_labels = 0;  // L, from the marker layout (null id = L)
  int64_t d_model = 125;   // feature width D
  int64_t hidden = 256;    // hidden width of the encoder/head ResConv1DBlocks
  /// model=soma_any_layout: the labels are an input (label_encoder.h); L is
  /// then the number of label slots.
  bool conditioned = false;
  LabelEncoderOptions label_encoder;  // conditioned only
  /// Conditioned only: the weight of the auxiliary position loss
  /// (LabelerImpl::PositionLoss); 0 = none, and no `position_head`.
  double position_loss = 0.0;
  /// Conditioned only: layers in which the point keys attend to the label
  /// embeddings before the scores (PointLabelAttention); 0 = none.
  int64_t cross_layers = 0;
  void Validate() const;  // ConfigError on violation
};

/// Per-frame median centring (REFERENCE 1.1): for every frame, the offset is
/// the per-coordinate *lower* median over the non-zero points (a point is
/// zero when all three coordinates are exactly 0), or (0,0,0) when the frame
/// has no non-zero point. The offset is subtracted from all N points,
/// including zero points. `points`: `B x N x 3` -> `B x N x 3`.
at::Tensor MedianCenter(const at::Tensor& points);
/// The offsets themselves, `B x 3`.
at::Tensor MedianOffsets(const at::Tensor& points);

/// The composed labeler. Children: `encoder`, `backbone`, `head`,
/// `normalization`. A conditioned labeler (LabelerOptions::conditioned,
/// model=soma_any_layout) has `label_encoder` and `label_head` in place of
/// `head`, and the buffer `layout_descriptors` (`L x Q`): the label slots of
/// the layout it labels when forward() gets no slots (set by SetLayout; saved
/// in checkpoints, so that a checkpoint labels its training layout as is).
class LabelerImpl : public torch::nn::Module {
 public:
  /// `backbone->d_model()` must equal `options.d_model`; the head gets
  /// `normalization->NumScoreColumns(L)` outputs.
  LabelerImpl(const LabelerOptions& options,
              std::shared_ptr<BackboneImpl> backbone,
              std::shared_ptr<NormalizationImpl> normalization);

  /// `points`: `B x N x 3` float (zero points = missing). Returns scores,
  /// A', label confidences and label ids (LabelerOutput); the attention
  /// weights (`B x k x h x N x N`) only when `return_attention` is true and
  /// the backbone has attention.
  /// A conditioned labeler labels against layout_descriptors (ConfigError if
  /// SetLayout was never called and none was loaded).
  LabelerOutput forward(const torch::Tensor& points,
                        bool return_attention = false);
  /// A conditioned labeler's forward with the given label slots (label ids
  /// index the slots; id L is null). ConfigError for a plain labeler (its
  /// layout is fixed). Not an overload of forward(): torch's ModuleHolder
  /// call operator needs forward() to be unique.
  LabelerOutput ForwardSlots(const torch::Tensor& points,
                             const LabelSlots& slots,
                             bool return_attention = false);

  const LabelerOptions& options() const { return options_; }
  int64_t num_labels() const { return options_.num_labels; }
  /// True for a layout-conditioned labeler (the fast inference engine does
  /// not support it: it needs `head`).
  bool conditioned() const { return options_.conditioned; }
  /// Q of a conditioned labeler's descriptors (0 otherwise).
  int64_t descriptor_width() const {
    return options_.conditioned ? options_.label_encoder.descriptor_width : 0;
  }
  /// Sets the layout of a conditioned labeler: `descriptors` `K x Q` float
  /// (LayoutDescriptors of vertex_descriptors.h), K <= L: the layout's
  /// labels fill the first K slots, the rest are zeroed and forward() masks
  /// them as padded. ShapeError on another shape, ConfigError for a plain
  /// labeler.
  void SetLayout(const torch::Tensor& descriptors);
  /// The label slots of the layout set by SetLayout (or loaded): `1 x L x
  /// Q` descriptors, the mask undefined when every slot holds a label.
  /// ConfigError when there is none.
  LabelSlots LayoutSlots() const;
  /// True when a layout is held (SetLayout or loaded): some slot's
  /// descriptor row is not all zero. Always false for a fixed-head model.
  bool HoldsLayout() const;
  /// A conditioned labeler's scores `B x N x L` from the point side
  /// (`label_head->PointKeys(features)`, `B x D x N`) and `slots`: checks the
  /// slots, embeds the labels (label_encoder) and matches them
  /// (ConditionedScoreHead::Scores). What forward() computes after the
  /// backbone; the fast training engine calls it on its own point keys.
  torch::Tensor ConditionedScores(const torch::Tensor& point_keys,
                                  const LabelSlots& slots);
  /// The auxiliary position loss of a conditioned labeller whose
  /// `position_loss` weight w is positive: the point keys (`B x D x N`, as
  /// ConditionedScores takes them) regress the rest position of their
  /// point's label (descriptor columns 0-2, body frame in body heights)
  /// through `position_head`, a linear map D -> 3:
  ///   w * sum_f (1 / n_f) sum_{i labelled} || P k_fi + c - p(l_fi) ||^2,
  /// n_f the frame's labelled points (ids < L of `labels`, `B x N` int64;
  /// frames without any add nothing), summed over frames as the labelling
  /// loss is. Dense supervision of where on the body a point is, which a
  /// per-layout model's classifier gets from its fixed labels and the
  /// conditioned one must learn as a continuous map. A scalar tensor; an
  /// undefined one when the weight is 0. Used by both training engines;
  /// validation and labelling do not compute it.
  torch::Tensor PositionLoss(const torch::Tensor& point_keys,
                             const LabelSlots& slots,
                             const torch::Tensor& labels);

  PointEncoder encoder{nullptr};
  Backbone backbone{nullptr};
  ScoreHead head{nullptr};  // null when conditioned
  Normalization normalization{nullptr};
  LabelEncoder label_encoder{nullptr};       // conditioned only
  ConditionedScoreHead label_head{nullptr};  // conditioned only
  torch::nn::Conv1d position_head{nullptr};  // position_loss > 0 only
  torch::Tensor layout_descriptors;          // conditioned only, L x Q

 private:
  LabelerOutput Run(const torch::Tensor& points,
                    const LabelSlots* slots,
                    bool return_attention);

  LabelerOptions options_;
};
TORCH_MODULE(Labeler);

/// A labeler architecture decoded from the `model` config group; the label
/// count and the normalization are supplied when it is built. Registry kind
/// "model" (configs/model/).
class ModelSpec {
 public:
  static constexpr std::string_view kRegistryName = "model";
  virtual ~ModelSpec() = default;
  /// A freshly initialised labeler for `num_labels` labels.
  virtual Labeler Build(int64_t num_labels,
                        Normalization normalization) const = 0;
  /// True when the labels are an input of the model (soma_any_layout).
  virtual bool conditioned() const { return false; }
};

/// Builds the labeler selected by `model` (a `model` group node, `name:
/// soma`) with the normalization selected by `normalization` (`name:
/// sinkhorn` or `log_softmax`) for `num_labels` labels. ConfigError on
/// invalid options. Parameters are initialised from torch's global RNG (seed
/// it with torch::manual_seed for reproducibility).
Labeler BuildLabeler(const ConfigNode& model,
                     const ConfigNode& normalization,
                     int64_t num_labels);
Labeler BuildLabeler(const ConfigNode& model,
                     const ConfigNode& normalization,
                     int64_t num_labels,
                     BuildContext& ctx);

/// Number of trainable parameter elements (requires_grad) of `module`.
int64_t CountTrainableParameters(const torch::nn::Module& module);

}  // namespace soma
