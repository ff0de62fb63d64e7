// Offline tracklet labelling (REFERENCE 5.5, `soma label task.tracklet=true`):
// every trajectory of a take (an input C3D column) gets the label predicted
// most often over the frames where it has a point, and every point of it
// takes that label. Null predictions vote too; on a tie the smallest id wins.
// The same-frame duplicate rule (5.4) is applied by the caller afterwards
// (ResolveDuplicateLabels, model/inference.h).
//
// The online counterpart, which looks only at past frames, is
// OnlineTrackletVoter (stream/online_tracklets.h). No libtorch here: labels
// are plain row-major int64 arrays, so evaluation code can use it too.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

namespace soma {

/// The per-point labels after the tracklet vote. `predicted` holds T x P
/// labels, row-major (frame t, packed point p), each in [0, num_labels]
/// (num_labels is null). `trajectories[t][p]` is the trajectory, in
/// [0, num_trajectories), of packed point p of frame t; points from
/// trajectories[t].size() to P - 1 are padding (their labels are not read).
/// Returns T x P labels, row-major: each point its trajectory's most frequent
/// prediction, padding null. ShapeError on inconsistent sizes, a trajectory
/// or label out of range.
std::vector<int64_t> TrackletLabels(
    std::span<const int64_t> predicted,
    int64_t max_points,
    const std::vector<std::vector<int>>& trajectories,
    int num_trajectories,
    int64_t num_labels);

}  // namespace soma
