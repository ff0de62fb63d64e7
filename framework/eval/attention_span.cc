#include "framework/eval/attention_span.h"

#include "framework/core/error.h"

#include <fmt/format.h>

#include <cmath>

namespace soma {

std::vector<AttentionSpanLayer> ComputeAttentionSpan(
    const std::vector<Eigen::MatrixXd>& attention,
    const Eigen::MatrixXd& distances) {
  const Eigen::Index n = distances.rows();
  if (distances.cols() != n || n < 2) {
    throw ShapeError(fmt::format(
        "ComputeAttentionSpan: distances are {} x {}, expected N x N, N >= 2",
        distances.rows(),
        distances.cols()));
  }
  std::vector<AttentionSpanLayer> layers;
  for (size_t k = 0; k < attention.size(); ++k) {
    const Eigen::MatrixXd& w = attention[k];
    if (w.rows() != n || w.cols() != n) {
      throw ShapeError(fmt::format(
          "ComputeAttentionSpan: layer {} attention is {} x {}, distances "
          "{} x {}",
          k,
          w.rows(),
          w.cols(),
          n,
          n));
    }
    if (!w.allFinite() || (w.array() < 0).any()) {
      throw ShapeError(fmt::format(
          "ComputeAttentionSpan: layer {} has negative or non-finite weights",
          k));
    }
    AttentionSpanLayer layer;
    for (Eigen::Index i = 0; i < n; ++i) {
      const double total = w.row(i).sum();
      if (!(total > 0)) {
        throw ShapeError(fmt::format(
            "ComputeAttentionSpan: layer {}, marker {}: all weights are zero",
            k,
            i));
      }
      layer.per_marker_m.push_back(w.row(i).dot(distances.row(i)) / total);
    }
    const Eigen::Map<const Eigen::VectorXd> span(layer.per_marker_m.data(), n);
    layer.mean_m = span.mean();
    const double variance = (span.array() - layer.mean_m).square().sum() /
                            static_cast<double>(n - 1);
    layer.ci95_m = 1.96 * std::sqrt(variance / static_cast<double>(n));
    layers.push_back(std::move(layer));
  }
  return layers;
}

Eigen::MatrixXd PairwiseDistances(const Eigen::Matrix3Xd& points) {
  const Eigen::Index n = points.cols();
  Eigen::MatrixXd d(n, n);
  for (Eigen::Index i = 0; i < n; ++i) {
    d.col(i) = (points.colwise() - points.col(i)).colwise().norm().transpose();
  }
  return d;
}

}  // namespace soma
