#include "framework/stream/online_tracklets.h"

#include "framework/core/error.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <numeric>

namespace soma {

std::string_view ToString(DuplicatePolicy policy) {
  switch (policy) {
    case DuplicatePolicy::kNullAll:
      return "null_all";
    case DuplicatePolicy::kStrongest:
      return "strongest";
  }
  return "?";
}

DuplicatePolicy DuplicatePolicyFromString(std::string_view name) {
  if (name == "null_all") return DuplicatePolicy::kNullAll;
  if (name == "strongest") return DuplicatePolicy::kStrongest;
  throw ConfigError(fmt::format(
      "Invalid configuration. duplicates = {}. Violated constraint: one of "
      "null_all, strongest",
      name));
}

void OnlineTrackletOptions::Validate() const {
  if (swap_frames < 0) {
    throw ConfigError(fmt::format(
        "Invalid configuration. tracklets.swap_frames = {}. Violated "
        "constraint: swap_frames >= 0",
        swap_frames));
  }
  if (!std::isfinite(half_life)) {
    throw ConfigError(
        fmt::format("Invalid configuration. tracklets.half_life = {}. Violated "
                    "constraint: finite",
                    half_life));
  }
}

OnlineTrackletVoter::OnlineTrackletVoter(int num_labels,
                                         const OnlineTrackletOptions& options)
    : num_labels_(num_labels), options_(options) {
  options_.Validate();
  SOMA_CHECK(num_labels > 0) << "OnlineTrackletVoter needs labels";
  decay_ = options_.half_life > 0 ? std::exp2(-1.0 / options_.half_life) : 1.0;
}

std::vector<int> OnlineTrackletVoter::Update(int64_t frame_index,
                                             std::span<const int32_t> track_ids,
                                             std::span<const int> predicted) {
  SOMA_CHECK_EQ(track_ids.size(), predicted.size());
  SOMA_CHECK(frame_index > last_frame_)
      << "OnlineTrackletVoter: frame " << frame_index << " after "
      << last_frame_;
  last_frame_ = frame_index;
  const int null = num_labels_;
  const size_t n = predicted.size();
  std::vector<int> labels(n, null);
  std::vector<double> strength(n, 0.0);  // vote mass of the chosen label
  for (size_t i = 0; i < n; ++i) {
    const int p = predicted[i];
    SOMA_CHECK(p >= 0 && p <= null)
        << "predicted label " << p << " outside [0, " << null << "]";
    if (track_ids[i] < 0) {
      labels[i] = p;
      strength[i] = 0.0;
      continue;
    }
    auto [it, inserted] = tracks_.try_emplace(track_ids[i]);
    Track& track = it->second;
    if (inserted) track.votes.assign(static_cast<size_t>(null) + 1, 0.0);
    track.last_seen = frame_index;
    // The label voted before this frame, for the swap test.
    const auto best_before =
        std::max_element(track.votes.begin(), track.votes.end());
    const int voted_before =
        *best_before > 0 ? static_cast<int>(best_before - track.votes.begin())
                         : p;
    if (options_.swap_frames > 0 && p != voted_before) {
      track.streak = p == track.streak_label ? track.streak + 1 : 1;
      track.streak_label = p;
      if (track.streak >= options_.swap_frames) {
        // The trajectory now follows another marker: restart from the run.
        std::fill(track.votes.begin(), track.votes.end(), 0.0);
        double weight = 0.0;
        for (int k = 0; k < track.streak - 1; ++k) weight = weight * decay_ + 1;
        track.votes[static_cast<size_t>(p)] = weight;
        track.streak = 0;
        track.streak_label = -1;
        ++num_swaps_;
      }
    } else {
      track.streak = 0;
      track.streak_label = -1;
    }
    for (double& v : track.votes) v *= decay_;
    track.votes[static_cast<size_t>(p)] += 1.0;
    int best = p;
    for (int k = 0; k <= null; ++k) {
      if (track.votes[static_cast<size_t>(k)] >
          track.votes[static_cast<size_t>(best)])
        best = k;
    }
    labels[i] = best;
    strength[i] = track.votes[static_cast<size_t>(best)];
  }

  // Duplicate real labels within the frame.
  std::vector<size_t> order(n);
  std::iota(order.begin(), order.end(), size_t{0});
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) {
    return strength[a] > strength[b];
  });
  std::vector<int> owner(static_cast<size_t>(null), -1);
  std::vector<bool> contested(static_cast<size_t>(null), false);
  for (size_t i : order) {
    const int l = labels[i];
    if (l == null) continue;
    if (owner[static_cast<size_t>(l)] < 0) {
      owner[static_cast<size_t>(l)] = static_cast<int>(i);
    } else {
      contested[static_cast<size_t>(l)] = true;
      labels[i] = null;
    }
  }
  if (options_.duplicates == DuplicatePolicy::kNullAll) {
    for (int l = 0; l < null; ++l) {
      if (contested[static_cast<size_t>(l)])
        labels[static_cast<size_t>(owner[static_cast<size_t>(l)])] = null;
    }
  }

  if (options_.forget_after > 0) {
    for (auto it = tracks_.begin(); it != tracks_.end();) {
      if (frame_index - it->second.last_seen > options_.forget_after) {
        it = tracks_.erase(it);
      } else {
        ++it;
      }
    }
  }
  return labels;
}

}  // namespace soma
