// What `soma stream` keeps of a stream: the labelled frames (written as a
// labelled C3D in `soma label`'s layout) and the per-frame latencies.
#pragma once

#include "framework/stream/frame.h"

#include <cstdint>
#include <filesystem>
#include <span>
#include <string>
#include <vector>

namespace soma {

struct C3dData;

/// Accumulates labelled frames and writes them as a labelled C3D: the L
/// label columns in the model's order, then `*<k>` columns for the most null
/// points of any frame (REFERENCE 5.6; the layout of `soma label`), the
/// input coordinates bit for bit. Frames are written in arrival order,
/// densely (gaps in the source's frame numbers are not kept).
class LabeledC3dRecorder {
 public:
  LabeledC3dRecorder(std::vector<std::string> labels,
                     double frame_rate,
                     std::string units);

  /// One frame; `labels[i]` the label of point i (null = L). Absent points
  /// (StreamFrame::IsPresent false) are skipped whatever their label.
  void Append(const StreamFrame& frame, std::span<const int> labels);

  int64_t num_frames() const { return static_cast<int64_t>(frames_.size()); }
  /// The C3D of the frames so far.
  C3dData Build() const;
  /// Build() + an atomic write (temp file + rename): a reader sees a
  /// complete file up to the last appended frame, or the previous one.
  void Write(const std::filesystem::path& path) const;

 private:
  struct Point {
    int label;
    float x, y, z;
  };
  std::vector<std::string> labels_;
  double frame_rate_;
  std::string units_;
  int64_t first_number_ = 1;
  std::vector<std::vector<Point>> frames_;
};

/// Latency samples (milliseconds) and their order statistics.
class LatencyStats {
 public:
  void Add(double ms) { samples_.push_back(ms); }
  int64_t count() const { return static_cast<int64_t>(samples_.size()); }
  /// The q-quantile (0..1, nearest rank); 0 when empty.
  double Quantile(double q) const;
  double Max() const;
  double Mean() const;

 private:
  std::vector<double> samples_;
};

}  // namespace soma
