#include "framework/eval/labeling_metrics.h"

#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include <cmath>

namespace soma {
namespace {

std::vector<LabelPair> Pairs(const std::vector<std::string>& gt,
                             const std::vector<std::string>& rec) {
  std::vector<LabelPair> pairs;
  for (size_t i = 0; i < gt.size(); ++i) pairs.push_back({gt[i], rec[i]});
  return pairs;
}

// Values worked by hand (and equal to sklearn's classification_report with
// zero_division=0 for these lists).
TEST(LabelingMetrics, MicroAccuracyMacroScoresOverTheUnionOfClasses) {
  const LabelingMetrics m = ComputeLabelingMetrics(
      Pairs({"A", "A", "B", "nan"}, {"A", "B", "B", "A"}));
  EXPECT_DOUBLE_EQ(m.accuracy, 0.5);
  ASSERT_EQ(m.classes.size(), 3u);
  EXPECT_EQ(m.classes[0].label, "A");
  EXPECT_DOUBLE_EQ(m.classes[0].precision, 0.5);
  EXPECT_DOUBLE_EQ(m.classes[0].recall, 0.5);
  EXPECT_DOUBLE_EQ(m.classes[1].precision, 0.5);
  EXPECT_DOUBLE_EQ(m.classes[1].recall, 1.0);
  EXPECT_NEAR(m.classes[1].f1, 2.0 / 3.0, 1e-12);
  EXPECT_EQ(m.classes[2].label, "nan");
  EXPECT_EQ(m.classes[2].support, 1);
  EXPECT_EQ(m.classes[2].predicted, 0);
  EXPECT_DOUBLE_EQ(m.classes[2].f1, 0.0);
  EXPECT_NEAR(m.precision, 1.0 / 3.0, 1e-12);
  EXPECT_NEAR(m.recall, 0.5, 1e-12);
  EXPECT_NEAR(m.f1, (0.5 + 2.0 / 3.0) / 3.0, 1e-12);
}

TEST(LabelingMetrics, LabelPredictedButAbsentFromGroundTruthScoresZero) {
  const LabelingMetrics perfect =
      ComputeLabelingMetrics(Pairs({"A", "B"}, {"A", "B"}));
  EXPECT_DOUBLE_EQ(perfect.f1, 1.0);
  const LabelingMetrics m =
      ComputeLabelingMetrics(Pairs({"A", "B"}, {"A", "C"}));
  ASSERT_EQ(m.classes.size(), 3u);  // A, B, C
  EXPECT_DOUBLE_EQ(m.accuracy, 0.5);
  EXPECT_NEAR(m.f1, 1.0 / 3.0, 1e-12);
  EXPECT_NEAR(m.precision, 1.0 / 3.0, 1e-12);
}

TEST(LabelingMetrics, UnknownGroundTruthLabelsCanBeScoredAsNull) {
  // A labeller that knows A and B; C is a marker it was trained without.
  std::vector<LabelPair> pairs = {
      {"A", "A"}, {"C", "nan"}, {"C", "B"}, {"nan", "nan"}, {"B", "B"}};
  const std::set<std::string> unknown =
      UnknownGroundTruthLabels(pairs, {"A", "B"});
  EXPECT_EQ(unknown, (std::set<std::string>{"C"}));
  EXPECT_DOUBLE_EQ(ComputeLabelingMetrics(pairs).accuracy, 3.0 / 5.0);
  EXPECT_EQ(ScoreLabelsAsNull(unknown, &pairs), 2);
  EXPECT_EQ(pairs[1], (LabelPair{"nan", "nan"}));
  EXPECT_EQ(pairs[2], (LabelPair{"nan", "B"}));  // a ghost labelled B: wrong
  EXPECT_DOUBLE_EQ(ComputeLabelingMetrics(pairs).accuracy, 4.0 / 5.0);
  EXPECT_TRUE(UnknownGroundTruthLabels(pairs, {"A", "B"}).empty());
}

TEST(LabelingMetrics, EmptyPairsAreAnError) {
  EXPECT_THROW(ComputeLabelingMetrics({}), ShapeError);
  LabelingEvaluator evaluator;
  evaluator.AddFrame({});
  EXPECT_EQ(evaluator.num_frames(), 0);
  EXPECT_THROW(evaluator.Finish(), ShapeError);
}

TEST(MatchFrameLabels, ExactCoordinatesOccludedExcludedGhostsKept) {
  Eigen::Matrix3Xd gt(3, 4);
  gt.col(0) << 0.1, 0.2, 0.3;  // LFHD
  gt.col(1) << 0.0, 0.0, 0.0;  // occluded
  gt.col(2) << 1.0, 1.0, 1.0;  // ghost
  gt.col(3) << 0.5, NAN, 0.1;  // missing (NaN)
  const std::vector<std::string> gt_labels = {"LFHD", "RFHD", "nan", "C7"};
  Eigen::Matrix3Xd rec(3, 3);
  rec.col(0) << 1.0, 1.0, 1.0;
  rec.col(1) << 0.1, 0.2, 0.3;
  rec.col(2) << 0.1, 0.2, 0.30001;  // 1e-5 off: not a match
  const auto pairs =
      MatchFrameLabels(gt, gt_labels, rec, {"RFHD", "LFHD", "nan"});
  ASSERT_EQ(pairs.size(), 2u);
  EXPECT_EQ(pairs[0], (LabelPair{"LFHD", "LFHD"}));
  EXPECT_EQ(pairs[1], (LabelPair{"nan", "RFHD"}));
}

TEST(MatchFrameLabels, AmbiguousMatchesAreDropped) {
  Eigen::Matrix3Xd gt(3, 1);
  gt.col(0) << 0.1, 0.2, 0.3;
  Eigen::Matrix3Xd rec(3, 2);
  rec.col(0) << 0.1, 0.2, 0.3;
  rec.col(1) << 0.1, 0.2, 0.3;
  EXPECT_TRUE(MatchFrameLabels(gt, {"A"}, rec, {"A", "B"}).empty());
  EXPECT_THROW(MatchFrameLabels(gt, {"A", "B"}, rec, {"A", "B"}), ShapeError);
}

TEST(Summarize, MeanMedianPopulationStdSkippingNaN) {
  const Summary s = Summarize({1.0, 2.0, NAN, 4.0, 5.0});
  EXPECT_EQ(s.count, 4);
  EXPECT_DOUBLE_EQ(s.mean, 3.0);
  EXPECT_DOUBLE_EQ(s.median, 3.0);
  EXPECT_DOUBLE_EQ(s.std, std::sqrt(2.5));
  EXPECT_DOUBLE_EQ(Summarize({3.0, 1.0, 2.0}).median, 2.0);
  EXPECT_TRUE(std::isnan(Summarize({}).mean));
}

TEST(LabelingEvaluator, PerFrameThenPooled) {
  LabelingEvaluator evaluator;
  evaluator.AddFrame(Pairs({"A", "B"}, {"A", "B"}));  // acc 1
  evaluator.AddFrame(Pairs({"A", "B"}, {"B", "B"}));  // acc 0.5
  const auto r = evaluator.Finish();
  EXPECT_EQ(r.num_frames, 2);
  EXPECT_DOUBLE_EQ(r.accuracy.mean, 0.75);
  EXPECT_DOUBLE_EQ(r.accuracy.std, 0.25);
  EXPECT_DOUBLE_EQ(r.pooled.accuracy, 0.75);
  EXPECT_EQ(r.pooled.num_pairs, 4);
}

TEST(ConfusionMatrix, CountsAndFiles) {
  const auto pairs = Pairs({"A", "A", "nan"}, {"A", "nan", "nan"});
  const ConfusionMatrix m = ComputeConfusionMatrix(pairs);
  ASSERT_EQ(m.labels, (std::vector<std::string>{"A", "nan"}));
  EXPECT_EQ(m.counts[0][0], 1);
  EXPECT_EQ(m.counts[0][1], 1);
  EXPECT_EQ(m.counts[1][1], 1);
  const auto dir = testing::CreateTestDir();
  WriteConfusionMatrixCsv(m, dir / "c.csv");
  EXPECT_EQ(ReadFile(dir / "c.csv"), "gt\\rec,A,nan\nA,1,1\nnan,0,1\n");
  WriteConfusionMatrixPng(m, dir / "c.png");
  EXPECT_EQ(ReadFile(dir / "c.png").substr(1, 3), "PNG");
  WriteClassReportCsv(ComputeLabelingMetrics(pairs), dir / "r.csv");
  EXPECT_NE(ReadFile(dir / "r.csv").find("macro avg,"), std::string::npos);
}

}  // namespace
}  // namespace soma
