#include "framework/eval/tracklet_vote.h"

#include "framework/core/error.h"
#include "framework/testing/testing.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cstdint>
#include <vector>

namespace soma {
namespace {

using ::testing::ElementsAre;
using ::testing::HasSubstr;

constexpr int64_t kNull = 3;  // three real labels: 0, 1, 2

TEST(TrackletLabels, EveryPointOfATrajectoryTakesItsMostFrequentPrediction) {
  // Three frames of up to two points; trajectory 0 is predicted 1, 1, 2 and
  // trajectory 1 (packed at different slots per frame) 0, null, 0.
  const std::vector<std::vector<int>> trajectories = {{0, 1}, {1, 0}, {0, 1}};
  const std::vector<int64_t> predicted = {1,
                                          0,  //
                                          kNull,
                                          1,  //
                                          2,
                                          0};
  EXPECT_THAT(TrackletLabels(predicted, 2, trajectories, 2, kNull),
              ElementsAre(1,
                          0,  //
                          0,
                          1,  //
                          1,
                          0));
}

TEST(TrackletLabels, NullVotesCountAndTiesGoToTheSmallestId) {
  // Trajectory 0: null twice, label 2 once: null wins. Trajectory 1: labels
  // 2 and 1 once each: the tie goes to 1.
  const std::vector<std::vector<int>> trajectories = {{0, 1}, {0, 1}, {0}};
  const std::vector<int64_t> predicted = {kNull,
                                          2,  //
                                          kNull,
                                          1,  //
                                          2,
                                          kNull};
  EXPECT_THAT(TrackletLabels(predicted, 2, trajectories, 3, kNull),
              ElementsAre(kNull,
                          1,  //
                          kNull,
                          1,  //
                          kNull,
                          kNull));
}

TEST(TrackletLabels, PaddingIsNullAndNotRead) {
  // The padding slot holds an out-of-range label: it is never read.
  const std::vector<std::vector<int>> trajectories = {{2}, {2, 0}};
  const std::vector<int64_t> predicted = {0,
                                          99,  //
                                          0,
                                          1};
  EXPECT_THAT(TrackletLabels(predicted, 2, trajectories, 3, kNull),
              ElementsAre(0,
                          kNull,  //
                          0,
                          1));
}

TEST(TrackletLabels, NoFramesGiveNoLabels) {
  EXPECT_TRUE(TrackletLabels({}, 4, {}, 2, kNull).empty());
}

TEST(TrackletLabels, InconsistentInputsAreShapeErrors) {
  const std::vector<int64_t> two = {0, 1};
  EXPECT_THAT(testing::ErrorMessage<ShapeError>(
                  [&] { TrackletLabels(two, 3, {{0}}, 1, kNull); }),
              HasSubstr("2 predicted labels for 1 frames of 3 points"));
  EXPECT_THAT(testing::ErrorMessage<ShapeError>([&] {
                TrackletLabels(two, 1, {{0, 0}}, 1, kNull);
              }),
              HasSubstr("2 predicted labels for 1 frames of 1 points"));
  EXPECT_THAT(testing::ErrorMessage<ShapeError>([&] {
                TrackletLabels(two, 1, {{0}, {0, 1}}, 2, kNull);
              }),
              HasSubstr("frame 1 has 2 points; expected at most 1"));
  EXPECT_THAT(testing::ErrorMessage<ShapeError>([&] {
                TrackletLabels(two, 2, {{0, 5}}, 2, kNull);
              }),
              HasSubstr("trajectory 5; expected 0 <= trajectory < 2"));
  const std::vector<int64_t> bad_label = {0, kNull + 1};
  EXPECT_THAT(testing::ErrorMessage<ShapeError>([&] {
                TrackletLabels(bad_label, 2, {{0, 1}}, 2, kNull);
              }),
              HasSubstr("predicted label 4; expected 0 <= label <= 3"));
}

}  // namespace
}  // namespace soma
