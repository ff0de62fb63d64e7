// The sequences `soma eval` scores (REFERENCE.md section 4): labelled C3D
// captures (one class per column) and `soma corrupt` ground truth (points
// from the corrupted `.c3d`, per-frame labels from the `.h5` beside it), read
// into one form: T frames of K points in metres with their label names, the
// null class being kNullLabel (labeling_metrics.h).
#pragma once

#include <Eigen/Core>

#include <filesystem>
#include <string>
#include <vector>

namespace soma {

/// T frames of K points (metres, (0,0,0) = missing) and their labels.
struct ScoredSequence {
  std::vector<Eigen::Matrix3Xd> frames;
  /// Per column (size K) when every frame shares the column labels, or per
  /// frame (T x K) when ground truth changes along a column.
  std::vector<std::string> column_labels;
  std::vector<std::vector<std::string>> frame_labels;

  const std::vector<std::string>& LabelsAt(size_t t) const {
    return frame_labels.empty() ? column_labels : frame_labels[t];
  }
};

/// A C3D column label as a class name: the canonical marker name
/// (CanonicalMarkerLabel), or kNullLabel for unlabelled columns (`*12`,
/// empty).
std::string ClassOfColumn(const std::string& label);

/// A labelled C3D (e.g. `soma label`'s output: labelled columns and null
/// columns `*<k>`): invalid points are (0, 0, 0), column labels are
/// ClassOfColumn of the file's labels. IoError as ReadC3d.
ScoredSequence ReadC3dSequence(const std::filesystem::path& path);

/// A `soma corrupt` ground truth: points from `<stem>.c3d` (beside `h5`),
/// per-frame label names from the label ids of `<stem>.h5` (ids outside the
/// dataset's labels are null). IoError when the `.c3d` is missing or the two
/// files disagree in frames or columns.
ScoredSequence ReadCorruptedGroundTruth(const std::filesystem::path& h5);

/// ReadCorruptedGroundTruth for `.h5`, ReadC3dSequence for `.c3d`, IoError
/// for any other extension.
ScoredSequence ReadGroundTruth(const std::filesystem::path& path);

}  // namespace soma
