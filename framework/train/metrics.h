// Labelling metrics of the validation loop (REFERENCE 2.5, 4.1-4.2).
//
// The pairs scored are the (ground truth, prediction) labels of the real
// points of a frame: every non-zero point, i.e. labelled markers and ghosts
// (GT null); zero points (occluded markers, padding) never enter, exactly as
// the exact-coordinate alignment of REFERENCE 4.1 drops them. Predictions are
// the argmax labels after the duplicate rule (REFERENCE 5.4).
//   accuracy = fraction of pairs with pred == gt (micro);
//   f1       = macro F1 over the classes in gt ∪ pred of the pairs (null
//              included; a class predicted but absent from GT scores 0).
#pragma once

#include <cstdint>
#include <vector>

namespace soma {

/// Accuracy and macro F1 of one set of pairs.
struct LabelingScore {
  double accuracy = 0;
  double f1 = 0;
  int64_t num_pairs = 0;
};

/// Scores the pairs (gt[i], pred[i]) for i with valid[i], classes 0..L (null
/// = L). `num_pairs` 0 gives accuracy = f1 = 0.
LabelingScore ScoreLabels(const int64_t* gt,
                          const int64_t* pred,
                          const bool* valid,
                          int64_t n,
                          int num_labels);

/// Accumulates validation batches.
///   batch_*: scores pooled over each batch, averaged over batches (the
///            released trainer's val_acc / val_f1, REFERENCE 2.5);
///   frame_*: scores per frame, averaged over frames with >= 1 pair (the
///            per-frame evaluation of REFERENCE 4.3).
class LabelingMetrics {
 public:
  explicit LabelingMetrics(int num_labels) : num_labels_(num_labels) {}
  /// `B x N` arrays, row-major.
  void AddBatch(const int64_t* gt,
                const int64_t* pred,
                const bool* valid,
                int64_t batch,
                int64_t num_points);
  double batch_accuracy() const;
  double batch_f1() const;
  double frame_accuracy() const;
  double frame_f1() const;

 private:
  int num_labels_;
  std::vector<double> batch_acc_, batch_f1_, frame_acc_, frame_f1_;
};

}  // namespace soma
