// Confidence a user can trust (issue #25 item 4): temperature scaling of the
// labeler's assignment probabilities, reliability diagrams and expected
// calibration error, the precision/coverage trade-off of a confidence
// threshold, the review list of low-confidence frame ranges, and the
// `calibration.yaml` file that carries a fitted temperature beside a
// checkpoint.
//
// Where the temperature enters. The labeler's point rows of the augmented
// assignment A' (Sinkhorn with dustbins, REFERENCE 1.4) are distributions over
// the L labels and the null column. Temperature scaling divides their log
// values by T and renormalises each row:
//
//     q_i = softmax(log p_i / T)        (over the L + 1 columns of row i)
//
// It acts on the probabilities, after Sinkhorn, not on the scores before it:
// the argmax of every row, hence every label, the duplicate rule and the
// accuracy stay exactly as they were; only the confidences change (Guo et
// al. 2017, "On calibration of modern neural networks", sec. 4.2). Scaling
// the scores before Sinkhorn instead would change the transport plan and
// with it the labels. T > 1 softens over-confident rows, T < 1 sharpens
// under-confident ones. T = 1 only renormalises the rows, and that matters:
// Sinkhorn's fixed number of iterations ends on the column update, so the
// point rows of A' sum to 0.81-1.03 (mean 0.986 on the bundled models'
// synthetic validation frames), not 1; `soma label` always renormalises.
//
// No libtorch here: rows are plain float arrays, row-major.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace soma {

/// Probabilities below this are treated as this value before taking logs
/// (float exp(A') underflows to 0 for very unlikely labels).
inline constexpr double kMinProbability = 1e-30;

/// Replaces each of the `rows` rows of `cols` probabilities at `probs`
/// (row-major) by softmax(log(max(p, kMinProbability)) / temperature).
/// ConfigError unless temperature > 0.
void ApplyTemperature(float* probs,
                      int64_t rows,
                      int64_t cols,
                      double temperature);

/// Options of FitTemperature.
struct TemperatureFitOptions {
  double min_temperature = 0.05;  // search interval of T
  double max_temperature = 20.0;
  double tolerance = 1e-6;  // on 1/T, golden-section search
  void Validate() const;    // ConfigError on violation
};

/// The fitted temperature and the negative log-likelihoods it trades.
struct TemperatureFit {
  double temperature = 1.0;
  double nll_before = 0;  // mean NLL per sample at T = 1
  double nll_after = 0;   // mean NLL per sample at `temperature`
  int64_t samples = 0;
  /// True when the optimum lies on the edge of the search interval.
  bool at_bound = false;
};

/// Mean negative log-likelihood of `targets` under softmax(log_probs / T).
/// `log_probs`: samples x `cols` row-major (log-probabilities, or any logits:
/// the softmax renormalises); `targets[i]` in [0, cols).
double MeanNll(const std::vector<float>& log_probs,
               const std::vector<int>& targets,
               int cols,
               double temperature);

/// The T minimising MeanNll (golden-section search on 1/T, over which the
/// NLL is convex). ShapeError for inconsistent sizes or no samples; a target
/// out of range is a ShapeError naming the sample.
TemperatureFit FitTemperature(const std::vector<float>& log_probs,
                              const std::vector<int>& targets,
                              int cols,
                              const TemperatureFitOptions& options = {});

/// The T whose scaled rows give the least expected calibration error
/// (ComputeReliability's, `num_bins` bins) of the confidence of each
/// sample's `chosen` column (its label, before any threshold) against
/// whether it is the target: a log grid of 5% steps over the options'
/// interval, then 0.25% steps around the best. ECE is not smooth in T, so no
/// bracketing search; it is what a reliability diagram shows, where the NLL
/// weighs the target's probability on wrong labels too. The NLL fields are
/// filled as FitTemperature's. ShapeError as FitTemperature's, or for a
/// `chosen` of another size or out of range.
TemperatureFit FitTemperatureByEce(const std::vector<float>& log_probs,
                                   const std::vector<int>& targets,
                                   const std::vector<int>& chosen,
                                   int cols,
                                   int num_bins,
                                   const TemperatureFitOptions& options = {});

/// One bin of a reliability diagram.
struct ReliabilityBin {
  double lower = 0, upper = 0;  // confidence interval [lower, upper)
  int64_t count = 0;
  double mean_confidence = 0;  // NaN when empty
  double accuracy = 0;         // fraction correct; NaN when empty
};

/// A reliability diagram and its calibration errors.
struct Reliability {
  std::vector<ReliabilityBin> bins;
  int64_t count = 0;
  double accuracy = 0;         // over all samples
  double mean_confidence = 0;  // over all samples
  /// Expected calibration error: sum over bins of count/N * |accuracy -
  /// mean confidence| (Naeini et al. 2015; Guo et al. 2017 eq. 3).
  double ece = 0;
  /// Maximum calibration error: the largest |accuracy - mean confidence| of
  /// a non-empty bin.
  double mce = 0;
};

/// Equal-width bins over [0, 1] (the last bin includes 1). `confidence[i]`
/// is the probability of sample i's prediction, `correct[i]` whether the
/// prediction was right. ShapeError if sizes differ or num_bins < 1.
Reliability ComputeReliability(const std::vector<double>& confidence,
                               const std::vector<bool>& correct,
                               int num_bins = 15);

/// One prediction for the precision/coverage curve.
struct ThresholdedPrediction {
  double confidence = 0;  // probability of the predicted (real) label
  bool correct = false;
};

/// Precision and coverage at one threshold.
struct CoveragePoint {
  double threshold = 0;
  int64_t kept = 0;      // predictions with confidence >= threshold
  int64_t correct = 0;   // of those, correct
  double precision = 1;  // correct / kept (1 when nothing is kept)
  double coverage = 0;   // kept / all predictions
};

/// The curve at each of `thresholds` (kept in the given order). Predictions
/// are the real labels a labelling assigned; a threshold turns those below
/// it into null.
std::vector<CoveragePoint> PrecisionCoverageCurve(
    const std::vector<ThresholdedPrediction>& predictions,
    const std::vector<double>& thresholds);

/// The thresholds the reports use: 0 to 0.9 in steps of 0.05, 0.9 to 0.99
/// in steps of 0.01, 0.991 to 0.999 in steps of 0.001, then 0.9995, 0.9999.
std::vector<double> DefaultThresholds();

/// The largest coverage whose precision is at least `min_precision`, over
/// every threshold (each distinct confidence; ties are kept or dropped
/// together): the point with the lowest such threshold. When no threshold
/// reaches it, coverage 0, kept 0, precision 1 and threshold = +inf.
CoveragePoint CoverageAtPrecision(
    const std::vector<ThresholdedPrediction>& predictions,
    double min_precision);

/// A named reliability diagram (e.g. "before", "after" temperature scaling).
struct NamedReliability {
  std::string name;
  Reliability reliability;
};

/// CSV of the bins of each diagram, one row per bin:
/// `series,bin_lower,bin_upper,count,mean_confidence,accuracy` (empty bins
/// have empty mean_confidence and accuracy).
std::string ReliabilityCsv(const std::vector<NamedReliability>& diagrams);

/// Writes the reliability diagram as a PNG: accuracy against mean confidence
/// per non-empty bin for each diagram (its ECE in the legend), and the
/// diagonal of perfect calibration.
void WriteReliabilityPng(const std::vector<NamedReliability>& diagrams,
                         const std::string& title,
                         const std::filesystem::path& path);

/// CSV of a precision/coverage curve:
/// `threshold,kept,correct,precision,coverage`.
std::string PrecisionCoverageCsv(const std::vector<CoveragePoint>& curve);

/// Writes the precision/coverage curve (precision against coverage, one
/// point per threshold) as a PNG, with the line precision = `target`.
void WritePrecisionCoveragePng(const std::vector<CoveragePoint>& curve,
                               double target,
                               const std::string& title,
                               const std::filesystem::path& path);

/// One row of the review list: a label whose assignments fell below the
/// confidence threshold on consecutive frames (or frames at most `max_gap`
/// apart, LowConfidenceRanges).
struct ReviewRange {
  int label = 0;        // label id
  int first_frame = 0;  // frame indices (0-based, inclusive)
  int last_frame = 0;
  int low_frames = 0;         // frames of the range below the threshold
  double min_confidence = 1;  // lowest probability in the range
  bool operator==(const ReviewRange&) const = default;
};

/// The ranges of frames where a real label (id < `num_labels`) was assigned
/// to a point with confidence below `threshold`: consecutive such frames,
/// and with `max_gap` > 0 also such frames separated by at most `max_gap`
/// frames without one. `labels` and `confidence` are `frames x points`
/// row-major (the label each point was assigned before thresholding, and its
/// probability); null and padding points (id >= num_labels or < 0) are
/// skipped. Sorted by first frame, then label.
std::vector<ReviewRange> LowConfidenceRanges(
    const std::vector<int>& labels,
    const std::vector<float>& confidence,
    int frames,
    int points,
    int num_labels,
    double threshold,
    int max_gap = 0);

/// A fitted temperature stored beside a checkpoint (`calibration.yaml`).
struct TemperatureCalibration {
  double temperature = 1.0;
  /// The checkpoint's file name and the FNV-1a 64 hash of its bytes (16 hex
  /// digits): the temperature belongs to exactly those weights.
  std::string checkpoint;
  std::string checkpoint_fnv1a64;
  std::string fitted_on;  // one line: what data the fit used
  int64_t frames = 0;
  int64_t points = 0;
  double nll_before = 0, nll_after = 0;  // at T = 1 and at `temperature`
  /// ECE of the raw Sinkhorn rows, of the rows renormalised (T = 1) and at
  /// `temperature`.
  double ece_raw = 0, ece_before = 0, ece_after = 0;
  std::string command;  // how it was made
  std::string code_version;
};

/// The file name looked for beside a checkpoint.
inline constexpr const char* kCalibrationFileName = "calibration.yaml";

/// FNV-1a 64 of the file's bytes as 16 hex digits; IoError if unreadable.
std::string FileFingerprint(const std::filesystem::path& path);

/// Writes `calibration` as YAML with comments (atomically).
void WriteCalibration(const std::filesystem::path& path,
                      const TemperatureCalibration& calibration);

/// Reads a calibration file; IoError / ConfigError naming the file.
TemperatureCalibration ReadCalibration(const std::filesystem::path& path);

/// The temperature to apply for a checkpoint, and where it came from.
struct CalibrationChoice {
  double temperature = 1.0;
  std::filesystem::path file;  // empty when none is applied
  std::string reason;          // one line for the log
};

/// Resolves `task.calibration`: "none" = T 1; "auto" = the
/// `calibration.yaml` beside `checkpoint` when it exists and was fitted for
/// this checkpoint's bytes (a file fitted for other weights is ignored with
/// the reason saying so); anything else is a path to a calibration file,
/// which must exist and match the checkpoint (ConfigError naming
/// `task.calibration` otherwise).
CalibrationChoice ResolveCalibration(const std::string& option,
                                     const std::filesystem::path& checkpoint);

}  // namespace soma
