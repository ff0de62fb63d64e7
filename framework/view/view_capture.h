// Reading what `soma view` shows (issue #27): a C3D capture, optionally its
// ground truth (a `soma corrupt` .h5 with its .c3d, or a labelled C3D) and
// a `soma label` sidecar (`<take>_labels.h5`: confidences and the input
// trajectory of every point), into ViewFrames; and the sticks drawn between
// a layout's neighbouring markers.
#pragma once

#include "framework/view/view_data.h"

#include <Eigen/Core>

#include <array>
#include <string>
#include <vector>

namespace soma {

/// The files of one page.
struct ViewInputs {
  std::string capture;  ///< the C3D shown (raw, labelled or ground truth)
  /// "" or the ground truth: a `soma corrupt` .h5 (its .c3d beside it) or a
  /// labelled .c3d. Points are matched by exact coordinates, as `soma eval`
  /// does, so it must come from the same capture.
  std::string truth;
  /// "" or a `soma label` sidecar of the same capture (points matched by
  /// coordinates within `sidecar_tolerance`).
  std::string sidecar;
  double tolerance = 1e-8;          ///< metres per coordinate (soma eval's)
  double sidecar_tolerance = 1e-6;  ///< metres: the sidecar stores float32 m
};

/// Reads the inputs. A point is shown when it is valid, finite and not
/// (0, 0, 0), and its column is not a model output that is no position
/// (listed in POINT:ANGLES, FORCES, MOMENTS, POWERS, SCALARS or REACTIONS;
/// virtual points such as a Plug-in Gait segment's origin are shown). Its label
/// is its C3D column's canonical label (CanonicalMarkerLabel; `*<k>` and empty
/// columns are null), else the sidecar's label of the point at its coordinates;
/// its true label is the label of the one ground-truth point at its coordinates
/// (none when zero or several match); its track id is the sidecar's input
/// column when the sidecar has the point, else its column in `capture`. Label
/// ids: the capture's labelled columns in column order, then the sidecar's
/// labels, then the ground truth's. IoError (one line, naming the file) for
/// unreadable files or frame counts that differ from the capture's.
ViewFrames ReadViewFrames(const ViewInputs& inputs);

/// The `<stem>_labels.h5` beside a `<stem>_labeled.c3d` when it exists
/// (what `soma label` writes), else "".
std::string FindSidecar(const std::string& capture);

/// Sticks between neighbouring markers: every label of `labels` that the
/// layout has is joined to its `neighbours` nearest layout markers (among
/// those also in `labels`) by distance between `layout_positions` (3 x M,
/// the layout on a body at rest, columns in `layout_labels` order). Pairs
/// of label ids (into `labels`), each once, smaller id first, sorted.
std::vector<std::array<int, 2>> NeighbourSticks(
    const std::vector<std::string>& labels,
    const std::vector<std::string>& layout_labels,
    const Eigen::Matrix3Xd& layout_positions,
    int neighbours);

}  // namespace soma
