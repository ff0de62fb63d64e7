#include "framework/model/inference.h"

#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/core/random.h"
#include "framework/model/fast_labeler.h"
#include "framework/model/labeler.h"
#include "framework/model/torch_utils.h"

#include <fmt/format.h>
#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <span>
#include <string>
#include <utility>
#include <vector>

namespace soma {

void InferenceOptions::Validate() const {
  if (batch_size <= 0) {
    throw ConfigError(
        fmt::format("Invalid configuration. batch_size = {}. Violated "
                    "constraint: batch_size > 0",
                    batch_size));
  }
  if (views < 1) {
    throw ConfigError(fmt::format(
        "Invalid configuration. views = {}. Violated constraint: views >= 1",
        views));
  }
}

InferenceOptions DecodeInferenceOptions(const ConfigNode& node) {
  ConfigReader reader(node);
  InferenceOptions options;
  reader.Read("batch_size", &options.batch_size);
  reader.Read("permute", &options.permute);
  reader.Read("seed", &options.seed);
  reader.Read("use_fast_path", &options.use_fast_path);
  std::string decode(ToString(options.decode));
  reader.Read("decode", &decode);
  reader.Check("decode",
               decode == ToString(LabelDecode::kArgmax) ||
                   decode == ToString(LabelDecode::kMatching),
               "one of argmax, matching");
  options.decode = LabelDecodeFromString(decode);
  reader.Read("views", &options.views);
  reader.Check("batch_size", options.batch_size > 0, "batch_size > 0");
  reader.Check("views", options.views >= 1, "views >= 1");
  reader.Finish();
  return options;
}

at::Tensor ResolveDuplicateLabels(const at::Tensor& label_ids,
                                  const at::Tensor& valid,
                                  int64_t num_labels) {
  if (label_ids.dim() != 2 || !label_ids.sizes().equals(valid.sizes())) {
    throw ShapeError(fmt::format(
        "ResolveDuplicateLabels: label_ids {} and valid {} must be T x P",
        ShapeString(label_ids),
        ShapeString(valid)));
  }
  const torch::Tensor null =
      torch::full_like(label_ids, num_labels, torch::kLong);
  const torch::Tensor ids =
      torch::where(valid.to(torch::kBool), label_ids.to(torch::kLong), null);
  // Per frame: how many valid points claim each label (column L = null).
  const torch::Tensor counts =
      torch::zeros({ids.size(0), num_labels + 1}, torch::kLong)
          .scatter_add_(1, ids, torch::ones_like(ids));
  const torch::Tensor duplicate =
      counts.gather(1, ids).ge(2).logical_and(ids.lt(num_labels));
  return ids.masked_fill(duplicate, num_labels);
}

at::Tensor MatchLabels(const at::Tensor& probabilities,
                       const at::Tensor& valid) {
  if (probabilities.dim() != 3 || valid.dim() != 2 ||
      probabilities.size(0) != valid.size(0) ||
      probabilities.size(1) != valid.size(1) || probabilities.size(2) < 1) {
    throw ShapeError(fmt::format(
        "MatchLabels: probabilities {} must be T x P x (L+1) and valid {} "
        "T x P",
        ShapeString(probabilities),
        ShapeString(valid)));
  }
  const torch::Tensor p = probabilities.to(torch::kFloat).contiguous();
  const torch::Tensor ok = valid.to(torch::kBool).contiguous();
  const int64_t frames = p.size(0), points = p.size(1), width = p.size(2);
  torch::Tensor labels = torch::empty({frames, points}, torch::kLong);
  const float* p_data = p.data_ptr<float>();
  const bool* ok_data = ok.data_ptr<bool>();
  int64_t* out = labels.data_ptr<int64_t>();
  at::parallel_for(0, frames, 1, [&](int64_t t0, int64_t t1) {
    for (int64_t t = t0; t < t1; ++t) {
      MatchFrameLabels(
          std::span<const float>(p_data + t * points * width,
                                 static_cast<size_t>(points * width)),
          std::span<const bool>(ok_data + t * points,
                                static_cast<size_t>(points)),
          width - 1,
          std::span<int64_t>(out + t * points, static_cast<size_t>(points)));
    }
  });
  return labels;
}

at::Tensor RotateAboutVertical(const at::Tensor& points, double angle) {
  if (points.dim() < 1 || points.size(-1) != 3) {
    throw ShapeError(
        fmt::format("RotateAboutVertical: points must be ... x 3, got {}",
                    ShapeString(points)));
  }
  const double c = std::cos(angle), s = std::sin(angle);
  const torch::Tensor x = points.select(-1, 0), y = points.select(-1, 1);
  return torch::stack({x * c - y * s, x * s + y * c, points.select(-1, 2)}, -1);
}

FrameLabeler::FrameLabeler(std::shared_ptr<LabelerImpl> model,
                           const InferenceOptions& options)
    : model_(std::move(model)), options_(options) {
  SOMA_CHECK(model_ != nullptr) << "FrameLabeler needs a model";
  options_.Validate();
  model_->eval();
  if (options_.use_fast_path && FastLabeler::Supports(*model_)) {
    fast_ = std::make_unique<FastLabeler>(*model_);
  }
}

FrameLabeler::~FrameLabeler() = default;
FrameLabeler::FrameLabeler(FrameLabeler&&) noexcept = default;
FrameLabeler& FrameLabeler::operator=(FrameLabeler&&) noexcept = default;

int64_t FrameLabeler::num_labels() const { return model_->num_labels(); }

std::pair<at::Tensor, at::Tensor> FrameLabeler::LabelView(
    const at::Tensor& batch_in,
    int64_t first_frame,
    int view,
    const LabelSlots* slots) const {
  const int64_t b = batch_in.size(0), p = batch_in.size(1);
  const int64_t width = num_labels() + 1;
  torch::Tensor batch =
      view == 0 ? batch_in
                : RotateAboutVertical(
                      batch_in, 2.0 * std::numbers::pi * view / options_.views);
  torch::Tensor order;  // network slot -> input point, per frame
  if (options_.permute && p > 1) {
    const Rng root(options_.seed);
    std::vector<int64_t> indices;
    indices.reserve(static_cast<size_t>(b * p));
    for (int64_t t = 0; t < b; ++t) {
      Rng frame = root.Stream(static_cast<uint64_t>(first_frame + t));
      if (view > 0) frame = frame.Stream(static_cast<uint64_t>(view));
      const std::vector<int> perm = frame.Permutation(static_cast<int>(p));
      indices.insert(indices.end(), perm.begin(), perm.end());
    }
    order = torch::tensor(indices, torch::kLong).view({b, p});
    batch = batch.gather(1, order.unsqueeze(-1).expand({b, p, 3}));
  }
  const LabelerOutput out = slots != nullptr
                                ? model_->ForwardSlots(batch, *slots)
                            : fast_ != nullptr ? fast_->Forward(batch)
                                               : model_->forward(batch);
  if (!order.defined()) return {out.label_confidence, out.label_ids};
  // Invert: output slot i holds input point order[i].
  return {torch::empty_like(out.label_confidence)
              .scatter_(1,
                        order.unsqueeze(-1).expand({b, p, width}),
                        out.label_confidence),
          torch::empty_like(out.label_ids).scatter_(1, order, out.label_ids)};
}

FrameLabels FrameLabeler::Label(const at::Tensor& points_in,
                                int64_t first_frame,
                                const LabelSlots* slots) const {
  if (points_in.dim() != 3 || points_in.size(2) != 3) {
    throw ShapeError(
        fmt::format("FrameLabeler: points must be T x P x 3, got {}",
                    ShapeString(points_in)));
  }
  if (slots != nullptr && (slots->descriptors.dim() != 3 ||
                           slots->descriptors.size(0) != points_in.size(0))) {
    throw ShapeError(fmt::format(
        "FrameLabeler: slots must be T x L x Q for {} frames, got {}",
        points_in.size(0),
        ShapeString(slots->descriptors)));
  }
  c10::InferenceMode inference_mode;
  const torch::Tensor points =
      points_in.to(torch::kCPU, torch::kFloat).contiguous();
  const int64_t frames = points.size(0);
  const int64_t p = points.size(1);
  const int64_t l = num_labels();
  FrameLabels result;
  result.label_confidence = torch::empty({frames, p, l + 1}, torch::kFloat);
  result.predicted_ids = torch::empty({frames, p}, torch::kLong);
  const int views = options_.views;
  for (int64_t t0 = 0; t0 < frames; t0 += options_.batch_size) {
    const int64_t b = std::min<int64_t>(frames - t0, options_.batch_size);
    LabelSlots frame_slots;
    if (slots != nullptr) {
      frame_slots.descriptors = slots->descriptors.narrow(0, t0, b);
      if (slots->mask.defined()) {
        frame_slots.mask = slots->mask.narrow(0, t0, b);
      }
    }
    const LabelSlots* view_slots = slots != nullptr ? &frame_slots : nullptr;
    const torch::Tensor batch = points.narrow(0, t0, b);
    auto [confidence, ids] = LabelView(batch, first_frame + t0, 0, view_slots);
    for (int view = 1; view < views; ++view) {
      confidence += LabelView(batch, first_frame + t0, view, view_slots).first;
    }
    if (views > 1) {
      // The views' mean distribution, and its argmax.
      confidence.div_(views);
      ids = confidence.argmax(-1);
    }
    result.label_confidence.narrow(0, t0, b).copy_(confidence);
    result.predicted_ids.narrow(0, t0, b).copy_(ids);
  }
  const torch::Tensor valid = points.ne(0).any(-1);
  result.label_ids =
      options_.decode == LabelDecode::kMatching
          ? MatchLabels(result.label_confidence, valid)
          : ResolveDuplicateLabels(result.predicted_ids, valid, l);
  return result;
}

}  // namespace soma
