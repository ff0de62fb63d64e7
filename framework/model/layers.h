// Building blocks of the SOMA score predictor (REFERENCE 1.2, 1.3; paper
// Sec. 4.1, Appendix A/B): the residual per-point conv block, SuperGlue-style
// multi-head self-attention, the two backbones (stacked self-attention and the
// no-transformer ablation) and the score head.
//
// Every convolution is a `Conv1d(kernel_size=1)`, i.e. a shared per-point
// linear layer acting on `B x C x N` tensors. Child module names follow the
// released checkpoint's sub-keys (`res_conv1d.{0,1,3,4}`, `proj.{0,1,2}`,
// `merge`, `post_merge.{0,1,3}`, `res_conv1d_blocks.{i}.{0,2,3,5}`), so
// released weights load through a pure prefix mapping (see labeler.h).
#pragma once

#include <torch/nn/module.h>
#include <torch/nn/modules/batchnorm.h>
#include <torch/nn/modules/container/modulelist.h>
#include <torch/nn/modules/container/sequential.h>
#include <torch/nn/modules/conv.h>
#include <torch/nn/pimpl.h>

#include <cstdint>
#include <memory>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace soma {

namespace fast {
class BackboneOp;
}  // namespace fast

/// ResConv1DBlock(Cin, Cout, hidden) (REFERENCE 1.2):
///   main     = conv(Cin->hidden) -> BN -> ReLU -> conv(hidden->Cout) -> BN
///   shortcut = conv(Cin->Cout) -> BN   if Cin != Cout, identity otherwise
///   output   = main + shortcut (no activation after the sum).
class ResConv1DBlockImpl : public torch::nn::Module {
 public:
  ResConv1DBlockImpl(int64_t in_channels,
                     int64_t out_channels,
                     int64_t hidden = 256);

  /// `x`: `B x Cin x N` -> `B x Cout x N`.
  torch::Tensor forward(const torch::Tensor& x);

  int64_t in_channels() const { return in_channels_; }
  int64_t out_channels() const { return out_channels_; }
  bool has_shortcut_conv() const { return !shortcut_conv.is_empty(); }

  // Layers, exposed for weight folding (fast_labeler.h). Registered as
  // `res_conv1d.{0,1,3,4}` and `res_conv1d_short.{0,1}`.
  torch::nn::Conv1d conv1{nullptr};
  torch::nn::BatchNorm1d bn1{nullptr};
  torch::nn::Conv1d conv2{nullptr};
  torch::nn::BatchNorm1d bn2{nullptr};
  torch::nn::Conv1d shortcut_conv{nullptr};  // null when Cin == Cout
  torch::nn::BatchNorm1d shortcut_bn{nullptr};

 private:
  int64_t in_channels_;
  int64_t out_channels_;
};
TORCH_MODULE(ResConv1DBlock);

/// SuperGlue-style multi-head self-attention with SOMA's post-merge MLP
/// (REFERENCE 1.2; paper Eq. 9 with the per-head scale 1/sqrt(d_model/h)).
///
/// q, k, v = conv(D->D)(x); heads use the interleaved channel layout
/// `channel = d * h + head` (`d < D/h`); scores are divided by sqrt(D/h);
/// softmax over keys with no masking; `merged = merge(out)`; the output is
/// `post_merge(cat[merged, x])` with post_merge = conv(2D->2D) -> BN -> ReLU
/// -> conv(2D->D) (last bias initialised to 0). The residual `x + MHA(x)` is
/// applied by the backbone, not here.
class MultiHeadAttentionImpl : public torch::nn::Module {
 public:
  MultiHeadAttentionImpl(int64_t d_model, int64_t num_heads);

  /// `x`: `B x D x N` -> (`B x D x N` update, attention `B x h x N x N`).
  std::pair<torch::Tensor, torch::Tensor> forward(const torch::Tensor& x);

  int64_t d_model() const { return d_model_; }
  int64_t num_heads() const { return num_heads_; }

  // Registered as `proj.{0,1,2}`, `merge`, `post_merge.{0,1,3}`.
  torch::nn::Conv1d query{nullptr};
  torch::nn::Conv1d key{nullptr};
  torch::nn::Conv1d value{nullptr};
  torch::nn::Conv1d merge{nullptr};
  torch::nn::Conv1d post_conv1{nullptr};
  torch::nn::BatchNorm1d post_bn{nullptr};
  torch::nn::Conv1d post_conv2{nullptr};

 private:
  int64_t d_model_;
  int64_t num_heads_;
};
TORCH_MODULE(MultiHeadAttention);

/// The middle of the score predictor: `B x D x N` features -> `B x D x N`.
class BackboneImpl : public torch::nn::Module {
 public:
  /// `x`: `B x D x N`. If `attention` is non-null and the backbone has
  /// attention layers, their weights are appended (one `B x h x N x N` tensor
  /// per layer).
  virtual torch::Tensor forward(const torch::Tensor& x,
                                std::vector<torch::Tensor>* attention) = 0;
  virtual int64_t d_model() const = 0;
  /// This backbone's path in the hand-written training engine
  /// (fast_train.h), operating on this module's parameters; nullptr with
  /// the reason in `*why_not` when it has none (the default: a new backbone
  /// trains on the torch engine until it provides one).
  virtual std::unique_ptr<fast::BackboneOp> MakeFastTrainOp(
      std::string* why_not);
};
TORCH_MODULE(Backbone);

/// Options of the stacked self-attention backbone (LayeredSelfAttention).
struct SelfAttentionOptions {
  int64_t d_model = 125;   // feature width D
  int64_t num_layers = 8;  // k (paper Appendix B/C)
  int64_t num_heads = 5;   // h; must divide d_model
  void Validate() const;   // ConfigError on violation
};

/// k layers of `x <- x + MHA(x)` (REFERENCE 1.2 LayeredSelfAttention).
/// Children: `self_attention_layers.{i}`.
class SelfAttentionImpl : public BackboneImpl {
 public:
  explicit SelfAttentionImpl(const SelfAttentionOptions& options);
  torch::Tensor forward(const torch::Tensor& x,
                        std::vector<torch::Tensor>* attention) override;
  int64_t d_model() const override { return options_.d_model; }
  std::unique_ptr<fast::BackboneOp> MakeFastTrainOp(
      std::string* why_not) override;
  const SelfAttentionOptions& options() const { return options_; }
  const std::vector<MultiHeadAttention>& layers() const { return layers_; }

 private:
  SelfAttentionOptions options_;
  std::vector<MultiHeadAttention> layers_;
};
TORCH_MODULE(SelfAttention);

/// Options of the no-transformer ablation backbone (LayeredResConv1d).
struct Conv1dBackboneOptions {
  int64_t d_model = 125;         // D
  int64_t num_layers = 8;        // residual blocks
  int64_t width_multiplier = 3;  // inner width = width_multiplier * D
  int64_t hidden = 256;          // hidden width of the ResConv1DBlock
  void Validate() const;
};

/// The no-transformer ablation (REFERENCE 1.2 LayeredResConv1d): each block
/// is `x <- x + [ResConv1DBlock(D->3D) -> ReLU -> conv(3D->D) -> BN -> ReLU ->
/// conv(D->D)](x)`; 240,893 parameters per block at D = 125. Children:
/// `res_conv1d_blocks.{i}.{0,2,3,5}`.
class Conv1dBackboneImpl : public BackboneImpl {
 public:
  explicit Conv1dBackboneImpl(const Conv1dBackboneOptions& options);
  torch::Tensor forward(const torch::Tensor& x,
                        std::vector<torch::Tensor>* attention) override;
  int64_t d_model() const override { return options_.d_model; }
  std::unique_ptr<fast::BackboneOp> MakeFastTrainOp(
      std::string* why_not) override;
  const Conv1dBackboneOptions& options() const { return options_; }

  /// One residual block's layers (registered inside a Sequential).
  struct Block {
    ResConv1DBlock expand{nullptr};  // D -> width_multiplier * D
    torch::nn::Conv1d reduce{nullptr};
    torch::nn::BatchNorm1d bn{nullptr};
    torch::nn::Conv1d out{nullptr};
  };
  const std::vector<Block>& blocks() const { return blocks_; }

 private:
  Conv1dBackboneOptions options_;
  std::vector<Block> blocks_;
};
TORCH_MODULE(Conv1dBackbone);

/// A backbone architecture decoded from a config node (`model.backbone`),
/// built once the feature width is known. Registry kind "backbone".
class BackboneSpec {
 public:
  static constexpr std::string_view kRegistryName = "backbone";
  virtual ~BackboneSpec() = default;
  /// Throws ConfigError (naming `path`) if the backbone cannot work with
  /// `d_model` (e.g. heads not dividing it).
  virtual void CheckCompatible(int64_t d_model,
                               std::string_view path) const = 0;
  /// A freshly initialised backbone of width `d_model` whose residual conv
  /// blocks (if any) use `hidden` hidden channels.
  virtual Backbone Build(int64_t d_model, int64_t hidden) const = 0;
};

/// The point encoder (REFERENCE 1.3 step 2): ResConv1DBlock(3->D) -> ReLU.
/// Child: `block`.
class PointEncoderImpl : public torch::nn::Module {
 public:
  PointEncoderImpl(int64_t d_model, int64_t hidden);
  /// `points`: `B x 3 x N` (centred) -> `B x D x N`.
  torch::Tensor forward(const torch::Tensor& points);
  ResConv1DBlock block{nullptr};
};
TORCH_MODULE(PointEncoder);

/// The score head (REFERENCE 1.3 step 4): ReLU -> ResConv1DBlock(D->2D) ->
/// ReLU -> divide by sqrt(D) -> conv(2D->C). Children: `block`, `classifier`.
class ScoreHeadImpl : public torch::nn::Module {
 public:
  ScoreHeadImpl(int64_t d_model, int64_t hidden, int64_t num_outputs);
  /// `x`: `B x D x N` -> scores `B x N x C`.
  torch::Tensor forward(const torch::Tensor& x);
  int64_t d_model() const { return d_model_; }
  ResConv1DBlock block{nullptr};
  torch::nn::Conv1d classifier{nullptr};

 private:
  int64_t d_model_;
};
TORCH_MODULE(ScoreHead);

}  // namespace soma
