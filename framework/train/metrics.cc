#include "framework/train/metrics.h"

#include <cstddef>
#include <numeric>

namespace soma {
namespace {

double Mean(const std::vector<double>& values) {
  if (values.empty()) return 0;
  return std::accumulate(values.begin(), values.end(), 0.0) /
         static_cast<double>(values.size());
}

}  // namespace

LabelingScore ScoreLabels(const int64_t* gt,
                          const int64_t* pred,
                          const bool* valid,
                          int64_t n,
                          int num_labels) {
  const std::size_t classes = static_cast<std::size_t>(num_labels) + 1;
  std::vector<int64_t> tp(classes, 0), fp(classes, 0), fn(classes, 0);
  std::vector<bool> present(classes, false);
  LabelingScore score;
  int64_t correct = 0;
  for (int64_t i = 0; i < n; ++i) {
    if (!valid[i]) continue;
    const auto g = static_cast<std::size_t>(gt[i]);
    const auto p = static_cast<std::size_t>(pred[i]);
    present[g] = true;
    present[p] = true;
    ++score.num_pairs;
    if (g == p) {
      ++correct;
      ++tp[g];
    } else {
      ++fp[p];
      ++fn[g];
    }
  }
  if (score.num_pairs == 0) return score;
  score.accuracy =
      static_cast<double>(correct) / static_cast<double>(score.num_pairs);
  double f1_sum = 0;
  int num_classes = 0;
  for (std::size_t c = 0; c < classes; ++c) {
    if (!present[c]) continue;
    ++num_classes;
    // F1 = 2 tp / (2 tp + fp + fn); sklearn's zero_division=0 gives 0 when
    // precision + recall = 0, which is tp = 0 here as well.
    const int64_t denominator = 2 * tp[c] + fp[c] + fn[c];
    if (denominator > 0) {
      f1_sum +=
          2.0 * static_cast<double>(tp[c]) / static_cast<double>(denominator);
    }
  }
  score.f1 = f1_sum / num_classes;
  return score;
}

void LabelingMetrics::AddBatch(const int64_t* gt,
                               const int64_t* pred,
                               const bool* valid,
                               int64_t batch,
                               int64_t num_points) {
  const LabelingScore pooled =
      ScoreLabels(gt, pred, valid, batch * num_points, num_labels_);
  if (pooled.num_pairs > 0) {
    batch_acc_.push_back(pooled.accuracy);
    batch_f1_.push_back(pooled.f1);
  }
  for (int64_t b = 0; b < batch; ++b) {
    const int64_t offset = b * num_points;
    const LabelingScore frame = ScoreLabels(
        gt + offset, pred + offset, valid + offset, num_points, num_labels_);
    if (frame.num_pairs == 0) continue;
    frame_acc_.push_back(frame.accuracy);
    frame_f1_.push_back(frame.f1);
  }
}

double LabelingMetrics::batch_accuracy() const { return Mean(batch_acc_); }
double LabelingMetrics::batch_f1() const { return Mean(batch_f1_); }
double LabelingMetrics::frame_accuracy() const { return Mean(frame_acc_); }
double LabelingMetrics::frame_f1() const { return Mean(frame_f1_); }

}  // namespace soma
