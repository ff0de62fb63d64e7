#include "framework/view/view_capture.h"

#include "framework/body/marker_layout.h"
#include "framework/core/error.h"
#include "framework/io/c3d.h"
#include "framework/io/corrupted_take.h"
#include "framework/io/mocap_dataset.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <map>
#include <set>

namespace soma {
namespace {

namespace fs = std::filesystem;

/// Label names to ids in the order they are first seen.
class LabelIds {
 public:
  /// The id of `name`, a new one if unseen; -1 (null) for "".
  int Id(const std::string& name) {
    if (name.empty()) return -1;
    const auto [it, added] =
        ids_.emplace(name, static_cast<int>(names_.size()));
    if (added) names_.push_back(name);
    return it->second;
  }
  const std::vector<std::string>& names() const { return names_; }

 private:
  std::map<std::string, int> ids_;
  std::vector<std::string> names_;
};

/// Points of one frame (metres) with a label id each (-1 = null).
struct LabeledPoints {
  std::vector<Eigen::Vector3d> points;
  std::vector<int> labels;
  std::vector<int> columns;  // input column (track id), -1 unknown
  std::vector<float> confidences;
};

/// A C3D column label as a class name: canonical marker name, or "" (null)
/// for unlabelled columns (`*12`, empty).
std::string ClassOfColumn(const std::string& label) {
  std::string canonical = CanonicalMarkerLabel(label);
  if (canonical.empty() || canonical[0] == '*') return "";
  return canonical;
}

bool IsPresent(const C3dData& c3d, int t, int k) {
  if (!c3d.valid(t, k)) return false;
  const Eigen::Vector3f p = c3d.Point(t, k);
  return p.allFinite() && !(p.array() == 0.0f).all();
}

/// The label id of each C3D column (its class, registered in column order;
/// -1 null), or kOutputColumn for the model outputs that are left out.
constexpr int kOutputColumn = -2;
std::vector<int> ColumnIds(const C3dData& c3d, LabelIds& ids) {
  const std::vector<bool> is_output = NonPositionColumns(c3d);
  std::vector<int> column_ids(c3d.num_points, -1);
  for (int k = 0; k < c3d.num_points; ++k) {
    if (is_output[k]) {
      column_ids[k] = kOutputColumn;
    } else if (k < static_cast<int>(c3d.labels.size())) {
      column_ids[k] = ids.Id(ClassOfColumn(c3d.labels[k]));
    }
  }
  return column_ids;
}

/// Per frame: the present points of a C3D (model outputs left out) and
/// their column classes.
std::vector<LabeledPoints> C3dPoints(const C3dData& c3d, LabelIds& ids) {
  const double to_metres = c3d.MetresPerUnit();
  const std::vector<int> column_ids = ColumnIds(c3d, ids);
  std::vector<LabeledPoints> frames(c3d.num_frames);
  for (int t = 0; t < c3d.num_frames; ++t) {
    for (int k = 0; k < c3d.num_points; ++k) {
      if (column_ids[k] == kOutputColumn || !IsPresent(c3d, t, k)) continue;
      frames[t].points.push_back(c3d.Point(t, k).cast<double>() * to_metres);
      frames[t].labels.push_back(column_ids[k]);
      frames[t].columns.push_back(k);
    }
  }
  return frames;
}

/// Ids of a dataset's label names (canonical), registered when first used.
class DatasetLabelIds {
 public:
  DatasetLabelIds(const DatasetInfo& info, LabelIds& ids)
      : info_(info), ids_(ids), cache_(info.num_labels(), kUnseen) {}
  /// The id of dataset label `id` (null = L = -1).
  int operator()(int16_t id) {
    if (id < 0 || id >= info_.num_labels()) return -1;
    if (cache_[id] == kUnseen) {
      cache_[id] = ids_.Id(CanonicalMarkerLabel(info_.labels[id]));
    }
    return cache_[id];
  }

 private:
  static constexpr int kUnseen = -3;
  const DatasetInfo& info_;
  LabelIds& ids_;
  std::vector<int> cache_;
};

/// A `soma corrupt` ground truth: points from `<stem>.c3d`, per-frame labels
/// from `<stem>.h5`; or a labelled C3D.
std::vector<LabeledPoints> ReadTruth(const fs::path& path, LabelIds& ids) {
  if (path.extension() == ".c3d") return C3dPoints(ReadC3d(path), ids);
  if (path.extension() != ".h5") {
    throw IoError(fmt::format(
        "{}: ground truth must be a soma corrupt .h5 (with its .c3d) or a "
        "labelled .c3d",
        path.string()));
  }
  const CorruptedTake take = ReadCorruptedTake(path);
  const C3dData& c3d = take.c3d;
  const LabeledFrames& gt = take.truth;
  const DatasetInfo& info = take.info;
  const double to_metres = c3d.MetresPerUnit();
  DatasetLabelIds label_id(info, ids);
  std::vector<LabeledPoints> frames(c3d.num_frames);
  for (int t = 0; t < c3d.num_frames; ++t) {
    const int16_t* labels = gt.frame_labels(t);
    for (int k = 0; k < c3d.num_points; ++k) {
      if (!IsPresent(c3d, t, k)) continue;
      frames[t].points.push_back(c3d.Point(t, k).cast<double>() * to_metres);
      frames[t].labels.push_back(label_id(labels[k]));
      frames[t].columns.push_back(k);
    }
  }
  return frames;
}

/// A `soma label` sidecar: per frame its non-padding points, labels,
/// confidences and input columns.
std::vector<LabeledPoints> ReadSidecar(const fs::path& path, LabelIds& ids) {
  const DatasetReader reader(path);
  const DatasetInfo& info = reader.info();
  LabeledFrames data;
  reader.Read(0, reader.num_frames(), &data);
  const std::vector<float> confidence = reader.ReadPointArray("confidence");
  const std::vector<float> column = reader.ReadPointArray("column");
  const int N = info.num_points;
  DatasetLabelIds label_id(info, ids);
  std::vector<LabeledPoints> frames(reader.num_frames());
  for (int64_t t = 0; t < reader.num_frames(); ++t) {
    const float* p = data.frame_points(t);
    const int16_t* labels = data.frame_labels(t);
    for (int n = 0; n < N; ++n) {
      const size_t i = static_cast<size_t>(t) * N + n;
      if (column[i] < 0) continue;  // padding
      const float* x = p + size_t{3} * n;
      frames[t].points.emplace_back(x[0], x[1], x[2]);
      frames[t].labels.push_back(label_id(labels[n]));
      frames[t].columns.push_back(static_cast<int>(column[i]));
      frames[t].confidences.push_back(confidence[i]);
    }
  }
  return frames;
}

/// The index of the one point of `candidates` within `tolerance` (max
/// coordinate difference) of `x`; -1 when none or several are.
int UniqueMatch(const Eigen::Vector3d& x,
                const std::vector<Eigen::Vector3d>& candidates,
                double tolerance) {
  int found = -1;
  for (size_t j = 0; j < candidates.size(); ++j) {
    if ((candidates[j] - x).cwiseAbs().maxCoeff() <= tolerance) {
      if (found >= 0) return -1;
      found = static_cast<int>(j);
    }
  }
  return found;
}

void CheckFrames(const std::string& file,
                 size_t frames,
                 const std::string& capture,
                 size_t expected) {
  if (frames != expected) {
    throw IoError(fmt::format("{}: {} frames, but the capture {} has {}",
                              file,
                              frames,
                              capture,
                              expected));
  }
}

}  // namespace

std::string FindSidecar(const std::string& capture) {
  const fs::path path(capture);
  const std::string stem = path.stem().string();
  constexpr std::string_view kSuffix = "_labeled";
  if (stem.size() <= kSuffix.size() ||
      stem.compare(stem.size() - kSuffix.size(), kSuffix.size(), kSuffix) !=
          0) {
    return "";
  }
  const fs::path sidecar =
      path.parent_path() /
      (stem.substr(0, stem.size() - kSuffix.size()) + "_labels.h5");
  return fs::exists(sidecar) ? sidecar.string() : "";
}

ViewFrames ReadViewFrames(const ViewInputs& inputs) {
  // Label ids: capture columns, then sidecar labels, then ground truth.
  LabelIds ids;
  const C3dData c3d = ReadC3d(inputs.capture);
  const std::vector<int> column_ids = ColumnIds(c3d, ids);
  std::vector<LabeledPoints> truth, sidecar;
  if (!inputs.sidecar.empty()) {
    sidecar = ReadSidecar(inputs.sidecar, ids);
    CheckFrames(inputs.sidecar, sidecar.size(), inputs.capture, c3d.num_frames);
  }
  if (!inputs.truth.empty()) {
    truth = ReadTruth(inputs.truth, ids);
    CheckFrames(inputs.truth, truth.size(), inputs.capture, c3d.num_frames);
  }

  ViewFrames frames;
  frames.title = fs::path(inputs.capture).filename().string();
  frames.source = inputs.capture;
  frames.truth_source = inputs.truth;
  frames.confidence_source = inputs.sidecar;
  frames.frame_rate = c3d.frame_rate;
  frames.first_frame = c3d.first_frame;
  frames.with_truth = !inputs.truth.empty();
  frames.with_confidence = !inputs.sidecar.empty();
  frames.labels = ids.names();
  const int L = static_cast<int>(frames.labels.size());
  auto id_or_null = [L](int id) { return id < 0 ? L : id; };

  const double to_metres = c3d.MetresPerUnit();
  int64_t from_sidecar = 0;
  for (int t = 0; t < c3d.num_frames; ++t) {
    for (int k = 0; k < c3d.num_points; ++k) {
      if (column_ids[k] == kOutputColumn || !IsPresent(c3d, t, k)) continue;
      const Eigen::Vector3d x = c3d.Point(t, k).cast<double>() * to_metres;
      int label = id_or_null(column_ids[k]);
      int track = k;
      float confidence = std::numeric_limits<float>::quiet_NaN();
      if (!sidecar.empty()) {
        const int j =
            UniqueMatch(x, sidecar[t].points, inputs.sidecar_tolerance);
        if (j >= 0) {
          ++from_sidecar;
          confidence = sidecar[t].confidences[j];
          track = sidecar[t].columns[j];
          if (label == L) label = id_or_null(sidecar[t].labels[j]);
        }
      }
      int true_label = L + 1;
      if (!truth.empty()) {
        const int j = UniqueMatch(x, truth[t].points, inputs.tolerance);
        if (j >= 0) true_label = id_or_null(truth[t].labels[j]);
      }
      const float position[3] = {static_cast<float>(x.x()),
                                 static_cast<float>(x.y()),
                                 static_cast<float>(x.z())};
      frames.AddPoint(position, label, true_label, confidence, track);
    }
    frames.EndFrame();
  }
  frames.track_source =
      from_sidecar > 0
          ? fmt::format("input column of the labeller ({})", inputs.sidecar)
          : fmt::format("column of {}", inputs.capture);
  frames.Validate();
  return frames;
}

std::vector<std::array<int, 2>> NeighbourSticks(
    const std::vector<std::string>& labels,
    const std::vector<std::string>& layout_labels,
    const Eigen::Matrix3Xd& layout_positions,
    int neighbours) {
  if (static_cast<Eigen::Index>(layout_labels.size()) !=
      layout_positions.cols()) {
    throw ShapeError(
        fmt::format("NeighbourSticks: {} layout labels but {} "
                    "positions",
                    layout_labels.size(),
                    layout_positions.cols()));
  }
  // (label id, layout column) of the labels the layout has.
  std::vector<std::pair<int, int>> present;
  for (size_t m = 0; m < layout_labels.size(); ++m) {
    const std::string name = CanonicalMarkerLabel(layout_labels[m]);
    const auto it = std::find(labels.begin(), labels.end(), name);
    if (it != labels.end()) {
      present.emplace_back(static_cast<int>(it - labels.begin()),
                           static_cast<int>(m));
    }
  }
  std::set<std::array<int, 2>> sticks;
  for (const auto& [id, m] : present) {
    std::vector<std::pair<double, int>> by_distance;
    for (const auto& [other_id, other_m] : present) {
      if (other_id == id) continue;
      by_distance.emplace_back(
          (layout_positions.col(m) - layout_positions.col(other_m)).norm(),
          other_id);
    }
    const size_t k =
        std::min<size_t>(std::max(neighbours, 0), by_distance.size());
    std::partial_sort(
        by_distance.begin(), by_distance.begin() + k, by_distance.end());
    for (size_t j = 0; j < k; ++j) {
      const int other = by_distance[j].second;
      sticks.insert({std::min(id, other), std::max(id, other)});
    }
  }
  return {sticks.begin(), sticks.end()};
}

}  // namespace soma
