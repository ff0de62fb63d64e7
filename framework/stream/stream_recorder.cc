#include "framework/stream/stream_recorder.h"

#include "framework/core/error.h"
#include "framework/io/c3d.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <numeric>

namespace soma {

LabeledC3dRecorder::LabeledC3dRecorder(std::vector<std::string> labels,
                                       double frame_rate,
                                       std::string units)
    : labels_(std::move(labels)),
      frame_rate_(frame_rate),
      units_(std::move(units)) {}

void LabeledC3dRecorder::Append(const StreamFrame& frame,
                                std::span<const int> labels) {
  SOMA_CHECK_EQ(labels.size(), static_cast<size_t>(frame.num_points()));
  if (frames_.empty()) first_number_ = frame.number;
  std::vector<Point>& points = frames_.emplace_back();
  for (int i = 0; i < frame.num_points(); ++i) {
    if (!frame.IsPresent(i)) continue;
    const float* x = &frame.xyz[3 * static_cast<size_t>(i)];
    points.push_back(Point{labels[static_cast<size_t>(i)], x[0], x[1], x[2]});
  }
}

C3dData LabeledC3dRecorder::Build() const {
  const int T = static_cast<int>(frames_.size());
  const int L = static_cast<int>(labels_.size());
  int max_null = 0;
  for (const auto& points : frames_) {
    int n = 0;
    for (const Point& p : points) n += p.label < 0 || p.label >= L;
    max_null = std::max(max_null, n);
  }
  const int K = L + max_null;
  C3dData out;
  out.frame_rate = frame_rate_;
  // C3D frame numbers are 1-based and positive.
  out.first_frame = std::max<int64_t>(first_number_, 1);
  out.num_frames = T;
  out.num_points = K;
  out.units = units_;
  out.labels = labels_;
  for (int k = 0; k < max_null; ++k)
    out.labels.push_back(fmt::format("*{}", k));
  out.num_file_labels = K;
  out.points.setZero(T, 3 * int64_t{K});
  out.residuals.setConstant(T, K, -1.0f);
  out.valid.setConstant(T, K, false);
  for (int t = 0; t < T; ++t) {
    int next_null = L;
    for (const Point& p : frames_[static_cast<size_t>(t)]) {
      const int column = p.label >= 0 && p.label < L ? p.label : next_null++;
      const Eigen::Index x = 3 * Eigen::Index{column};
      out.points(t, x) = p.x;
      out.points(t, x + 1) = p.y;
      out.points(t, x + 2) = p.z;
      out.residuals(t, column) = 0.0f;
      out.valid(t, column) = true;
    }
  }
  return out;
}

void LabeledC3dRecorder::Write(const std::filesystem::path& path) const {
  C3dData out = Build();
  out.source = path.string();
  WriteC3d(path, out);
}

double LatencyStats::Quantile(double q) const {
  if (samples_.empty()) return 0.0;
  std::vector<double> sorted = samples_;
  const size_t rank = static_cast<size_t>(
      std::clamp(std::ceil(q * static_cast<double>(sorted.size())),
                 1.0,
                 static_cast<double>(sorted.size())));
  std::nth_element(sorted.begin(), sorted.begin() + (rank - 1), sorted.end());
  return sorted[rank - 1];
}

double LatencyStats::Max() const {
  return samples_.empty() ? 0.0
                          : *std::max_element(samples_.begin(), samples_.end());
}

double LatencyStats::Mean() const {
  return samples_.empty()
             ? 0.0
             : std::accumulate(samples_.begin(), samples_.end(), 0.0) /
                   static_cast<double>(samples_.size());
}

}  // namespace soma
