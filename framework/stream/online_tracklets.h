// Online tracklet labelling (issue #26): the per-frame labels of the labeler
// stabilised over each trajectory's history, without looking ahead.
//
// Offline tracklet mode (REFERENCE 5.5, `soma label task.tracklet=true`) gives
// every trajectory the most frequent per-frame prediction over the whole take,
// future frames included. Online, a frame's labels are final when emitted, so
// each trajectory keeps a running vote over its past observations instead:
//
//   v <- decay * v + onehot(prediction),   decay = 2^(-1 / half_life)
//
// (one step per observation of the trajectory; null predictions vote too) and
// the trajectory's label in this frame is argmax v (ties: this frame's
// prediction, then the smallest id). A trajectory seen for the first time
// (a start, or the new id after a break) starts from an empty vote, so its
// first label is the per-frame one. A swap (the capture system's trajectory
// jumps to another marker) shows as a run of frames predicting the same other
// label: after `swap_frames` of them the votes restart from that run. Points
// without a trajectory id keep their per-frame label. Finally a real label
// claimed by two points of the frame is resolved (duplicates policy): by
// default the point with the most votes for it (the longer-established
// trajectory) keeps it and the others become null.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <unordered_map>
#include <vector>

namespace soma {

/// What happens when two points of a frame vote for the same real label.
enum class DuplicatePolicy {
  kNullAll,    ///< both become null (the offline rule, REFERENCE 5.4)
  kStrongest,  ///< the point with the most (decayed) votes for it keeps it
};
std::string_view ToString(DuplicatePolicy policy);
/// "null_all" | "strongest"; ConfigError otherwise.
DuplicatePolicy DuplicatePolicyFromString(std::string_view name);

/// Options of OnlineTrackletVoter.
struct OnlineTrackletOptions {
  /// Half-life of a vote, in observations of the trajectory; <= 0: no decay
  /// (a running majority vote over the whole past).
  double half_life = 240;
  /// Consecutive frames predicting one label other than the voted one after
  /// which the trajectory is taken to have swapped (votes restart); 0: never.
  int swap_frames = 0;
  /// A trajectory not seen for this many frames is forgotten (bounds memory;
  /// a later point with its id starts afresh). <= 0: never.
  int64_t forget_after = 100000;
  DuplicatePolicy duplicates = DuplicatePolicy::kStrongest;
  void Validate() const;  // ConfigError on violation
};

/// The running per-trajectory vote. Not thread-safe; one per stream.
class OnlineTrackletVoter {
 public:
  /// `num_labels` real labels; the null id is `num_labels`.
  OnlineTrackletVoter(int num_labels, const OnlineTrackletOptions& options);

  /// One frame: `track_ids[i]` the trajectory of point i (-1: none; ids are
  /// unique within a frame), `predicted[i]` its per-frame label in
  /// [0, num_labels] (the labeler's argmax, before any duplicate rule).
  /// `frame_index` must increase from call to call. Returns the final label
  /// of every point.
  std::vector<int> Update(int64_t frame_index,
                          std::span<const int32_t> track_ids,
                          std::span<const int> predicted);

  /// Trajectories currently remembered.
  int num_tracks() const { return static_cast<int>(tracks_.size()); }
  /// Swaps detected so far.
  int64_t num_swaps() const { return num_swaps_; }
  int num_labels() const { return num_labels_; }

 private:
  struct Track {
    std::vector<double> votes;  // L + 1
    int64_t last_seen = 0;
    int streak_label = -1;  // the label of the current disagreeing run
    int streak = 0;
  };
  int num_labels_;
  OnlineTrackletOptions options_;
  double decay_ = 1.0;
  std::unordered_map<int32_t, Track> tracks_;
  int64_t last_frame_ = INT64_MIN;
  int64_t num_swaps_ = 0;
};

}  // namespace soma
