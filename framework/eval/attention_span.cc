#include "framework/eval/attention_span.h"

#include "framework/core/error.h"
#include "framework/core/random.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <utility>

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

Eigen::Matrix3Xd APoseMarkers(const BodyModel& body,
                              const MarkerLayout& layout,
                              const std::vector<std::string>& labels,
                              double arm_angle_deg) {
  BodyPose pose = BodyPose::Rest(body.num_joints());
  const double angle = arm_angle_deg * std::numbers::pi / 180.0;
  for (const auto& [joint, sign] :
       {std::pair<const char*, double>{"left_shoulder", 1.0},
        {"right_shoulder", -1.0}}) {
    const int j = body.FindJoint(joint);
    if (j < 0) {
      throw ShapeError(fmt::format(
          "attention_span: body '{}' has no joint '{}' to lower the arms "
          "(set task.arm_angle_deg=0 for the rest pose)",
          body.name,
          joint));
    }
    pose.rotations.col(j) = Eigen::Vector3d(0, sign * angle, 0);
  }
  const Eigen::Matrix3Xd vertices =
      PoseVertices(body, Eigen::VectorXd::Zero(body.num_betas()), pose);
  const Eigen::Matrix3Xd all =
      MarkerPositions(layout, vertices, VertexNormals(vertices, body.faces));
  Eigen::Matrix3Xd markers(3, labels.size());
  for (size_t l = 0; l < labels.size(); ++l) {
    const int m = layout.FindLabel(labels[l]);
    if (m < 0) {
      throw ConfigError(fmt::format(
          "attention_span: the model's label '{}' is not in the layout "
          "(choose the layout the model was trained with, e.g. "
          "layout=superset89)",
          labels[l]));
    }
    markers.col(l) = all.col(m);
  }
  return markers;
}

CompleteFrames SelectCompleteFrames(const C3dData& c3d,
                                    const std::vector<std::string>& labels,
                                    const std::string& source,
                                    int max_frames,
                                    uint64_t seed) {
  std::vector<int> column(labels.size(), -1);
  for (int k = 0; k < c3d.num_points; ++k) {
    const std::string label = CanonicalMarkerLabel(c3d.labels[k]);
    for (size_t l = 0; l < labels.size(); ++l) {
      if (labels[l] == label) column[l] = k;
    }
  }
  for (size_t l = 0; l < labels.size(); ++l) {
    if (column[l] < 0) {
      throw IoError(fmt::format(
          "{}: no column labelled '{}' (the model's labels must all be in "
          "the take)",
          source,
          labels[l]));
    }
  }
  std::vector<int> frames;
  for (int t = 0; t < c3d.num_frames; ++t) {
    bool complete = true;
    for (int k : column) {
      const Eigen::Vector3f p = c3d.Point(t, k);
      complete = complete && c3d.valid(t, k) && p.allFinite() &&
                 !(p.array() == 0.0f).all();
    }
    if (complete) frames.push_back(t);
  }
  if (frames.empty()) {
    throw IoError(
        fmt::format("{}: no frame has all {} labels", source, labels.size()));
  }
  if (static_cast<int>(frames.size()) > max_frames) {
    Rng rng = Rng(seed).Stream("attention_span/frames");
    std::vector<int> picked;
    for (int i : rng.SampleWithoutReplacement(static_cast<int>(frames.size()),
                                              max_frames)) {
      picked.push_back(frames[i]);
    }
    std::sort(picked.begin(), picked.end());
    frames = std::move(picked);
  }
  const double to_metres = c3d.MetresPerUnit();
  CompleteFrames complete;
  complete.points.resize(frames.size() * labels.size() * 3);
  float* a = complete.points.data();
  for (size_t f = 0; f < frames.size(); ++f) {
    for (size_t l = 0; l < labels.size(); ++l) {
      const Eigen::Vector3f p = c3d.Point(frames[f], column[l]);
      for (int i = 0; i < 3; ++i) {
        *a++ = static_cast<float>(p[i] * to_metres);
      }
    }
  }
  complete.frames = std::move(frames);
  return complete;
}

}  // namespace soma
