#include "framework/stream/online_tracklets.h"

#include "framework/core/error.h"

#include <gtest/gtest.h>

#include <vector>

namespace soma {
namespace {

constexpr int kLabels = 6;  // null = 6
constexpr int kNull = kLabels;

/// Feeds one trajectory `track` the per-frame predictions `predicted`,
/// starting at `first_frame`; returns the online labels.
std::vector<int> Feed(OnlineTrackletVoter& voter,
                      int32_t track,
                      const std::vector<int>& predicted,
                      int64_t first_frame = 0) {
  std::vector<int> out;
  for (size_t t = 0; t < predicted.size(); ++t) {
    const int32_t ids[] = {track};
    const int pred[] = {predicted[t]};
    out.push_back(voter.Update(first_frame + int64_t(t), ids, pred)[0]);
  }
  return out;
}

OnlineTrackletOptions NoDecay() {
  OnlineTrackletOptions options;
  options.half_life = 0;
  return options;
}

TEST(OnlineTrackletVoter, FirstObservationIsThePerFrameLabel) {
  OnlineTrackletVoter voter(kLabels, {});
  const int32_t ids[] = {0, 1, 2};
  const int pred[] = {3, kNull, 0};
  EXPECT_EQ(voter.Update(0, ids, pred), (std::vector<int>{3, kNull, 0}));
  EXPECT_EQ(voter.num_tracks(), 3);
}

TEST(OnlineTrackletVoter, IsolatedPerFrameErrorsAreOutvoted) {
  OnlineTrackletVoter voter(kLabels, {});
  std::vector<int> pred(30, 2);
  pred[10] = 4;
  pred[11] = kNull;
  pred[20] = 5;
  const std::vector<int> out = Feed(voter, 9, pred);
  for (size_t t = 0; t < out.size(); ++t) EXPECT_EQ(out[t], 2) << t;
}

TEST(OnlineTrackletVoter, NoLookAhead) {
  // Two streams with the same first 20 frames and different futures give
  // the same labels on those 20 frames.
  std::vector<int> a(20, 1);
  a[3] = a[4] = a[5] = 0;
  std::vector<int> b = a;
  a.insert(a.end(), 40, 3);
  b.insert(b.end(), 40, 1);
  OnlineTrackletVoter va(kLabels, NoDecay()), vb(kLabels, NoDecay());
  const std::vector<int> oa = Feed(va, 0, a), ob = Feed(vb, 0, b);
  for (int t = 0; t < 20; ++t) EXPECT_EQ(oa[t], ob[t]) << t;
  // The offline majority of `a` (1 over 20 frames vs 3 over 40) would be 3
  // everywhere; online, the early frames keep what was known then.
  EXPECT_EQ(oa[0], 1);
  EXPECT_EQ(oa[19], 1);
  EXPECT_EQ(oa.back(), 3);
}

TEST(OnlineTrackletVoter, EarlyFramesFollowTheCurrentPredictionOnTies) {
  OnlineTrackletVoter voter(kLabels, NoDecay());
  // 1 then 0: a tie after two frames; the current prediction wins it.
  EXPECT_EQ(Feed(voter, 0, {1, 0}), (std::vector<int>{1, 0}));
}

TEST(OnlineTrackletVoter, NullVotesCount) {
  // A ghost trajectory: mostly null per frame, sometimes a label.
  OnlineTrackletVoter voter(kLabels, {});
  const std::vector<int> out =
      Feed(voter, 5, {kNull, kNull, 2, kNull, 3, kNull, kNull, 2, kNull});
  for (size_t t = 0; t < out.size(); ++t) EXPECT_EQ(out[t], kNull) << t;
}

TEST(OnlineTrackletVoter, TrajectoriesStartAndEnd) {
  OnlineTrackletVoter voter(kLabels, {});
  // Frame 0-9: trajectory 1 (label 2); frame 5-14: trajectory 2 (label 4).
  for (int64_t t = 0; t < 15; ++t) {
    std::vector<int32_t> ids;
    std::vector<int> pred;
    if (t < 10) {
      ids.push_back(1);
      pred.push_back(t == 6 ? 4 : 2);  // one error while both are alive
    }
    if (t >= 5) {
      ids.push_back(2);
      pred.push_back(4);
    }
    const std::vector<int> out = voter.Update(t, ids, pred);
    if (t < 10) EXPECT_EQ(out[0], 2) << t;
    if (t >= 5) EXPECT_EQ(out.back(), 4) << t;
  }
}

TEST(OnlineTrackletVoter, ABrokenTrajectoryRestartsFromItsNewId) {
  // The capture system breaks a trajectory: its marker continues under a new
  // id. The new id has no history: its first label is the per-frame one.
  OnlineTrackletVoter voter(kLabels, NoDecay());
  Feed(voter, 1, std::vector<int>(50, 2));
  const std::vector<int> out = Feed(voter, 7, {3, 2, 2, 2}, 50);
  EXPECT_EQ(out, (std::vector<int>{3, 2, 2, 2}));  // 3 vs 2: tie at frame 51
}

TEST(OnlineTrackletVoter, ForgottenTrajectoriesStartAfresh) {
  OnlineTrackletOptions options;
  options.forget_after = 10;
  OnlineTrackletVoter voter(kLabels, options);
  Feed(voter, 1, std::vector<int>(20, 2));
  EXPECT_EQ(voter.num_tracks(), 1);
  Feed(voter, 2, std::vector<int>(11, 3), 20);  // trajectory 1 unseen for 11
  EXPECT_EQ(voter.num_tracks(), 1);
  // Id 1 reused for another marker: no memory of label 2.
  EXPECT_EQ(Feed(voter, 1, {5}, 40), (std::vector<int>{5}));
}

TEST(OnlineTrackletVoter, WithoutDecayOrSwapDetectionASwapIsNeverFollowed) {
  OnlineTrackletVoter voter(kLabels, NoDecay());
  std::vector<int> pred(100, 1);
  pred.insert(pred.end(), 60, 4);  // the trajectory now follows marker 4
  const std::vector<int> out = Feed(voter, 0, pred);
  EXPECT_EQ(out.back(), 1);
}

TEST(OnlineTrackletVoter, DecayFollowsASwapWithinTheHalfLifeScale) {
  OnlineTrackletOptions options;
  options.half_life = 10;
  OnlineTrackletVoter voter(kLabels, options);
  std::vector<int> pred(100, 1);
  pred.insert(pred.end(), 60, 4);
  const std::vector<int> out = Feed(voter, 0, pred);
  int switched = -1;
  for (int t = 100; t < 160; ++t) {
    if (out[t] == 4) {
      switched = t - 100;
      break;
    }
  }
  // Old votes ~ 1/(1-d) = 14.9 decaying, new ones 1 + d + ...: they cross
  // after 10 frames (half-life 10: d^n = 1/2).
  EXPECT_EQ(switched, 9);
  EXPECT_EQ(out.back(), 4);
}

TEST(OnlineTrackletVoter, SwapDetectionRestartsAfterARun) {
  OnlineTrackletOptions options;
  options.half_life = 0;
  options.swap_frames = 5;
  OnlineTrackletVoter voter(kLabels, options);
  std::vector<int> pred(100, 1);
  pred[50] = pred[51] = pred[52] = pred[53] = 3;  // a 4-frame run: no swap
  pred.insert(pred.end(), 20, 4);
  const std::vector<int> out = Feed(voter, 0, pred);
  for (int t = 0; t < 100; ++t) EXPECT_EQ(out[t], 1) << t;
  for (int t = 100; t < 104; ++t) EXPECT_EQ(out[t], 1) << t;
  for (int t = 104; t < 120; ++t) EXPECT_EQ(out[t], 4) << t;
  EXPECT_EQ(voter.num_swaps(), 1);
}

TEST(OnlineTrackletVoter, DuplicatesStrongestKeepsTheLabel) {
  OnlineTrackletVoter voter(kLabels, NoDecay());
  // Trajectory 0 has voted 2 for 10 frames; trajectory 1 appears, says 2.
  Feed(voter, 0, std::vector<int>(10, 2));
  const int32_t ids[] = {1, 0};
  const int pred[] = {2, 2};
  EXPECT_EQ(voter.Update(10, ids, pred), (std::vector<int>{kNull, 2}));
}

TEST(OnlineTrackletVoter, DuplicatesNullAllIsTheOfflineRule) {
  OnlineTrackletOptions options = NoDecay();
  options.duplicates = DuplicatePolicy::kNullAll;
  OnlineTrackletVoter voter(kLabels, options);
  Feed(voter, 0, std::vector<int>(10, 2));
  const int32_t ids[] = {1, 0, 2};
  const int pred[] = {2, 2, kNull};
  EXPECT_EQ(voter.Update(10, ids, pred),
            (std::vector<int>{kNull, kNull, kNull}));
}

TEST(OnlineTrackletVoter, UntrackedPointsKeepTheirPerFrameLabel) {
  OnlineTrackletVoter voter(kLabels, {});
  const int32_t ids[] = {-1, -1};
  const int pred0[] = {1, 3};
  const int pred1[] = {2, 4};
  EXPECT_EQ(voter.Update(0, ids, pred0), (std::vector<int>{1, 3}));
  EXPECT_EQ(voter.Update(1, ids, pred1), (std::vector<int>{2, 4}));
  EXPECT_EQ(voter.num_tracks(), 0);
}

TEST(OnlineTrackletVoter, RejectsFramesOutOfOrderAndBadLabels) {
  OnlineTrackletVoter voter(kLabels, {});
  const int32_t ids[] = {0};
  const int pred[] = {1};
  voter.Update(5, ids, pred);
  EXPECT_THROW(voter.Update(5, ids, pred), Error);
  const int bad[] = {kNull + 1};
  EXPECT_THROW(voter.Update(6, ids, bad), Error);
}

TEST(OnlineTrackletVoter, DuplicatePolicyNames) {
  EXPECT_EQ(DuplicatePolicyFromString("strongest"),
            DuplicatePolicy::kStrongest);
  EXPECT_EQ(ToString(DuplicatePolicy::kNullAll), "null_all");
  EXPECT_THROW(DuplicatePolicyFromString("both"), ConfigError);
}

}  // namespace
}  // namespace soma
