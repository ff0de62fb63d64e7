// SOMA's labelling metrics (REFERENCE.md section 4), exactly:
//
//  - correspondence: a ground-truth point matches a labelled output point
//    when all three coordinates agree: SOMA tests isclose(|gt - rec|, 0,
//    rtol=1e-3, atol=1e-8), and with 0 as the reference the relative term
//    vanishes, so the test is |gt - rec| <= 1e-8 m per coordinate (outputs
//    copy input coordinates bit for bit); only ground-truth points with exactly
//    one match are kept, so occluded markers (no point) never enter the
//    evaluation while ghosts (ground truth "null") do;
//  - per-pair metrics: micro accuracy, and precision / recall / F1 macro-
//    averaged over the sorted union of the classes present in ground truth
//    and prediction, null included (sklearn classification_report with
//    zero_division=0);
//  - averaging: metrics per frame (over that frame's pairs), then the mean,
//    median and population std (numpy nanmean/nanmedian/nanstd) over all
//    frames of all sequences, plus the pooled metrics over every pair.
//
// Labels are strings; kNullLabel ("nan", as in SOMA's outputs) is the null
// class (ghost points, points the labeller rejected).
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <filesystem>
#include <set>
#include <string>
#include <string_view>
#include <vector>

namespace soma {

inline constexpr std::string_view kNullLabel = "nan";

/// One evaluated point: its ground-truth and its predicted label.
struct LabelPair {
  std::string gt;
  std::string rec;
  bool operator==(const LabelPair&) const = default;
};

/// Tolerance of the exact-coordinate correspondence, metres per coordinate.
struct MatchTolerance {
  double atol = 1e-8;
};

/// REFERENCE 4.1 for one frame. `gt_points`/`rec_points` are 3 x K / 3 x P
/// (metres); a point that is all zeros or has a non-finite coordinate is
/// missing. Returns one pair per ground-truth point with exactly one match,
/// in ground-truth column order. ShapeError if label counts differ from the
/// point counts.
std::vector<LabelPair> MatchFrameLabels(
    const Eigen::Matrix3Xd& gt_points,
    const std::vector<std::string>& gt_labels,
    const Eigen::Matrix3Xd& rec_points,
    const std::vector<std::string>& rec_labels,
    const MatchTolerance& tolerance = {});

/// The ground-truth labels of `pairs` that are not null and not in `known`
/// (the labels a labeller can output), sorted.
std::set<std::string> UnknownGroundTruthLabels(
    const std::vector<LabelPair>& pairs, const std::set<std::string>& known);

/// Scores the ground-truth labels in `labels` as null: a model trained on a
/// subset layout should reject the other markers of a superset capture as
/// ghosts (SOMA Table 4, "Base MoCap"). Returns the pairs changed.
int64_t ScoreLabelsAsNull(const std::set<std::string>& labels,
                          std::vector<LabelPair>* pairs);

/// Precision, recall, F1 and support of one class.
struct ClassReport {
  std::string label;
  double precision = 0.0;
  double recall = 0.0;
  double f1 = 0.0;
  int64_t support = 0;    // ground-truth occurrences
  int64_t predicted = 0;  // predicted occurrences
};

/// Metrics of a set of pairs (REFERENCE 4.2).
struct LabelingMetrics {
  double accuracy = 0.0;   // micro: fraction of pairs with rec == gt
  double precision = 0.0;  // macro over `classes`
  double recall = 0.0;
  double f1 = 0.0;
  int64_t num_pairs = 0;
  std::vector<ClassReport> classes;  // sorted union of gt and rec labels
};

/// Throws ShapeError if `pairs` is empty (the metrics are undefined;
/// SOMA skips frames without matches).
LabelingMetrics ComputeLabelingMetrics(const std::vector<LabelPair>& pairs);

/// Confusion matrix over the sorted union of labels: counts[gt][rec].
struct ConfusionMatrix {
  std::vector<std::string> labels;
  std::vector<std::vector<int64_t>> counts;  // rows = ground truth
};

ConfusionMatrix ComputeConfusionMatrix(const std::vector<LabelPair>& pairs);

/// mean / median / std (population, ddof 0) of per-frame values; NaN when
/// there are no frames.
struct Summary {
  double mean = 0.0;
  double median = 0.0;
  double std = 0.0;
  int64_t count = 0;
};

Summary Summarize(const std::vector<double>& values);

/// Accumulates frames (of one or several sequences) and reports the
/// per-frame summaries and the pooled metrics.
class LabelingEvaluator {
 public:
  /// Adds one frame's pairs; a frame without pairs is skipped (as SOMA does).
  void AddFrame(const std::vector<LabelPair>& pairs);

  int64_t num_frames() const { return static_cast<int64_t>(accuracy_.size()); }
  const std::vector<LabelPair>& pooled_pairs() const { return pooled_; }

  struct Result {
    Summary accuracy, precision, recall, f1;  // over frames
    LabelingMetrics pooled;                   // over all pairs
    int64_t num_frames = 0;
  };
  /// ShapeError if no frame had pairs.
  Result Finish() const;

 private:
  std::vector<double> accuracy_, precision_, recall_, f1_;
  std::vector<LabelPair> pooled_;
};

/// CSV writers (atomic): `label,precision,recall,f1,support,predicted` and a
/// square matrix with a `gt\rec` header row.
void WriteClassReportCsv(const LabelingMetrics& metrics,
                         const std::filesystem::path& path);
void WriteConfusionMatrixCsv(const ConfusionMatrix& matrix,
                             const std::filesystem::path& path);
/// Row-normalised heatmap PNG (white = 0, dark = 1) with label names.
void WriteConfusionMatrixPng(const ConfusionMatrix& matrix,
                             const std::filesystem::path& path);

}  // namespace soma
