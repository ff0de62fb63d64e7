// Self-attention span (SOMA Appendix A): how far, on the body, each layer of
// the labeler looks. Given, per layer, the attention weights between the
// markers averaged over frames (the paper: max over heads, mean over
// frames; rows = the attending marker) and the distances between the same
// markers on a body in a canonical pose, the span of marker i is the
// attention-weighted mean distance
//   span_i = sum_j W_ij D_ij / sum_j W_ij   (metres),
// and a layer's span is the mean over markers, with a 95% confidence
// interval of that mean (1.96 standard errors over markers).
#pragma once

#include <Eigen/Core>

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

}  // namespace soma
