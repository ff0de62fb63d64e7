#include "framework/model/layers.h"

#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/model/fast_train.h"
#include "framework/model/register.h"
#include "framework/registry/registry.h"

#include <fmt/format.h>
#include <torch/torch.h>

#include <cmath>
#include <string>

namespace soma {
namespace {

torch::nn::Conv1d PointwiseConv(int64_t in, int64_t out) {
  return torch::nn::Conv1d(torch::nn::Conv1dOptions(in, out, 1).bias(true));
}

void ThrowInvalid(std::string_view path,
                  std::string_view key,
                  int64_t value,
                  std::string_view constraint) {
  throw ConfigError(
      fmt::format("Invalid configuration. {}{}{} = {}. Violated constraint: {}",
                  path,
                  path.empty() ? "" : ".",
                  key,
                  value,
                  constraint));
}

}  // namespace

// ---------------------------------------------------------------------------
// ResConv1DBlock

ResConv1DBlockImpl::ResConv1DBlockImpl(int64_t in_channels,
                                       int64_t out_channels,
                                       int64_t hidden)
    : in_channels_(in_channels), out_channels_(out_channels) {
  SOMA_CHECK(in_channels > 0 && out_channels > 0 && hidden > 0)
      << "ResConv1DBlock(" << in_channels << ", " << out_channels << ", "
      << hidden << ")";
  conv1 = PointwiseConv(in_channels, hidden);
  bn1 = torch::nn::BatchNorm1d(hidden);
  conv2 = PointwiseConv(hidden, out_channels);
  bn2 = torch::nn::BatchNorm1d(out_channels);
  // Sequential indices match the released keys: 0 conv, 1 BN, 2 ReLU, 3 conv,
  // 4 BN.
  register_module(
      "res_conv1d",
      torch::nn::Sequential(conv1, bn1, torch::nn::ReLU(), conv2, bn2));
  if (in_channels != out_channels) {
    shortcut_conv = PointwiseConv(in_channels, out_channels);
    shortcut_bn = torch::nn::BatchNorm1d(out_channels);
    register_module("res_conv1d_short",
                    torch::nn::Sequential(shortcut_conv, shortcut_bn));
  }
}

torch::Tensor ResConv1DBlockImpl::forward(const torch::Tensor& x) {
  torch::Tensor main = bn2(conv2(torch::relu(bn1(conv1(x)))));
  if (shortcut_conv.is_empty()) return main + x;
  return main + shortcut_bn(shortcut_conv(x));
}

// ---------------------------------------------------------------------------
// MultiHeadAttention

MultiHeadAttentionImpl::MultiHeadAttentionImpl(int64_t d_model,
                                               int64_t num_heads)
    : d_model_(d_model), num_heads_(num_heads) {
  SOMA_CHECK(d_model > 0 && num_heads > 0 && d_model % num_heads == 0)
      << "MultiHeadAttention(d_model=" << d_model << ", num_heads=" << num_heads
      << ")";
  query = PointwiseConv(d_model, d_model);
  key = PointwiseConv(d_model, d_model);
  value = PointwiseConv(d_model, d_model);
  torch::nn::ModuleList proj;
  proj->push_back(query);
  proj->push_back(key);
  proj->push_back(value);
  register_module("proj", proj);
  merge = register_module("merge", PointwiseConv(d_model, d_model));
  post_conv1 = PointwiseConv(2 * d_model, 2 * d_model);
  post_bn = torch::nn::BatchNorm1d(2 * d_model);
  post_conv2 = PointwiseConv(2 * d_model, d_model);
  // The only non-default initialisation of the model (REFERENCE 1.6).
  {
    torch::NoGradGuard no_grad;
    post_conv2->bias.zero_();
  }
  register_module("post_merge",
                  torch::nn::Sequential(
                      post_conv1, post_bn, torch::nn::ReLU(), post_conv2));
}

std::pair<torch::Tensor, torch::Tensor> MultiHeadAttentionImpl::forward(
    const torch::Tensor& x) {
  const int64_t batch = x.size(0);
  const int64_t points = x.size(2);
  const int64_t head_dim = d_model_ / num_heads_;
  // B x D x N -> B x dh x h x N: channel c = d * h + head (interleaved).
  auto split = [&](const torch::Tensor& t) {
    return t.view({batch, head_dim, num_heads_, points});
  };
  const torch::Tensor q = split(query(x)).permute({0, 2, 3, 1});  // B h N dh
  const torch::Tensor k = split(key(x)).permute({0, 2, 1, 3});    // B h dh N
  const torch::Tensor v = split(value(x)).permute({0, 2, 3, 1});  // B h N dh
  const torch::Tensor scores =
      torch::matmul(q, k) /
      std::sqrt(static_cast<double>(head_dim));  // B h N N
  torch::Tensor prob = torch::softmax(scores, -1);
  // B h N dh -> B dh h N -> B D N (same interleaving).
  const torch::Tensor out = torch::matmul(prob, v)
                                .permute({0, 3, 1, 2})
                                .reshape({batch, d_model_, points});
  const torch::Tensor merged = merge(out);
  const torch::Tensor update =
      post_conv2(torch::relu(post_bn(post_conv1(torch::cat({merged, x}, 1)))));
  return {update, prob};
}

// ---------------------------------------------------------------------------
// Backbones

void SelfAttentionOptions::Validate() const {
  if (d_model <= 0) ThrowInvalid("", "d_model", d_model, "d_model > 0");
  if (num_layers < 0)
    ThrowInvalid("", "num_layers", num_layers, "num_layers >= 0");
  if (num_heads <= 0) ThrowInvalid("", "num_heads", num_heads, "num_heads > 0");
  if (d_model % num_heads != 0) {
    ThrowInvalid("", "num_heads", num_heads, "d_model % num_heads == 0");
  }
}

SelfAttentionImpl::SelfAttentionImpl(const SelfAttentionOptions& options)
    : options_(options) {
  options_.Validate();
  torch::nn::ModuleList list;
  for (int64_t i = 0; i < options_.num_layers; ++i) {
    layers_.emplace_back(options_.d_model, options_.num_heads);
    list->push_back(layers_.back());
  }
  register_module("self_attention_layers", list);
}

torch::Tensor SelfAttentionImpl::forward(
    const torch::Tensor& x, std::vector<torch::Tensor>* attention) {
  torch::Tensor h = x;
  for (MultiHeadAttention& layer : layers_) {
    auto [update, prob] = layer(h);
    h = h + update;
    if (attention != nullptr) attention->push_back(std::move(prob));
  }
  return h;
}

std::unique_ptr<fast::BackboneOp> BackboneImpl::MakeFastTrainOp(
    std::string* why_not) {
  if (why_not != nullptr) {
    *why_not = fmt::format("the backbone {} has no fast training path", name());
  }
  return nullptr;
}

std::unique_ptr<fast::BackboneOp> SelfAttentionImpl::MakeFastTrainOp(
    std::string* /*why_not*/) {
  return std::make_unique<fast::SelfAttentionOp>(*this);
}

void Conv1dBackboneOptions::Validate() const {
  if (d_model <= 0) ThrowInvalid("", "d_model", d_model, "d_model > 0");
  if (num_layers < 0)
    ThrowInvalid("", "num_layers", num_layers, "num_layers >= 0");
  if (width_multiplier <= 0) {
    ThrowInvalid(
        "", "width_multiplier", width_multiplier, "width_multiplier > 0");
  }
  if (hidden <= 0) ThrowInvalid("", "hidden", hidden, "hidden > 0");
}

Conv1dBackboneImpl::Conv1dBackboneImpl(const Conv1dBackboneOptions& options)
    : options_(options) {
  options_.Validate();
  const int64_t d = options_.d_model;
  const int64_t wide = options_.width_multiplier * d;
  torch::nn::ModuleList list;
  for (int64_t i = 0; i < options_.num_layers; ++i) {
    Block block;
    block.expand = ResConv1DBlock(d, wide, options_.hidden);
    block.reduce = PointwiseConv(wide, d);
    block.bn = torch::nn::BatchNorm1d(d);
    block.out = PointwiseConv(d, d);
    // Indices 0, 2, 3, 5 carry parameters, as in the released checkpoint.
    list->push_back(torch::nn::Sequential(block.expand,
                                          torch::nn::ReLU(),
                                          block.reduce,
                                          block.bn,
                                          torch::nn::ReLU(),
                                          block.out));
    blocks_.push_back(std::move(block));
  }
  register_module("res_conv1d_blocks", list);
}

std::unique_ptr<fast::BackboneOp> Conv1dBackboneImpl::MakeFastTrainOp(
    std::string* /*why_not*/) {
  return std::make_unique<fast::Conv1dBackboneOp>(*this);
}

torch::Tensor Conv1dBackboneImpl::forward(
    const torch::Tensor& x, std::vector<torch::Tensor>* /*attention*/) {
  torch::Tensor h = x;
  for (Block& block : blocks_) {
    const torch::Tensor t = torch::relu(block.expand(h));
    h = h + block.out(torch::relu(block.bn(block.reduce(t))));
  }
  return h;
}

// ---------------------------------------------------------------------------
// Encoder and head

PointEncoderImpl::PointEncoderImpl(int64_t d_model, int64_t hidden) {
  block = register_module("block", ResConv1DBlock(3, d_model, hidden));
}

torch::Tensor PointEncoderImpl::forward(const torch::Tensor& points) {
  return torch::relu(block(points));
}

ScoreHeadImpl::ScoreHeadImpl(int64_t d_model,
                             int64_t hidden,
                             int64_t num_outputs)
    : d_model_(d_model) {
  SOMA_CHECK(num_outputs > 0) << "ScoreHead with " << num_outputs << " outputs";
  block =
      register_module("block", ResConv1DBlock(d_model, 2 * d_model, hidden));
  classifier =
      register_module("classifier", PointwiseConv(2 * d_model, num_outputs));
}

torch::Tensor ScoreHeadImpl::forward(const torch::Tensor& x) {
  // "Score scaling": divide by sqrt(D) before the final conv (REFERENCE 1.3).
  const torch::Tensor h = torch::relu(block(torch::relu(x))) /
                          std::sqrt(static_cast<double>(d_model_));
  return classifier(h).transpose(1, 2);
}

// ---------------------------------------------------------------------------
// Registry

namespace {

class SelfAttentionSpec : public BackboneSpec {
 public:
  explicit SelfAttentionSpec(SelfAttentionOptions options)
      : options_(options) {}
  void CheckCompatible(int64_t d_model, std::string_view path) const override {
    if (d_model % options_.num_heads != 0) {
      ThrowInvalid(path,
                   "num_heads",
                   options_.num_heads,
                   fmt::format("d_model ({}) % num_heads == 0", d_model));
    }
  }
  Backbone Build(int64_t d_model, int64_t /*hidden*/) const override {
    SelfAttentionOptions options = options_;
    options.d_model = d_model;
    return Backbone(
        std::shared_ptr<BackboneImpl>(SelfAttention(options).ptr()));
  }

 private:
  SelfAttentionOptions options_;
};

class Conv1dBackboneSpec : public BackboneSpec {
 public:
  explicit Conv1dBackboneSpec(Conv1dBackboneOptions options)
      : options_(options) {}
  void CheckCompatible(int64_t /*d_model*/,
                       std::string_view /*path*/) const override {}
  Backbone Build(int64_t d_model, int64_t hidden) const override {
    Conv1dBackboneOptions options = options_;
    options.d_model = d_model;
    options.hidden = hidden;
    return Backbone(
        std::shared_ptr<BackboneImpl>(Conv1dBackbone(options).ptr()));
  }

 private:
  Conv1dBackboneOptions options_;
};

}  // namespace

void RegisterBackbones() {
  Registry<BackboneSpec>& registry = GetRegistry<BackboneSpec>();
  registry.Register(
      "self_attention", [](const ConfigNode& node, BuildContext&) {
        ConfigReader reader(node);
        SelfAttentionOptions options;
        reader.Read("num_layers", &options.num_layers);
        reader.Read("num_heads", &options.num_heads);
        reader.Check("num_layers", options.num_layers >= 0, "num_layers >= 0");
        reader.Check("num_heads", options.num_heads > 0, "num_heads > 0");
        reader.Finish();
        return std::make_unique<SelfAttentionSpec>(options);
      });
  registry.Register("conv1d", [](const ConfigNode& node, BuildContext&) {
    ConfigReader reader(node);
    Conv1dBackboneOptions options;
    reader.Read("num_layers", &options.num_layers);
    reader.Read("width_multiplier", &options.width_multiplier);
    reader.Check("num_layers", options.num_layers >= 0, "num_layers >= 0");
    reader.Check("width_multiplier",
                 options.width_multiplier > 0,
                 "width_multiplier > 0");
    reader.Finish();
    return std::make_unique<Conv1dBackboneSpec>(options);
  });
}

}  // namespace soma
