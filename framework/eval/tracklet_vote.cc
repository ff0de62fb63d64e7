#include "framework/eval/tracklet_vote.h"

#include "framework/core/error.h"

#include <fmt/format.h>

#include <algorithm>

namespace soma {

std::vector<int64_t> TrackletLabels(
    std::span<const int64_t> predicted,
    int64_t max_points,
    const std::vector<std::vector<int>>& trajectories,
    int num_trajectories,
    int64_t num_labels) {
  const auto num_frames = static_cast<int64_t>(trajectories.size());
  if (max_points < 0 || num_trajectories < 0 || num_labels < 0) {
    throw ShapeError(fmt::format(
        "TrackletLabels: max_points = {}, num_trajectories = {}, num_labels = "
        "{}; expected all >= 0",
        max_points,
        num_trajectories,
        num_labels));
  }
  if (static_cast<int64_t>(predicted.size()) != num_frames * max_points) {
    throw ShapeError(fmt::format(
        "TrackletLabels: {} predicted labels for {} frames of {} points; "
        "expected {}",
        predicted.size(),
        num_frames,
        max_points,
        num_frames * max_points));
  }
  // votes[k][l]: how often trajectory k was predicted label l (l = L: null).
  std::vector<std::vector<int64_t>> votes(
      num_trajectories, std::vector<int64_t>(num_labels + 1, 0));
  for (int64_t t = 0; t < num_frames; ++t) {
    const std::vector<int>& row = trajectories[t];
    if (static_cast<int64_t>(row.size()) > max_points) {
      throw ShapeError(fmt::format(
          "TrackletLabels: frame {} has {} points; expected at most {}",
          t,
          row.size(),
          max_points));
    }
    for (size_t p = 0; p < row.size(); ++p) {
      const int k = row[p];
      const int64_t label = predicted[t * max_points + p];
      if (k < 0 || k >= num_trajectories) {
        throw ShapeError(fmt::format(
            "TrackletLabels: frame {} point {} is on trajectory {}; expected "
            "0 <= trajectory < {}",
            t,
            p,
            k,
            num_trajectories));
      }
      if (label < 0 || label > num_labels) {
        throw ShapeError(fmt::format(
            "TrackletLabels: frame {} point {} is predicted label {}; "
            "expected 0 <= label <= {} (null)",
            t,
            p,
            label,
            num_labels));
      }
      ++votes[k][label];
    }
  }
  // The first maximum: ties go to the smallest id.
  std::vector<int64_t> trajectory_label(num_trajectories, num_labels);
  for (int k = 0; k < num_trajectories; ++k) {
    const std::vector<int64_t>& v = votes[k];
    trajectory_label[k] = std::max_element(v.begin(), v.end()) - v.begin();
  }
  std::vector<int64_t> out(predicted.size(), num_labels);
  for (int64_t t = 0; t < num_frames; ++t) {
    const std::vector<int>& row = trajectories[t];
    for (size_t p = 0; p < row.size(); ++p) {
      out[t * max_points + p] = trajectory_label[row[p]];
    }
  }
  return out;
}

}  // namespace soma
