// A `soma corrupt` output (synth/corruption.h) as its readers (`soma eval`,
// `soma view`) open it: the corrupted capture `<stem>.c3d` and, beside it,
// its per-frame ground truth `<stem>.h5` (mocap_dataset.h), both with the
// same frames and columns.
#pragma once

#include "framework/io/c3d.h"
#include "framework/io/mocap_dataset.h"

#include <filesystem>

namespace soma {

struct CorruptedTake {
  std::filesystem::path c3d_path;  // <stem>.c3d
  C3dData c3d;                     // the corrupted capture, T x K
  DatasetInfo info;                // the ground truth's labels (L)
  /// T frames of K points: per frame, the label id of every column (null =
  /// L; ids outside the labels are null too).
  LabeledFrames truth;
};

/// Reads the ground truth `h5` and the capture beside it. IoError when the
/// `.c3d` is missing, either file is malformed, or they disagree in frames
/// or columns.
CorruptedTake ReadCorruptedTake(const std::filesystem::path& h5);

}  // namespace soma
