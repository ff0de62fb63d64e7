#include "framework/eval/ground_truth.h"

#include "framework/body/marker_layout.h"
#include "framework/core/error.h"
#include "framework/eval/labeling_metrics.h"
#include "framework/io/c3d.h"
#include "framework/io/mocap_dataset.h"

#include <fmt/format.h>

namespace soma {

namespace fs = std::filesystem;

std::string ClassOfColumn(const std::string& label) {
  const std::string canonical = CanonicalMarkerLabel(label);
  if (canonical.empty() || canonical[0] == '*') return std::string(kNullLabel);
  return canonical;
}

ScoredSequence ReadC3dSequence(const fs::path& path) {
  const C3dData c3d = ReadC3d(path);
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

ScoredSequence ReadCorruptedGroundTruth(const fs::path& h5) {
  fs::path c3d_path = h5;
  c3d_path.replace_extension(".c3d");
  if (!fs::exists(c3d_path)) {
    throw IoError(fmt::format(
        "{}: ground truth needs its corrupted capture {} beside it (as soma "
        "corrupt writes them)",
        h5.string(),
        c3d_path.string()));
  }
  ScoredSequence seq = ReadC3dSequence(c3d_path);
  const DatasetReader reader(h5);
  const DatasetInfo& info = reader.info();
  if (reader.num_frames() != static_cast<int64_t>(seq.frames.size()) ||
      info.num_points != static_cast<int>(seq.column_labels.size())) {
    throw IoError(fmt::format(
        "{}: ground truth has {} frames x {} columns but {} has {} x {}",
        h5.string(),
        reader.num_frames(),
        info.num_points,
        c3d_path.string(),
        seq.frames.size(),
        seq.column_labels.size()));
  }
  LabeledFrames gt;
  reader.Read(0, reader.num_frames(), &gt);
  seq.frame_labels.assign(seq.frames.size(), {});
  for (size_t t = 0; t < seq.frames.size(); ++t) {
    const int16_t* ids = gt.frame_labels(static_cast<int64_t>(t));
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
