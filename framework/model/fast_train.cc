// The fast training engine's step (fast_train.h): the normalization + loss
// ops (Sinkhorn with dustbins, log-softmax; per frame in double, fast_loss.h),
// FastTrainer (forward, loss and backward of the whole labeler) and the fused
// Adam step. The layers are in fast_layers.cc, the backbones in
// fast_backbones.cc.
#include "framework/model/fast_train.h"

#include "framework/core/error.h"
#include "framework/model/fast_loss.h"
#include "framework/model/fast_parallel.h"
#include "framework/model/fast_train_internal.h"
#include "framework/model/label_encoder.h"
#include "framework/model/labeler.h"
#include "framework/model/layers.h"
#include "framework/model/normalization.h"

#include <ATen/Parallel.h>
#include <fmt/format.h>
#include <torch/optim/adam.h>
#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <utility>

namespace soma {
namespace fast {

// ---------------------------------------------------------------------------
// Normalization + loss

namespace {

/// Per-thread scratch of the per-frame loss loops (grow-only).
struct ThreadScratch {
  internal::FrameLossScratch frame;
  std::vector<float> g;
  std::vector<float> w;
};

class SinkhornLossOp : public NormalizationLossOp {
 public:
  SinkhornLossOp(at::Tensor bin_score, int num_iters)
      : bin_score_(std::move(bin_score)), num_iters_(num_iters) {}

  double ForwardBackward(const Context& ctx,
                         const Mat& scores,
                         const int64_t* label_ids,
                         int64_t num_labels,
                         const LabelMask& mask,
                         Mat& d_scores) override {
    const int64_t n = ctx.points;
    const int64_t l = num_labels;
    const double alpha = bin_score_.item<double>();
    d_scores.Resize(scores.rows, l);
    std::vector<double> loss(static_cast<size_t>(ctx.batch), 0.0);
    std::vector<double> dalpha(static_cast<size_t>(ctx.batch), 0.0);
    scratch_.resize(static_cast<size_t>(internal::FastParallelThreads()));
    internal::FastParallelFor(
        0, ctx.batch, kFrameGrain, [&](int64_t begin, int64_t end) {
          ThreadScratch& own = scratch_[static_cast<size_t>(
              internal::FastParallelThreadIndex())];
          internal::FrameLossScratch& scratch = own.frame;
          std::vector<float>& g = own.g;
          std::vector<float>& w = own.w;
          g.resize(static_cast<size_t>((n + 1) * (l + 1)));
          w.resize(g.size());
          for (int64_t f = begin; f < end; ++f) {
            internal::BuildFrameTargets(
                label_ids + f * n, n, l, true, g.data(), w.data());
            if (mask.data != nullptr) {
              const bool* present = mask.data + f * mask.frame_stride;
              for (int64_t j = 0; j < l; ++j) {
                if (present[j]) continue;
                for (int64_t i = 0; i <= n; ++i) w[i * (l + 1) + j] = 0.0f;
              }
            }
            double da = 0.0;
            loss[static_cast<size_t>(f)] =
                internal::SinkhornLossFrame(scores.row(f * n),
                                            scores.ld,
                                            n,
                                            l,
                                            alpha,
                                            num_iters_,
                                            g.data(),
                                            w.data(),
                                            nullptr,
                                            d_scores.row(f * n),
                                            d_scores.ld,
                                            1.0,
                                            &da,
                                            scratch);
            dalpha[static_cast<size_t>(f)] = da;
          }
        });
    double total = 0.0, total_dalpha = 0.0;
    for (size_t f = 0; f < loss.size(); ++f) {
      total += loss[f];
      total_dalpha += dalpha[f];
    }
    *Grad(bin_score_) = static_cast<float>(total_dalpha);
    return total;
  }

 private:
  at::Tensor bin_score_;
  int num_iters_;
  std::vector<ThreadScratch> scratch_;
};

class LogSoftmaxLossOp : public NormalizationLossOp {
 public:
  explicit LogSoftmaxLossOp(const LabelingLossOptions& options)
      : options_(options) {}

  double ForwardBackward(const Context& ctx,
                         const Mat& scores,
                         const int64_t* label_ids,
                         int64_t num_labels,
                         const LabelMask& mask,
                         Mat& d_scores) override {
    SOMA_CHECK(mask.data == nullptr)
        << "the log-softmax loss has no padded label slots";
    const int64_t n = ctx.points;
    const int64_t l = num_labels;
    d_scores.Resize(scores.rows, l + 1);
    std::vector<double> loss(static_cast<size_t>(ctx.batch), 0.0);
    scratch_.resize(static_cast<size_t>(internal::FastParallelThreads()));
    internal::FastParallelFor(
        0, ctx.batch, kFrameGrain, [&](int64_t begin, int64_t end) {
          ThreadScratch& own = scratch_[static_cast<size_t>(
              internal::FastParallelThreadIndex())];
          internal::FrameLossScratch& scratch = own.frame;
          std::vector<float>& g = own.g;
          std::vector<float>& w = own.w;
          g.resize(static_cast<size_t>((n + 1) * (l + 1)));
          w.resize(g.size());
          for (int64_t f = begin; f < end; ++f) {
            internal::BuildFrameTargets(
                label_ids + f * n, n, l, false, g.data(), w.data());
            loss[static_cast<size_t>(f)] =
                internal::LogSoftmaxLossFrame(scores.row(f * n),
                                              scores.ld,
                                              n,
                                              l,
                                              options_.quirk_probability_loss,
                                              g.data(),
                                              w.data(),
                                              nullptr,
                                              d_scores.row(f * n),
                                              d_scores.ld,
                                              1.0,
                                              scratch);
          }
        });
    double total = 0.0;
    for (double value : loss) total += value;
    return total;
  }

 private:
  LabelingLossOptions options_;
  std::vector<ThreadScratch> scratch_;
};

}  // namespace

std::unique_ptr<NormalizationLossOp> MakeSinkhornLossOp(at::Tensor bin_score,
                                                        int num_iters) {
  return std::make_unique<SinkhornLossOp>(std::move(bin_score), num_iters);
}

std::unique_ptr<NormalizationLossOp> MakeLogSoftmaxLossOp(
    const LabelingLossOptions& loss) {
  return std::make_unique<LogSoftmaxLossOp>(loss);
}

}  // namespace fast

// ---------------------------------------------------------------------------
// FastTrainer

std::unique_ptr<FastTrainer> FastTrainer::Create(
    LabelerImpl& model,
    const LabelingLoss& loss,
    const FastTrainerOptions& options,
    std::string* why_not) {
  std::string reason;
  if (options.bf16 &&
      internal::DefaultBf16Backend() == internal::Bf16Backend::kNone) {
    if (why_not != nullptr) {
      *why_not =
          "bf16 products need AVX512_BF16 or AMX-BF16, which this CPU (or "
          "kernel) does not provide";
    }
    return nullptr;
  }
  std::unique_ptr<fast::BackboneOp> backbone;
  std::unique_ptr<fast::NormalizationLossOp> norm;
  try {
    backbone = model.backbone->MakeFastTrainOp(&reason);
    if (backbone != nullptr) {
      norm = model.normalization->MakeFastLossOp(loss, &reason);
    }
    if (backbone == nullptr || norm == nullptr) {
      if (why_not != nullptr) *why_not = reason;
      return nullptr;
    }
    return std::unique_ptr<FastTrainer>(
        new FastTrainer(model, std::move(backbone), std::move(norm), options));
  } catch (const InternalError& e) {
    if (why_not != nullptr) *why_not = e.what();
    return nullptr;
  }
}

FastTrainer::FastTrainer(LabelerImpl& model,
                         std::unique_ptr<fast::BackboneOp> backbone,
                         std::unique_ptr<fast::NormalizationLossOp> loss,
                         const FastTrainerOptions& options)
    : model_(model), backbone_(std::move(backbone)), loss_(std::move(loss)) {
  ctx_.isa = internal::ResolveIsa(options.isa);
  ctx_.bf16 = options.bf16;
  encoder_ = std::make_unique<fast::ResBlockOp>(*model.encoder->block,
                                                /*relu_out=*/true,
                                                1.0f);
  if (model.conditioned()) {
    // The label side, on torch autograd (LabelSideLoss).
    auto add = [this](const torch::nn::Module& module) {
      for (const at::Tensor& p : module.parameters()) {
        autograd_parameters_.push_back(p);
      }
    };
    add(*model.label_encoder);
    add(*model.label_head->label_proj);
    for (const PointLabelAttention& layer : model.label_head->cross) {
      add(*layer);
    }
    autograd_parameters_.push_back(model.label_head->log_scale);
    if (model.position_head) add(*model.position_head);
    // ConditionedScoreHead::PointKeys: point_proj(ReLU(block(ReLU(F)))).
    head_ = std::make_unique<fast::ResBlockOp>(*model.label_head->block,
                                               /*relu_out=*/true,
                                               1.0f);
    classifier_ =
        std::make_unique<fast::LinearOp>(model.label_head->point_proj.get());
    return;
  }
  const float head_scale = static_cast<float>(
      1.0 / std::sqrt(static_cast<double>(model.options().d_model)));
  head_ = std::make_unique<fast::ResBlockOp>(*model.head->block,
                                             /*relu_out=*/true,
                                             head_scale);
  classifier_ = std::make_unique<fast::LinearOp>(model.head->classifier.get());
}

FastTrainer::~FastTrainer() = default;

double FastTrainer::LabelSideLoss(const at::Tensor& labels,
                                  const LabelSlots* slots) {
  const int64_t* label_ids = labels.data_ptr<int64_t>();
  const int64_t n = ctx_.points;
  const int64_t rows = ctx_.rows();
  const int64_t num_labels = model_.num_labels();
  const LabelSlots layout_slots =
      slots != nullptr ? LabelSlots{} : model_.LayoutSlots();
  const LabelSlots& batch_slots = slots != nullptr ? *slots : layout_slots;
  const at::Tensor mask =
      CheckLabelSlots(
          batch_slots, num_labels, model_.descriptor_width(), ctx_.batch)
          .contiguous();
  torch::AutoGradMode enable_grad(true);
  const int64_t d = keys_.cols;
  at::Tensor keys = torch::empty({ctx_.batch, n, d}, torch::kFloat);
  fast::CopyColumns(keys_.data(), keys_.ld, rows, d, keys.data_ptr<float>(), d);
  keys.requires_grad_(true);
  const at::Tensor scores =
      model_.ConditionedScores(keys.transpose(1, 2), batch_slots)
          .contiguous();  // B x N x L
  scores_.Resize(rows, num_labels);
  fast::CopyColumns(scores.data_ptr<float>(),
                    num_labels,
                    rows,
                    num_labels,
                    scores_.data(),
                    scores_.ld);
  const fast::LabelMask label_mask{mask.data_ptr<bool>(),
                                   mask.size(0) == 1 ? 0 : num_labels};
  const double loss = loss_->ForwardBackward(
      ctx_, scores_, label_ids, num_labels, label_mask, d_scores_);
  // Overwrite the label side's gradients, as the kernels do theirs.
  for (at::Tensor& p : autograd_parameters_) p.mutable_grad() = at::Tensor();
  scores.backward(torch::from_blob(d_scores_.data(),
                                   {ctx_.batch, n, num_labels},
                                   {n * d_scores_.ld, d_scores_.ld, 1},
                                   torch::kFloat));
  double position = 0.0;
  if (model_.options().position_loss > 0.0) {
    const at::Tensor value =
        model_.PositionLoss(keys.transpose(1, 2), batch_slots, labels);
    value.backward();  // adds to keys.grad
    position = value.item<double>();
  }
  d_keys_.Resize(rows, d);
  fast::CopyColumns(keys.grad().contiguous().data_ptr<float>(),
                    d,
                    rows,
                    d,
                    d_keys_.data(),
                    d_keys_.ld);
  return loss + position;
}

double FastTrainer::Step(const at::Tensor& points,
                         const at::Tensor& label_ids,
                         const LabelSlots* slots) {
  SOMA_CHECK(points.dim() == 3 && points.size(2) == 3)
      << "FastTrainer: points must be B x N x 3";
  if (slots != nullptr && !model_.conditioned()) {
    throw InternalError(
        "FastTrainer: label slots given to a labeller with a fixed layout");
  }
  SOMA_CHECK(label_ids.dim() == 2 && label_ids.size(0) == points.size(0) &&
             label_ids.size(1) == points.size(1))
      << "FastTrainer: label ids must be B x N";
  const at::Tensor p = points.to(torch::kFloat).contiguous();
  const at::Tensor ids = label_ids.to(torch::kLong).contiguous();
  ctx_.batch = p.size(0);
  ctx_.points = p.size(1);
  const int64_t n = ctx_.points;
  const int64_t rows = ctx_.rows();
  const int64_t num_labels = model_.num_labels();
  torch::NoGradGuard no_grad;

  // Median centring (no gradient: the points are data).
  points_.Resize(rows, 3);
  const float* src = p.data_ptr<float>();
  internal::FastParallelFor(0, ctx_.batch, 16, [&](int64_t begin, int64_t end) {
    for (int64_t f = begin; f < end; ++f) {
      float offset[3];
      internal::MedianOffset(src + f * n * 3, n, offset);
      for (int64_t i = 0; i < n; ++i) {
        float* dst = points_.row(f * n + i);
        for (int c = 0; c < 3; ++c)
          dst[c] = src[(f * n + i) * 3 + c] - offset[c];
      }
    }
  });

  encoder_->Pack();
  backbone_->Pack();
  head_->Pack();
  classifier_->Pack();

  // With bf16 products, the classifier that makes the scores Sinkhorn reads
  // stays fp32 (as the products over the 3 point coordinates do, LinearOp).
  fast::Context scores_ctx = ctx_;
  scores_ctx.bf16 = false;

  // Forward.
  encoder_->Forward(ctx_, points_, features_);
  backbone_->Forward(ctx_, features_, backbone_out_);
  fast::Relu(backbone_out_, head_in_);
  head_->Forward(ctx_, head_in_, head_out_);
  fast::Mat& head_y = model_.conditioned() ? keys_ : scores_;
  head_y.Resize(rows, classifier_->out_channels());
  classifier_->Forward(scores_ctx,
                       head_out_.data(),
                       head_out_.ld,
                       rows,
                       head_y.data(),
                       head_y.ld);
  const double loss = model_.conditioned()
                          ? LabelSideLoss(ids, slots)
                          : loss_->ForwardBackward(ctx_,
                                                   scores_,
                                                   ids.data_ptr<int64_t>(),
                                                   num_labels,
                                                   fast::LabelMask{},
                                                   d_scores_);

  const fast::Mat& d_head_y = model_.conditioned() ? d_keys_ : d_scores_;
  d_head_out_.Resize(rows, head_out_.cols);
  classifier_->Backward(scores_ctx,
                        head_out_.data(),
                        head_out_.ld,
                        d_head_y.data(),
                        d_head_y.ld,
                        rows,
                        d_head_out_.data(),
                        d_head_out_.ld,
                        false);
  head_->Backward(ctx_, head_in_, head_out_, d_head_out_, &d_head_in_, false);
  fast::ReluBackwardInPlace(backbone_out_, d_head_in_);
  backbone_->Backward(ctx_, d_head_in_, d_features_);
  encoder_->Backward(ctx_, points_, features_, d_features_, nullptr, false);
  return loss;
}

// ---------------------------------------------------------------------------
// Fused Adam

namespace {

/// One parameter's update: its tensors and step constants, at `offset` in
/// the concatenation of all parameters.
struct AdamSegment {
  float* w = nullptr;
  const float* g = nullptr;
  float* m = nullptr;
  float* v = nullptr;
  int64_t count = 0;
  int64_t offset = 0;
  float step_size = 0.0f;
  float inv_bc2_sqrt = 0.0f;
  float b1 = 0.0f;
  float b2 = 0.0f;
  float eps = 0.0f;
  float wd = 0.0f;
};

}  // namespace

bool FusedAdamStep(torch::optim::Optimizer& optimizer) {
  auto* adam = dynamic_cast<torch::optim::Adam*>(&optimizer);
  if (adam == nullptr) return false;
  for (const auto& group : adam->param_groups()) {
    const auto& options =
        static_cast<const torch::optim::AdamOptions&>(group.options());
    if (options.amsgrad()) return false;
  }
  torch::NoGradGuard no_grad;
  std::vector<AdamSegment> segments;
  int64_t total = 0;
  for (auto& group : adam->param_groups()) {
    const auto& options =
        static_cast<const torch::optim::AdamOptions&>(group.options());
    const double lr = options.lr();
    const double beta1 = std::get<0>(options.betas());
    const double beta2 = std::get<1>(options.betas());
    const float eps = static_cast<float>(options.eps());
    const float wd = static_cast<float>(options.weight_decay());
    for (at::Tensor& p : group.params()) {
      if (!p.grad().defined()) continue;
      const std::string key = c10::guts::to_string(p.unsafeGetTensorImpl());
      auto& states = adam->state();
      auto it = states.find(key);
      if (it == states.end()) {
        auto state = std::make_unique<torch::optim::AdamParamState>();
        state->step(0);
        state->exp_avg(torch::zeros_like(p, at::MemoryFormat::Preserve));
        state->exp_avg_sq(torch::zeros_like(p, at::MemoryFormat::Preserve));
        it = states.emplace(key, std::move(state)).first;
      }
      auto& state = static_cast<torch::optim::AdamParamState&>(*it->second);
      state.step(state.step() + 1);
      const double bc1 =
          1.0 - std::pow(beta1, static_cast<double>(state.step()));
      const double bc2 =
          1.0 - std::pow(beta2, static_cast<double>(state.step()));
      const float step_size = static_cast<float>(lr / bc1);
      const float inv_bc2_sqrt = static_cast<float>(1.0 / std::sqrt(bc2));
      const float b1 = static_cast<float>(beta1);
      const float b2 = static_cast<float>(beta2);
      SOMA_CHECK(p.is_contiguous() && p.grad().is_contiguous() &&
                 state.exp_avg().is_contiguous() &&
                 state.exp_avg_sq().is_contiguous() &&
                 p.scalar_type() == torch::kFloat)
          << "FusedAdamStep needs contiguous float tensors";
      AdamSegment segment;
      segment.w = p.data_ptr<float>();
      segment.g = p.grad().data_ptr<float>();
      segment.m = state.exp_avg().data_ptr<float>();
      segment.v = state.exp_avg_sq().data_ptr<float>();
      segment.count = p.numel();
      segment.step_size = step_size;
      segment.inv_bc2_sqrt = inv_bc2_sqrt;
      segment.b1 = b1;
      segment.b2 = b2;
      segment.eps = eps;
      segment.wd = wd;
      segment.offset = total;
      total += segment.count;
      segments.push_back(segment);
    }
  }
  // All parameters in one parallel loop over their concatenated elements.
  internal::FastParallelFor(0, total, 16384, [&](int64_t begin, int64_t end) {
    auto it = std::upper_bound(
        segments.begin(),
        segments.end(),
        begin,
        [](int64_t value, const AdamSegment& s) { return value < s.offset; });
    for (--it; it != segments.end() && it->offset < end; ++it) {
      const AdamSegment& s = *it;
      const int64_t i0 = std::max<int64_t>(begin - s.offset, 0);
      const int64_t i1 = std::min<int64_t>(end - s.offset, s.count);
      for (int64_t i = i0; i < i1; ++i) {
        const float grad = s.g[i] + s.wd * s.w[i];
        s.m[i] = s.m[i] * s.b1 + (1.0f - s.b1) * grad;
        s.v[i] = s.v[i] * s.b2 + (1.0f - s.b2) * grad * grad;
        const float denom = std::sqrt(s.v[i]) * s.inv_bc2_sqrt + s.eps;
        s.w[i] -= s.step_size * s.m[i] / denom;
      }
    }
  });
  return true;
}

}  // namespace soma
