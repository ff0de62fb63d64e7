#include "framework/stream/stream_labeler.h"

#include "framework/core/timer.h"
#include "framework/model/inference.h"
#include "framework/model/labeler.h"

#include <ATen/ATen.h>

namespace soma {
namespace {

InferenceOptions ToInference(const StreamLabelerOptions& options) {
  InferenceOptions inference;
  inference.batch_size = 1;
  inference.permute = options.permute;
  inference.seed = options.seed;
  inference.use_fast_path = options.use_fast_path;
  return inference;
}

}  // namespace

StreamLabeler::StreamLabeler(const std::shared_ptr<LabelerImpl>& model,
                             const StreamLabelerOptions& options)
    : labeler_(std::make_unique<FrameLabeler>(model, ToInference(options))),
      options_(options),
      voter_(static_cast<int>(model->num_labels()), options.tracklet) {}

StreamLabeler::~StreamLabeler() = default;
StreamLabeler::StreamLabeler(StreamLabeler&&) noexcept = default;
StreamLabeler& StreamLabeler::operator=(StreamLabeler&&) noexcept = default;

int StreamLabeler::num_labels() const {
  return static_cast<int>(labeler_->num_labels());
}

bool StreamLabeler::uses_fast_path() const {
  return labeler_->uses_fast_path();
}

StreamLabels StreamLabeler::Label(const StreamFrame& frame,
                                  double metres_per_unit,
                                  int64_t frame_index) {
  const int n = frame.num_points();
  const int null = num_labels();
  std::vector<int> present;
  present.reserve(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) {
    if (frame.IsPresent(i)) present.push_back(i);
  }
  StreamLabels out;
  out.per_frame.assign(static_cast<size_t>(n), null);
  out.labels.assign(static_cast<size_t>(n), null);
  out.confidence.assign(static_cast<size_t>(n), 0.0f);
  const int p = static_cast<int>(present.size());
  std::vector<int32_t> track_ids(static_cast<size_t>(p));
  std::vector<int> predicted(static_cast<size_t>(p), null);
  std::vector<float> confidence;  // P x (L+1)
  if (p > 0) {
    at::Tensor points = at::empty({1, p, 3}, at::kFloat);
    float* a = points.data_ptr<float>();
    for (int j = 0; j < p; ++j) {
      const float* x =
          &frame.xyz[3 * static_cast<size_t>(present[static_cast<size_t>(j)])];
      for (int c = 0; c < 3; ++c) {
        a[3 * j + c] = static_cast<float>(x[c] * metres_per_unit);
      }
      track_ids[static_cast<size_t>(j)] =
          frame.track_ids[static_cast<size_t>(present[static_cast<size_t>(j)])];
    }
    Timer timer;
    const FrameLabels labels = labeler_->Label(points, frame_index);
    out.label_ms = timer.ElapsedSeconds() * 1e3;
    const int64_t* pred = labels.predicted_ids.data_ptr<int64_t>();
    const int64_t* ids = labels.label_ids.data_ptr<int64_t>();
    for (int j = 0; j < p; ++j) {
      predicted[static_cast<size_t>(j)] = static_cast<int>(pred[j]);
      out.per_frame[static_cast<size_t>(present[static_cast<size_t>(j)])] =
          static_cast<int>(ids[j]);
    }
    const at::Tensor probabilities = labels.label_confidence.contiguous();
    confidence.assign(probabilities.data_ptr<float>(),
                      probabilities.data_ptr<float>() + probabilities.numel());
  }
  std::vector<int> final_labels;
  if (options_.tracklets) {
    final_labels = voter_.Update(frame_index, track_ids, predicted);
  } else {
    final_labels.resize(static_cast<size_t>(p));
    for (int j = 0; j < p; ++j) {
      final_labels[static_cast<size_t>(j)] =
          out.per_frame[static_cast<size_t>(present[static_cast<size_t>(j)])];
    }
  }
  for (int j = 0; j < p; ++j) {
    const int i = present[static_cast<size_t>(j)];
    out.labels[static_cast<size_t>(i)] = final_labels[static_cast<size_t>(j)];
    out.confidence[static_cast<size_t>(i)] =
        confidence[static_cast<size_t>(j) * static_cast<size_t>(null + 1) +
                   static_cast<size_t>(final_labels[static_cast<size_t>(j)])];
  }
  return out;
}

}  // namespace soma
