// Labels one stream frame at a time: the labeler's per-frame labels (the
// fast forward at batch 1) and, optionally, the online tracklet vote
// (online_tracklets.h). No libtorch in this header.
#pragma once

#include "framework/stream/frame.h"
#include "framework/stream/online_tracklets.h"

#include <cstdint>
#include <memory>
#include <vector>

namespace soma {

class LabelerImpl;
class FrameLabeler;

/// Options of StreamLabeler.
struct StreamLabelerOptions {
  /// Random point order per frame (REFERENCE 5.3), seeded per frame index as
  /// in an offline `soma label` of the same take.
  bool permute = true;
  uint64_t seed = 0;
  bool use_fast_path = true;
  /// Stabilise labels over trajectories (false: per-frame labels).
  bool tracklets = true;
  OnlineTrackletOptions tracklet;
};

/// The labels of one frame, per point of the StreamFrame (absent points:
/// null, confidence 0).
struct StreamLabels {
  std::vector<int> per_frame;     ///< the labeler's labels (duplicate rule 5.4)
  std::vector<int> labels;        ///< final: per_frame or the tracklet vote
  std::vector<float> confidence;  ///< the labeler's probability of `labels`
  double label_ms = 0.0;          ///< time spent in the forward pass
};

class StreamLabeler {
 public:
  StreamLabeler(const std::shared_ptr<LabelerImpl>& model,
                const StreamLabelerOptions& options);
  ~StreamLabeler();
  StreamLabeler(StreamLabeler&&) noexcept;
  StreamLabeler& operator=(StreamLabeler&&) noexcept;

  /// Labels `frame`, whose coordinates are `metres_per_unit` metres per
  /// unit; `frame_index` (0, 1, ... in stream order, dropped frames
  /// included) seeds the point permutation.
  StreamLabels Label(const StreamFrame& frame,
                     double metres_per_unit,
                     int64_t frame_index);

  int num_labels() const;
  bool uses_fast_path() const;
  const OnlineTrackletVoter& voter() const { return voter_; }

 private:
  std::unique_ptr<FrameLabeler> labeler_;
  StreamLabelerOptions options_;
  OnlineTrackletVoter voter_;
};

}  // namespace soma
