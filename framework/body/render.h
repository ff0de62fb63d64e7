// Orthographic rendering of a posed body with its markers, for a person to
// look at: front and side views side by side, Lambert-shaded mesh (z-buffer),
// markers as discs (hollow when hidden behind the body) with their labels.
#pragma once

#include "framework/core/image.h"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <string>
#include <vector>

namespace soma {

struct RenderOptions {
  int view_size = 600;          // pixels per view (square)
  double marker_radius_px = 4;  // disc radius
  bool labels = true;           // draw marker labels
  std::string title;            // drawn above the views
};

/// Front view (from -Y, the direction the rest body faces) and side view
/// (from +X, the body's left) of `vertices`/`faces` with `markers` (3 x M,
/// may be empty) and their `labels` (empty or M strings). Both views share
/// one scale and fit the body and markers with a margin.
Image RenderBodyViews(const Eigen::Matrix3Xd& vertices,
                      const Eigen::Matrix3Xi& faces,
                      const Eigen::Matrix3Xd& markers,
                      const std::vector<std::string>& labels,
                      const RenderOptions& options = {});

}  // namespace soma
