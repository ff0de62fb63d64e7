#include "framework/solve/labelled_markers.h"

#include "framework/core/error.h"

#include <fmt/format.h>

#include <limits>
#include <map>

namespace soma {
namespace {

/// Column of each capture label in the layout (-1: unmatched), filling
/// the label lists of `out`.
std::vector<int> MatchLabels(const std::vector<std::string>& labels,
                             const MarkerLayout& layout,
                             LabelledMarkers* out) {
  std::map<std::string, int> layout_index;
  for (int m = 0; m < layout.num_markers(); ++m) {
    layout_index.emplace(CanonicalMarkerLabel(layout.markers[m].label), m);
    out->labels.push_back(layout.markers[m].label);
  }
  std::vector<int> column(labels.size(), -1);
  std::vector<bool> seen(layout.num_markers(), false);
  for (size_t p = 0; p < labels.size(); ++p) {
    const auto it = layout_index.find(CanonicalMarkerLabel(labels[p]));
    if (it == layout_index.end() || seen[it->second]) {
      out->unmatched_labels.push_back(labels[p]);
      continue;
    }
    seen[it->second] = true;
    column[p] = it->second;
  }
  for (int m = 0; m < layout.num_markers(); ++m) {
    if (!seen[m]) out->absent_labels.push_back(layout.markers[m].label);
  }
  return column;
}

}  // namespace

LabelledMarkers MatchToLayout(const C3dData& c3d, const MarkerLayout& layout) {
  LabelledMarkers out;
  const std::vector<int> column = MatchLabels(c3d.labels, layout, &out);
  if (static_cast<int>(out.absent_labels.size()) == layout.num_markers()) {
    throw IoError(fmt::format(
        "{}: none of its {} labels is in the layout ({} markers, e.g. {})",
        c3d.source,
        c3d.labels.size(),
        layout.num_markers(),
        layout.num_markers() > 0 ? layout.markers[0].label : ""));
  }
  out.frame_rate = c3d.frame_rate;
  const double scale = c3d.MetresPerUnit();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  out.frames.resize(c3d.num_frames);
  for (int t = 0; t < c3d.num_frames; ++t) {
    Eigen::Matrix3Xd& frame = out.frames[t];
    frame = Eigen::Matrix3Xd::Constant(3, layout.num_markers(), nan);
    for (int p = 0; p < c3d.num_points; ++p) {
      if (column[p] < 0 || !c3d.valid(t, p)) continue;
      const Eigen::Vector3d x = c3d.Point(t, p).cast<double>() * scale;
      if (x.allFinite()) frame.col(column[p]) = x;
    }
  }
  return out;
}

LabelledMarkers MatchToLayout(const std::vector<std::string>& labels,
                              const Eigen::Matrix3Xd& points,
                              const MarkerLayout& layout) {
  if (static_cast<int>(labels.size()) != points.cols()) {
    throw ShapeError(fmt::format("MatchToLayout: {} labels for {} points",
                                 labels.size(),
                                 points.cols()));
  }
  LabelledMarkers out;
  const std::vector<int> column = MatchLabels(labels, layout, &out);
  out.frames.push_back(Eigen::Matrix3Xd::Constant(
      3, layout.num_markers(), std::numeric_limits<double>::quiet_NaN()));
  for (size_t p = 0; p < labels.size(); ++p) {
    if (column[p] >= 0 && points.col(p).allFinite()) {
      out.frames[0].col(column[p]) = points.col(p);
    }
  }
  return out;
}

}  // namespace soma
