#include "framework/model/label_encoder.h"

#include "framework/body/vertex_descriptors.h"
#include "framework/core/error.h"
#include "framework/model/torch_utils.h"

#include <fmt/format.h>
#include <torch/torch.h>

#include <cmath>
#include <limits>
#include <numbers>
#include <string>
#include <string_view>

namespace soma {

namespace {

[[noreturn]] void Invalid(std::string_view key,
                          int64_t value,
                          std::string_view constraint) {
  throw ConfigError(
      fmt::format("Invalid configuration. model.label_encoder.{} = {}. "
                  "Violated constraint: {}",
                  key,
                  value,
                  constraint));
}

}  // namespace

void LabelEncoderOptions::Validate() const {
  if (descriptor_width <= 0) {
    Invalid("descriptor_width", descriptor_width, "descriptor_width > 0");
  }
  if (d_model <= 0) Invalid("d_model", d_model, "d_model > 0");
  if (hidden <= 0) Invalid("hidden", hidden, "hidden > 0");
  if (num_layers < 0) Invalid("num_layers", num_layers, "num_layers >= 0");
  if (num_heads <= 0) Invalid("num_heads", num_heads, "num_heads > 0");
  if (d_model % num_heads != 0) {
    Invalid("num_heads",
            num_heads,
            fmt::format("d_model ({}) % num_heads == 0", d_model));
  }
  if (fourier_bands < 0 || fourier_bands > kMaxFourierBands) {
    Invalid("fourier_bands",
            fourier_bands,
            fmt::format("0 <= fourier_bands <= {}", kMaxFourierBands));
  }
}

torch::Tensor WithFourierFeatures(const torch::Tensor& descriptors,
                                  int64_t bands) {
  if (bands == 0) return descriptors;
  const torch::Tensor frequencies =
      torch::pow(2.0, torch::arange(bands, descriptors.options())) *
      std::numbers::pi;  // F
  const torch::Tensor angles =
      (descriptors.narrow(-1, 0, 3).unsqueeze(-1) * frequencies)
          .flatten(-2);  // ... x 3F
  return torch::cat({descriptors, angles.sin(), angles.cos()}, -1);
}

torch::Tensor LayoutSlotDescriptors(const BodyModel& body,
                                    const MarkerLayout& layout,
                                    int64_t descriptor_width) {
  if (LabelDescriptorWidth(body.num_joints()) != descriptor_width) {
    throw ConfigError(fmt::format(
        "Invalid configuration. model.label_encoder.num_joints = {}. "
        "Violated constraint: the body's joint count ({}, body '{}')",
        descriptor_width - LabelDescriptorWidth(0),
        body.num_joints(),
        body.name));
  }
  Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> q =
      LayoutDescriptors(ComputeVertexDescriptors(body), layout);
  return torch::from_blob(q.data(), {q.rows(), q.cols()}, torch::kFloat)
      .clone();
}

torch::Tensor CheckLabelSlots(const LabelSlots& slots,
                              int64_t num_labels,
                              int64_t width,
                              int64_t batch) {
  const torch::Tensor& q = slots.descriptors;
  if (!q.defined() || q.dim() != 3 || q.size(1) != num_labels ||
      q.size(2) != width || (q.size(0) != batch && q.size(0) != 1)) {
    throw ShapeError(fmt::format(
        "Labeler: label slot descriptors must be {} x {} x {} (or 1 x {} x "
        "{}), got {}",
        batch,
        num_labels,
        width,
        num_labels,
        width,
        q.defined() ? ShapeString(q) : std::string("undefined")));
  }
  if (!slots.mask.defined()) {
    return torch::ones({q.size(0), num_labels},
                       torch::TensorOptions().dtype(torch::kBool));
  }
  const torch::Tensor& m = slots.mask;
  if (m.dim() != 2 || m.size(0) != q.size(0) || m.size(1) != num_labels ||
      m.scalar_type() != torch::kBool) {
    throw ShapeError(
        fmt::format("Labeler: label slot mask must be bool {} x {}, got {}",
                    q.size(0),
                    num_labels,
                    ShapeString(m)));
  }
  return m;
}

torch::Tensor MaskedAttentionUpdate(MultiHeadAttentionImpl& layer,
                                    const torch::Tensor& x,
                                    const torch::Tensor& key_mask) {
  const int64_t batch = x.size(0);
  const int64_t d_model = layer.d_model();
  const int64_t heads = layer.num_heads();
  const int64_t tokens = x.size(2);
  const int64_t head_dim = d_model / heads;
  auto split = [&](const torch::Tensor& t) {
    return t.view({batch, head_dim, heads, tokens});
  };
  const torch::Tensor q = split(layer.query(x)).permute({0, 2, 3, 1});
  const torch::Tensor k = split(layer.key(x)).permute({0, 2, 1, 3});
  const torch::Tensor v = split(layer.value(x)).permute({0, 2, 3, 1});
  torch::Tensor scores = torch::matmul(q, k) /
                         std::sqrt(static_cast<double>(head_dim));  // B h L L
  // Query i sees key j when j is a label, or j == i.
  const torch::Tensor eye = torch::eye(
      tokens, torch::TensorOptions().dtype(torch::kBool).device(x.device()));
  const torch::Tensor visible =
      key_mask.unsqueeze(1).logical_or(eye.unsqueeze(0));  // B x L x L
  scores = scores.masked_fill(visible.logical_not().unsqueeze(1),
                              -std::numeric_limits<float>::infinity());
  const torch::Tensor prob = torch::softmax(scores, -1);
  const torch::Tensor out = torch::matmul(prob, v)
                                .permute({0, 3, 1, 2})
                                .reshape({batch, d_model, tokens});
  const torch::Tensor merged = layer.merge(out);
  return layer.post_conv2(
      torch::relu(layer.post_bn(layer.post_conv1(torch::cat({merged, x}, 1)))));
}

LabelEncoderImpl::LabelEncoderImpl(const LabelEncoderOptions& options)
    : options_(options) {
  options_.Validate();
  torch::nn::Sequential mlp;
  input = torch::nn::Linear(options_.InputWidth(), options_.hidden);
  output = torch::nn::Linear(options_.hidden, options_.d_model);
  mlp->push_back(input);
  mlp->push_back(torch::nn::ReLU());
  mlp->push_back(output);
  register_module("mlp", mlp);
  torch::nn::ModuleList list;
  for (int64_t i = 0; i < options_.num_layers; ++i) {
    layers.push_back(MultiHeadAttention(options_.d_model, options_.num_heads));
    list->push_back(layers.back());
  }
  register_module("self_attention_layers", list);
}

torch::Tensor LabelEncoderImpl::forward(const torch::Tensor& descriptors,
                                        const torch::Tensor& mask) {
  // Padded slots' descriptors are ignored: zero them so that whatever a
  // caller left there cannot reach the embeddings (through BatchNorm's batch
  // statistics in training).
  const torch::Tensor q =
      descriptors.masked_fill(mask.logical_not().unsqueeze(-1), 0.0);
  torch::Tensor x =
      output(torch::relu(input(WithFourierFeatures(q, options_.fourier_bands))))
          .transpose(1, 2)
          .contiguous();  // B D L
  for (MultiHeadAttention& layer : layers) {
    x = x + MaskedAttentionUpdate(*layer, x, mask);
  }
  return x;
}

ConditionedScoreHeadImpl::ConditionedScoreHeadImpl(int64_t d_model,
                                                   int64_t hidden)
    : d_model_(d_model) {
  block =
      register_module("block", ResConv1DBlock(d_model, 2 * d_model, hidden));
  point_proj = register_module(
      "point_proj",
      torch::nn::Conv1d(torch::nn::Conv1dOptions(2 * d_model, d_model, 1)));
  label_proj = register_module(
      "label_proj",
      torch::nn::Conv1d(torch::nn::Conv1dOptions(d_model, d_model, 1)));
  log_scale = register_parameter("log_scale", torch::zeros({}));
}

torch::Tensor ConditionedScoreHeadImpl::forward(const torch::Tensor& features,
                                                const torch::Tensor& labels,
                                                const torch::Tensor& mask) {
  return Scores(PointKeys(features), labels, mask);
}

torch::Tensor ConditionedScoreHeadImpl::PointKeys(
    const torch::Tensor& features) {
  return point_proj(torch::relu(block(torch::relu(features))));  // B D N
}

torch::Tensor ConditionedScoreHeadImpl::Scores(const torch::Tensor& point_keys,
                                               const torch::Tensor& labels,
                                               const torch::Tensor& mask) {
  const torch::Tensor keys = label_proj(labels);  // B' D L
  const torch::Tensor scores =
      torch::matmul(point_keys.transpose(1, 2), keys) *
      (log_scale.exp() / std::sqrt(static_cast<double>(d_model_)));  // B N L
  return scores.masked_fill(mask.logical_not().unsqueeze(1), kPaddedSlotScore);
}

}  // namespace soma
