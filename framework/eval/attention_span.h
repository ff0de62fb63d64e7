// Self-attention span (SOMA Appendix A): how far, on the body, each layer of
// the labeler looks. Given, per layer, the attention weights between the
// markers averaged over frames (the paper: max over heads, mean over
// frames; rows = the attending marker) and the distances between the same
// markers on a body in a canonical pose, the span of marker i is the
// attention-weighted mean distance
//   span_i = sum_j W_ij D_ij / sum_j W_ij   (metres),
// and a layer's span is the mean over markers, with a 95% confidence
// interval of that mean (1.96 standard errors over markers).
//
// Also the inputs of `soma attention_span` that need no network: the markers
// in an A-pose (the distances) and the frames of a real take that have every
// label (what the network sees). The attention itself is MeanAttention
// (model/mean_attention.h).
#pragma once

#include "framework/body/body_model.h"
#include "framework/body/marker_layout.h"
#include "framework/io/c3d.h"

#include <Eigen/Core>

#include <cstdint>
#include <string>
#include <vector>

namespace soma {

struct AttentionSpanLayer {
  std::vector<double> per_marker_m;  // span_i, metres
  double mean_m = 0.0;               // mean over markers
  double ci95_m = 0.0;               // half-width of the 95% interval
};

/// One entry per layer of `attention` (each N x N, non-negative, no zero
/// row). `distances` is N x N (metres). Throws ShapeError on size mismatch,
/// negative weights or an all-zero row.
std::vector<AttentionSpanLayer> ComputeAttentionSpan(
    const std::vector<Eigen::MatrixXd>& attention,
    const Eigen::MatrixXd& distances);

/// Pairwise Euclidean distances between the columns of `points` (3 x N).
Eigen::MatrixXd PairwiseDistances(const Eigen::Matrix3Xd& points);

/// Marker positions (3 x L, in the order of `labels`) on `body` at mean
/// shape in an A-pose: the shoulders (`left_shoulder`, `right_shoulder`)
/// rotated `arm_angle_deg` down about the front-back axis (the procedural
/// and MakeHuman rest poses are T-poses with the left arm along +x, z up).
/// ShapeError if the body lacks a shoulder joint, ConfigError if a label is
/// not in `layout`.
Eigen::Matrix3Xd APoseMarkers(const BodyModel& body,
                              const MarkerLayout& layout,
                              const std::vector<std::string>& labels,
                              double arm_angle_deg);

/// The frames of a take in which every one of L labels is present.
struct CompleteFrames {
  std::vector<int> frames;    // F frame indices, ascending
  std::vector<float> points;  // F x L x 3, metres, row-major (label order)
};

/// The frames of `c3d` where the columns of all `labels` (matched by
/// CanonicalMarkerLabel) are valid, finite and not (0, 0, 0); at most
/// `max_frames` of them, drawn without replacement from `seed`'s stream
/// "attention_span/frames" when there are more. IoError (naming `source`)
/// if a label has no column or no frame is complete.
CompleteFrames SelectCompleteFrames(const C3dData& c3d,
                                    const std::vector<std::string>& labels,
                                    const std::string& source,
                                    int max_frames,
                                    uint64_t seed);

}  // namespace soma
