#include "framework/model/label_encoder.h"

#include "framework/body/vertex_descriptors.h"
#include "framework/core/error.h"
#include "framework/model/torch_utils.h"

#include <fmt/format.h>
#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <numbers>
#include <string>
#include <string_view>
#include <unordered_map>
#include <vector>

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
  if (relative_bias < 0) {
    Invalid("relative_bias", relative_bias, "relative_bias >= 0");
  }
}

torch::Tensor RelativeOffsets(const torch::Tensor& descriptors) {
  SOMA_CHECK(descriptors.dim() == 3 && descriptors.size(2) >= 3)
      << "RelativeOffsets: descriptors must be B x L x Q with Q >= 3, got "
      << descriptors.sizes();
  const torch::Tensor p = descriptors.narrow(2, 0, 3);
  const torch::Tensor offset =
      (p.unsqueeze(1) - p.unsqueeze(2)) / kRelativeOffsetScale;  // B L L 3
  // The norm's gradient at a zero offset (the diagonal) is undefined under
  // autograd (0/0); sqrt(|d|^2 + eps) keeps it finite and differs from the
  // norm by under 1e-6 beyond 1e-3 (about 0.1 mm).
  const torch::Tensor length =
      (offset.square().sum(-1, /*keepdim=*/true) + 1e-12).sqrt();
  return torch::cat({offset, length}, -1);
}

LabelSlots GatherLabelSlots(const LabeledFrames& frames,
                            const SlotTable& table) {
  if (table.num_rows() == 0) {
    throw InternalError(
        "GatherLabelSlots: the frames carry label slots but the slot table "
        "is empty");
  }
  const int64_t b = frames.num_frames();
  const int64_t s = frames.num_slots;
  const int64_t g = table.num_rows();
  const auto width = static_cast<int64_t>(table.width);
  // The table's rows and one zero row for the padded slots.
  const torch::Tensor rows = torch::cat(
      {torch::from_blob(
           const_cast<float*>(table.rows.data()), {g, width}, torch::kFloat),
       torch::zeros({1, width})});
  const torch::Tensor ids =
      torch::from_blob(
          const_cast<int16_t*>(frames.slots.data()), {b, s}, torch::kShort)
          .to(torch::kLong);
  const torch::Tensor padded = ids.lt(0);
  LabelSlots slots;
  slots.descriptors =
      rows.index_select(0, torch::where(padded, g, ids).flatten())
          .view({b, s, width});
  slots.mask = padded.logical_not();
  return slots;
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

CompactSlots CompactLabelSlots(const LabelSlots& slots) {
  const torch::Tensor q =
      slots.descriptors.to(torch::kCPU).contiguous();  // B x L x Q
  const int64_t batch = q.size(0);
  const int64_t num_slots = q.size(1);
  const int64_t width = q.size(2);
  const torch::Tensor m = CheckLabelSlots(slots, num_slots, width, batch)
                              .to(torch::kCPU)
                              .contiguous();
  const char* rows = static_cast<const char*>(q.data_ptr());
  const bool* mask = m.data_ptr<bool>();
  const int64_t mask_stride = m.size(0) == 1 ? 0 : num_slots;
  const size_t row_bytes = q.element_size() * static_cast<size_t>(width);
  auto row = [&](int64_t b, int64_t l) {
    return rows + static_cast<size_t>(b * num_slots + l) * row_bytes;
  };

  // Per frame: its labelled slots in the canonical order (by the bytes of
  // their rows, ties by slot), the set as one key, and its distinct set.
  std::unordered_map<std::string, int64_t> set_of;
  std::vector<int64_t> representative;  // a frame holding set u
  std::vector<int64_t> frames_with;     // frames holding set u
  std::vector<int64_t> padded_with;     // their padded slots together
  std::vector<int64_t> set_size;
  std::vector<int64_t> slot_set(static_cast<size_t>(batch * num_slots), -1);
  std::vector<int64_t> slot_position(slot_set.size(), 0);
  std::vector<int64_t> frame_set(static_cast<size_t>(batch), 0);
  std::vector<int64_t> order;
  std::string key;
  for (int64_t b = 0; b < batch; ++b) {
    order.clear();
    for (int64_t l = 0; l < num_slots; ++l) {
      if (mask[b * mask_stride + l]) order.push_back(l);
    }
    std::sort(order.begin(), order.end(), [&](int64_t i, int64_t j) {
      const int c = std::memcmp(row(b, i), row(b, j), row_bytes);
      return c != 0 ? c < 0 : i < j;
    });
    key.resize(order.size() * row_bytes);
    for (size_t p = 0; p < order.size(); ++p) {
      std::memcpy(key.data() + p * row_bytes, row(b, order[p]), row_bytes);
    }
    const auto [it, inserted] =
        set_of.try_emplace(key, static_cast<int64_t>(representative.size()));
    if (inserted) {
      representative.push_back(b);
      frames_with.push_back(0);
      padded_with.push_back(0);
      set_size.push_back(static_cast<int64_t>(order.size()));
    }
    const int64_t u = it->second;
    const auto su = static_cast<size_t>(u);
    frame_set[static_cast<size_t>(b)] = u;
    ++frames_with[su];
    padded_with[su] += num_slots - set_size[su];
    for (size_t p = 0; p < order.size(); ++p) {
      const size_t slot = static_cast<size_t>(b * num_slots + order[p]);
      slot_set[slot] = u;
      slot_position[slot] = static_cast<int64_t>(p);
    }
  }

  const int64_t sets = static_cast<int64_t>(representative.size());
  int64_t columns = 1;
  for (int64_t u = 0; u < sets; ++u) {
    const auto su = static_cast<size_t>(u);
    columns = std::max(columns, set_size[su] + (padded_with[su] > 0 ? 1 : 0));
  }
  CompactSlots out;
  out.descriptors = torch::zeros({sets, columns, width}, q.options());
  out.mask = torch::zeros({sets, columns}, torch::kBool);
  out.weights = torch::zeros({sets, columns}, torch::kFloat);
  out.index = torch::empty({batch * num_slots}, torch::kLong);
  char* d = static_cast<char*>(out.descriptors.data_ptr());
  bool* dm = out.mask.data_ptr<bool>();
  float* w = out.weights.data_ptr<float>();
  int64_t* index = out.index.data_ptr<int64_t>();
  for (int64_t l = 0; l < batch * num_slots; ++l) {
    const int64_t u = slot_set[static_cast<size_t>(l)];
    if (u < 0) {  // a padded slot: its set's padding token
      const int64_t v = frame_set[static_cast<size_t>(l / num_slots)];
      index[l] = v * columns + set_size[static_cast<size_t>(v)];
      continue;
    }
    const auto su = static_cast<size_t>(u);
    const int64_t c = slot_position[static_cast<size_t>(l)];
    index[l] = u * columns + c;
    if (l / num_slots == representative[su]) {
      std::memcpy(d + static_cast<size_t>(u * columns + c) * row_bytes,
                  rows + static_cast<size_t>(l) * row_bytes,
                  row_bytes);
      dm[u * columns + c] = true;
      w[u * columns + c] = static_cast<float>(frames_with[su]);
    }
  }
  for (int64_t u = 0; u < sets; ++u) {
    const auto su = static_cast<size_t>(u);
    if (padded_with[su] > 0) {
      w[u * columns + set_size[su]] = static_cast<float>(padded_with[su]);
    }
  }
  const torch::Device device = slots.descriptors.device();
  out.descriptors = out.descriptors.to(device);
  out.mask = out.mask.to(device);
  out.weights = out.weights.to(device);
  out.index = out.index.to(device);
  return out;
}

namespace {

/// `bn(x)` for `x` `B x C x L` whose statistics, in training, weigh token
/// (b, l) by `weights[b][l]` (their sum the batch's token count): what
/// BatchNorm1d computes on the batch the weighted tokens stand for, its
/// running statistics included (biased variance to normalise, unbiased to
/// track, as torch's).
torch::Tensor WeightedBatchNorm(torch::nn::BatchNorm1dImpl& bn,
                                const torch::Tensor& x,
                                const torch::Tensor& weights) {
  if (!weights.defined() || !bn.is_training()) return bn.forward(x);
  const torch::nn::BatchNormOptions& options = bn.options;
  const torch::Tensor w = weights.to(x.scalar_type()).unsqueeze(1);  // B 1 L
  const double count = w.sum().item<double>();
  if (count <= 1.0) {
    throw ShapeError(fmt::format(
        "Labeler: a batch norm in training needs more than 1 value per "
        "channel, got {} tokens",
        count));
  }
  const std::vector<int64_t> batch_and_tokens = {0, 2};
  const torch::Tensor mean =
      (x * w).sum(batch_and_tokens, /*keepdim=*/true) / count;
  const torch::Tensor centred = x - mean;
  const torch::Tensor var =
      (centred.square() * w).sum(batch_and_tokens, /*keepdim=*/true) / count;
  torch::Tensor y = centred * torch::rsqrt(var + options.eps());
  if (options.affine()) {
    y = y * bn.weight.view({1, -1, 1}) + bn.bias.view({1, -1, 1});
  }
  if (options.track_running_stats()) {
    torch::NoGradGuard no_grad;
    bn.num_batches_tracked += 1;
    const double momentum = options.momentum().has_value()
                                ? *options.momentum()
                                : 1.0 / bn.num_batches_tracked.item<double>();
    bn.running_mean.mul_(1.0 - momentum).add_(mean.flatten(), momentum);
    bn.running_var.mul_(1.0 - momentum)
        .add_(var.flatten() * (count / (count - 1.0)), momentum);
  }
  return y;
}

}  // namespace

torch::Tensor MaskedAttentionUpdate(MultiHeadAttentionImpl& layer,
                                    const torch::Tensor& x,
                                    const torch::Tensor& key_mask,
                                    const torch::Tensor& weights,
                                    const torch::Tensor& logit_bias) {
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
  if (logit_bias.defined()) scores = scores + logit_bias;
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
  return layer.post_conv2(torch::relu(WeightedBatchNorm(
      *layer.post_bn, layer.post_conv1(torch::cat({merged, x}, 1)), weights)));
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
  if (options_.relative_bias > 0) {
    torch::nn::ModuleList mlps;
    for (int64_t i = 0; i < options_.num_layers; ++i) {
      torch::nn::Linear last(options_.relative_bias, options_.num_heads);
      {
        torch::NoGradGuard no_grad;
        last->weight.zero_();
        last->bias.zero_();
      }
      relative.push_back(
          torch::nn::Sequential(torch::nn::Linear(4, options_.relative_bias),
                                torch::nn::ReLU(),
                                last));
      mlps->push_back(relative.back());
    }
    register_module("relative_bias", mlps);
  }
}

torch::Tensor LabelEncoderImpl::forward(const torch::Tensor& descriptors,
                                        const torch::Tensor& mask,
                                        const torch::Tensor& weights) {
  // Padded slots' descriptors are ignored: zero them so that whatever a
  // caller left there cannot reach the embeddings (through BatchNorm's batch
  // statistics in training).
  const torch::Tensor q =
      descriptors.masked_fill(mask.logical_not().unsqueeze(-1), 0.0);
  torch::Tensor x =
      output(torch::relu(input(WithFourierFeatures(q, options_.fourier_bands))))
          .transpose(1, 2)
          .contiguous();  // B D L
  const torch::Tensor offsets =
      relative.empty() ? torch::Tensor() : RelativeOffsets(q);  // B L L 4
  for (size_t i = 0; i < layers.size(); ++i) {
    const torch::Tensor bias =
        relative.empty()
            ? torch::Tensor()
            : relative[i]->forward(offsets).permute({0, 3, 1, 2});  // B h L L
    x = x + MaskedAttentionUpdate(*layers[i], x, mask, weights, bias);
  }
  return x;
}

torch::Tensor LabelEncoderImpl::EncodeSlots(const torch::Tensor& descriptors,
                                            const torch::Tensor& mask) {
  // A gradient for the descriptors belongs to each frame's own rows: the
  // whole batch then (the compact slots copy a set's rows from one frame).
  if (descriptors.size(0) == 1 || descriptors.requires_grad()) {
    return forward(descriptors, mask);
  }
  const int64_t batch = descriptors.size(0);
  const int64_t num_slots = descriptors.size(1);
  const CompactSlots compact = CompactLabelSlots({descriptors, mask});
  const torch::Tensor tokens =
      forward(compact.descriptors, compact.mask, compact.weights)
          .transpose(1, 2)
          .reshape({-1, options_.d_model});  // U*C x D
  return tokens.index_select(0, compact.index)
      .view({batch, num_slots, options_.d_model})
      .transpose(1, 2)
      .contiguous();  // B x D x L
}

PointLabelAttentionImpl::PointLabelAttentionImpl(int64_t d_model,
                                                 int64_t num_heads)
    : d_model_(d_model), num_heads_(num_heads) {
  SOMA_CHECK(num_heads > 0 && d_model % num_heads == 0)
      << "PointLabelAttention: d_model " << d_model << " is not a multiple of "
      << num_heads << " heads";
  auto conv = [&](const char* name) {
    return register_module(
        name, torch::nn::Conv1d(torch::nn::Conv1dOptions(d_model, d_model, 1)));
  };
  query = conv("query");
  key = conv("key");
  value = conv("value");
  merge = conv("merge");
  torch::NoGradGuard no_grad;
  merge->weight.zero_();
  merge->bias.zero_();
}

torch::Tensor PointLabelAttentionImpl::forward(const torch::Tensor& point_keys,
                                               const torch::Tensor& labels,
                                               const torch::Tensor& mask) {
  const int64_t b = point_keys.size(0);
  const int64_t n = point_keys.size(2);
  const int64_t bl = labels.size(0);
  const int64_t l = labels.size(2);
  const int64_t h = num_heads_;
  const int64_t dh = d_model_ / h;
  const torch::Tensor q = query(point_keys).view({b, h, dh, n});
  const torch::Tensor k = key(labels).view({bl, h, dh, l});
  const torch::Tensor v = value(labels).view({bl, h, dh, l});
  // B x h x N x L (a shared layout's 1 x ... broadcasts over the frames).
  const torch::Tensor logits =
      torch::matmul(q.transpose(2, 3), k) / std::sqrt(static_cast<double>(dh));
  const torch::Tensor weights = torch::softmax(
      logits.masked_fill(mask.logical_not().view({mask.size(0), 1, 1, l}),
                         kPaddedSlotScore),
      -1);
  const torch::Tensor mixed =
      torch::matmul(v, weights.transpose(2, 3)).reshape({b, d_model_, n});
  return point_keys + merge(mixed);
}

ConditionedScoreHeadImpl::ConditionedScoreHeadImpl(int64_t d_model,
                                                   int64_t hidden,
                                                   int64_t cross_layers,
                                                   int64_t num_heads)
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
  for (int64_t i = 0; i < cross_layers; ++i) {
    cross.push_back(register_module(fmt::format("cross{}", i),
                                    PointLabelAttention(d_model, num_heads)));
  }
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
  torch::Tensor points = point_keys;
  for (PointLabelAttention& layer : cross) {
    points = layer(points, labels, mask);
  }
  const torch::Tensor keys = label_proj(labels);  // B' D L
  const torch::Tensor scores =
      torch::matmul(points.transpose(1, 2), keys) *
      (log_scale.exp() / std::sqrt(static_cast<double>(d_model_)));  // B N L
  return scores.masked_fill(mask.logical_not().unsqueeze(1), kPaddedSlotScore);
}

}  // namespace soma
