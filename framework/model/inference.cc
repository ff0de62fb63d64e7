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
  reader.Check("batch_size", options.batch_size > 0, "batch_size > 0");
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
  const Rng root(options_.seed);
  for (int64_t t0 = 0; t0 < frames; t0 += options_.batch_size) {
    const int64_t t1 = std::min<int64_t>(frames, t0 + options_.batch_size);
    torch::Tensor batch = points.narrow(0, t0, t1 - t0);
    torch::Tensor order;  // network slot -> input point, per frame
    if (options_.permute && p > 1) {
      std::vector<int64_t> indices;
      indices.reserve(static_cast<size_t>((t1 - t0) * p));
      for (int64_t t = t0; t < t1; ++t) {
        const std::vector<int> perm =
            root.Stream(static_cast<uint64_t>(first_frame + t))
                .Permutation(static_cast<int>(p));
        indices.insert(indices.end(), perm.begin(), perm.end());
      }
      order = torch::tensor(indices, torch::kLong).view({t1 - t0, p});
      batch = batch.gather(1, order.unsqueeze(-1).expand({t1 - t0, p, 3}));
    }
    LabelerOutput out;
    if (slots != nullptr) {
      LabelSlots frame_slots;
      frame_slots.descriptors = slots->descriptors.narrow(0, t0, t1 - t0);
      if (slots->mask.defined()) {
        frame_slots.mask = slots->mask.narrow(0, t0, t1 - t0);
      }
      out = model_->ForwardSlots(batch, frame_slots);
    } else {
      out = fast_ != nullptr ? fast_->Forward(batch) : model_->forward(batch);
    }
    torch::Tensor confidence = out.label_confidence;
    torch::Tensor ids = out.label_ids;
    if (order.defined()) {
      // Invert: output slot i holds input point order[i].
      confidence =
          torch::empty_like(confidence)
              .scatter_(1,
                        order.unsqueeze(-1).expand({t1 - t0, p, l + 1}),
                        confidence);
      ids = torch::empty_like(ids).scatter_(1, order, ids);
    }
    result.label_confidence.narrow(0, t0, t1 - t0).copy_(confidence);
    result.predicted_ids.narrow(0, t0, t1 - t0).copy_(ids);
  }
  const torch::Tensor valid = points.ne(0).any(-1);
  result.label_ids =
      options_.decode == LabelDecode::kMatching
          ? MatchLabels(result.label_confidence, valid)
          : ResolveDuplicateLabels(result.predicted_ids, valid, l);
  return result;
}

}  // namespace soma
