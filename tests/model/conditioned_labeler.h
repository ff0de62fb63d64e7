// A small layout-conditioned labeller (model=soma_any_layout) for the model
// tests: d_model 12, 2 self-attention layers of 3 heads, a label encoder of 2
// layers, descriptors of a 24-joint body, Sinkhorn with `num_iters`, and the
// position loss weighted by `position_loss`, `cross_layers` point-label
// attention layers, and rest-offset logit biases of hidden width
// `relative_bias` in the label encoder (their last layers drawn at random:
// as built they are zero, which would leave them untested).
#pragma once

#include "framework/model/label_encoder.h"
#include "framework/model/labeler.h"
#include "framework/model/layers.h"
#include "framework/model/normalization.h"

#include <cstdint>

namespace soma::testing {

/// Draws the rest-offset bias MLPs' parameters (LabelEncoderImpl::relative)
/// from N(0, 0.5^2): as built their last layers are zero, which would leave
/// the biases untested.
inline void DrawRelativeBiases(LabelEncoderImpl& encoder) {
  torch::NoGradGuard no_grad;
  for (torch::nn::Sequential& mlp : encoder.relative) {
    for (torch::Tensor& p : mlp->parameters()) p.normal_(0.0, 0.5);
  }
}

/// Q of LabelDescriptorWidth(24) (body/vertex_descriptors.h).
inline constexpr int64_t kConditionedDescriptorWidth = 3 + 3 + 1 + 24 + 4;

inline Labeler SmallConditionedLabeler(int64_t num_labels,
                                       int num_iters = 35,
                                       double position_loss = 0.0,
                                       int64_t cross_layers = 0,
                                       int64_t relative_bias = 0) {
  LabelerOptions options;
  options.position_loss = position_loss;
  options.cross_layers = cross_layers;
  options.num_labels = num_labels;
  options.d_model = 12;
  options.hidden = 16;
  options.conditioned = true;
  options.label_encoder.descriptor_width = kConditionedDescriptorWidth;
  options.label_encoder.d_model = 12;
  options.label_encoder.hidden = 10;
  options.label_encoder.num_layers = 2;
  options.label_encoder.num_heads = 3;
  options.label_encoder.relative_bias = relative_bias;
  SelfAttentionOptions attention;
  attention.d_model = 12;
  attention.num_layers = 2;
  attention.num_heads = 3;
  SinkhornOptions sinkhorn;
  sinkhorn.num_iters = num_iters;
  Labeler model(
      options, SelfAttention(attention).ptr(), Sinkhorn(sinkhorn).ptr());
  DrawRelativeBiases(*model->label_encoder);
  return model;
}

}  // namespace soma::testing
