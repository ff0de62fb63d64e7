#include "framework/eval/ground_truth.h"

#include "framework/body/marker_layout.h"
#include "framework/core/error.h"
#include "framework/eval/labeling_metrics.h"
#include "framework/io/c3d.h"
#include "framework/io/corrupted_take.h"

#include <fmt/format.h>

namespace soma {

namespace fs = std::filesystem;

std::string ClassOfColumn(const std::string& label) {
  std::string canonical = CanonicalMarkerLabel(label);
  if (canonical.empty() || canonical[0] == '*') return std::string(kNullLabel);
  return canonical;
}

namespace {

/// The points of `c3d` (metres, invalid = 0) with its column classes.
ScoredSequence SequenceOfC3d(const C3dData& c3d) {
  const double to_metres = c3d.MetresPerUnit();
  ScoredSequence seq;
  seq.frames.resize(c3d.num_frames);
  for (int t = 0; t < c3d.num_frames; ++t) {
    Eigen::Matrix3Xd& f = seq.frames[t];
    f.setZero(3, c3d.num_points);
    for (int p = 0; p < c3d.num_points; ++p) {
      if (c3d.valid(t, p))
        f.col(p) = c3d.Point(t, p).cast<double>() * to_metres;
    }
  }
  seq.column_labels.resize(c3d.num_points);
  for (int p = 0; p < c3d.num_points; ++p) {
    const std::string label =
        p < static_cast<int>(c3d.labels.size()) ? c3d.labels[p] : "";
    seq.column_labels[p] = ClassOfColumn(label);
  }
  return seq;
}

}  // namespace

ScoredSequence ReadC3dSequence(const fs::path& path) {
  return SequenceOfC3d(ReadC3d(path));
}

ScoredSequence ReadCorruptedGroundTruth(const fs::path& h5) {
  const CorruptedTake take = ReadCorruptedTake(h5);
  const DatasetInfo& info = take.info;
  ScoredSequence seq = SequenceOfC3d(take.c3d);
  seq.frame_labels.assign(seq.frames.size(), {});
  for (size_t t = 0; t < seq.frames.size(); ++t) {
    const int16_t* ids = take.truth.frame_labels(static_cast<int64_t>(t));
    auto& labels = seq.frame_labels[t];
    labels.resize(info.num_points);
    for (int k = 0; k < info.num_points; ++k) {
      labels[k] = ids[k] < info.num_labels() ? info.labels[ids[k]]
                                             : std::string(kNullLabel);
    }
  }
  return seq;
}

ScoredSequence ReadGroundTruth(const fs::path& path) {
  if (path.extension() == ".h5") return ReadCorruptedGroundTruth(path);
  if (path.extension() == ".c3d") return ReadC3dSequence(path);
  throw IoError(fmt::format(
      "{}: ground truth must be a soma corrupt .h5 (with its .c3d) or a "
      "labelled .c3d",
      path.string()));
}

}  // namespace soma
