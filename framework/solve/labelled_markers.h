// Labelled mocap in a layout's marker order: the solver's input. Labels of
// the capture are matched to the layout through CanonicalMarkerLabel (vendor
// aliases, subject prefixes); points that are invalid in the file or not
// finite become NaN columns (missing markers).
#pragma once

#include "framework/body/marker_layout.h"
#include "framework/io/c3d.h"

#include <Eigen/Core>

#include <string>
#include <vector>

namespace soma {

struct LabelledMarkers {
  std::vector<std::string> labels;       // the layout's labels, in order
  std::vector<Eigen::Matrix3Xd> frames;  // 3 x M per frame, metres, NaN
  double frame_rate = 0.0;               // Hz
  /// Labels of the capture that are not in the layout (ignored), and
  /// capture labels that repeat an already matched layout marker.
  std::vector<std::string> unmatched_labels;
  /// Layout labels the capture does not have (always missing).
  std::vector<std::string> absent_labels;

  int num_frames() const { return static_cast<int>(frames.size()); }
};

/// Matches the points of `c3d` to `layout` (converting to metres). Throws
/// IoError naming the file if no label of the capture is in the layout.
LabelledMarkers MatchToLayout(const C3dData& c3d, const MarkerLayout& layout);

/// The same for one frame given as labels + points (3 x N, metres).
LabelledMarkers MatchToLayout(const std::vector<std::string>& labels,
                              const Eigen::Matrix3Xd& points,
                              const MarkerLayout& layout);

}  // namespace soma
