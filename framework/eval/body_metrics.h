// Body-fit metrics (issue #8 item 6): how far the body fitted from predicted
// labels is from the body fitted from ground-truth labels. Both fits are
// `soma solve` outputs (solve_output.h) of the same capture; every frame
// both solved is posed on the same body model, each fit with its own betas,
// and compared:
//   V2V        mean over vertices of |v_ref - v_cand| (posed meshes, mm)
//   joint err  mean over joints of |j_ref - j_cand| (mm); joints are the
//              world positions of the posed skeleton (forward kinematics)
//   PCK@tau    percentage of joints with |j_ref - j_cand| < tau (Noise-in
//              Bias-out Eq. 13; PCK1/3/7 = 10/30/70 mm)
// Sequence values are means over the compared frames (PCK is then the
// fraction over all compared joints, as Eq. 13 with a fixed joint count).
// A frame is compared only when both fits solved it (termination converged
// or no-convergence and finite parameters); the others are counted by
// reason.
#pragma once

#include "framework/body/body_model.h"
#include "framework/solve/solve_output.h"

#include <map>
#include <string>
#include <vector>

namespace soma {

struct BodyMetricsOptions {
  /// PCK thresholds, millimetres (strictly positive). Default: Noise-in
  /// Bias-out's PCK1, PCK3, PCK7.
  std::vector<double> pck_thresholds_mm = {10.0, 30.0, 70.0};
  /// Throws ConfigError for an empty list or a threshold <= 0 / non-finite.
  void Validate() const;
};

/// One frame of the comparison.
struct BodyFrameMetrics {
  int frame = 0;  // index in the solve outputs
  /// Empty when compared; otherwise why not, e.g. "reference_skipped",
  /// "candidate_failed", "reference_skipped+candidate_non_finite".
  std::string excluded_reason;
  double v2v_mm = 0.0;        // NaN when excluded
  double joint_err_mm = 0.0;  // NaN when excluded
  double max_joint_err_mm = 0.0;
  std::vector<double> pck;  // percent, one per threshold; NaN when excluded

  bool compared() const { return excluded_reason.empty(); }
};

struct BodyMetrics {
  std::vector<double> pck_thresholds_mm;
  std::vector<BodyFrameMetrics> frames;  // every frame of the outputs
  int frames_total = 0;
  int frames_compared = 0;
  int frames_excluded = 0;
  /// Excluded frames per reason (BodyFrameMetrics::excluded_reason).
  std::map<std::string, int> excluded_by_reason;
  // Means over the compared frames (NaN when none was compared).
  double v2v_mm = 0.0;
  double joint_err_mm = 0.0;
  double max_v2v_mm = 0.0;  // worst frame
  std::vector<double> pck;  // percent, one per threshold

  /// One line: "body fit: 58/60 frames compared (2 excluded:
  /// reference_skipped 2), V2V 12.3 mm, joint error 10.1 mm, PCK@10/30/70 mm
  /// 48.0/95.8/100.0 %".
  std::string BriefReport() const;
};

/// Compares `candidate` (fit from predicted labels) with `reference` (fit
/// from ground-truth labels) on `body` (the body both were fitted with).
/// Throws ShapeError when the fits do not belong together or to the body:
/// a different joint count (or joint names) from the body, different betas
/// sizes or more betas than the body has, a body name other than
/// `body.name`, different frame counts or frame rates, per-frame arrays of
/// the wrong size.
BodyMetrics ComputeBodyMetrics(const BodyModel& body,
                               const SolveOutput& reference,
                               const SolveOutput& candidate,
                               const BodyMetricsOptions& options = {});

/// The metric / CSV column name of a PCK threshold: "pck10" for 10 mm,
/// "pck2.5" for 2.5 mm.
std::string PckMetricName(double threshold_mm);

/// Per-frame CSV: frame,compared,excluded_reason,v2v_mm,joint_err_mm,
/// max_joint_err_mm,pck<tau>... (one column per threshold, e.g. pck10);
/// empty values for excluded frames.
std::string BodyMetricsToCsv(const BodyMetrics& metrics);

}  // namespace soma
