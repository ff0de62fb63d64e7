#include "framework/eval/calibration.h"

#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/random.h"
#include "framework/testing/testing.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <numeric>

namespace soma {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

constexpr double kTol = 1e-12;

/// Samples whose labels are drawn from softmax(z / true_temperature) while
/// the "model" reports log_softmax(z): an over-confident model when
/// true_temperature > 1. Returns the model's log-probabilities.
std::vector<float> SyntheticLogits(int samples,
                                   int cols,
                                   double true_temperature,
                                   uint64_t seed,
                                   std::vector<int>* targets) {
  Rng rng(seed);
  std::vector<float> log_probs(static_cast<size_t>(samples) * cols);
  targets->resize(samples);
  std::vector<double> z(cols), p(cols);
  for (int i = 0; i < samples; ++i) {
    for (int c = 0; c < cols; ++c) z[c] = rng.Normal(0.0, 4.0);
    const double max_z = *std::max_element(z.begin(), z.end());
    double sum = 0, sum_t = 0;
    for (int c = 0; c < cols; ++c) {
      sum += std::exp(z[c] - max_z);
      p[c] = std::exp((z[c] - max_z) / true_temperature);
      sum_t += p[c];
    }
    for (int c = 0; c < cols; ++c) {
      log_probs[static_cast<size_t>(i) * cols + c] =
          static_cast<float>(z[c] - max_z - std::log(sum));
    }
    double u = rng.Uniform() * sum_t;
    int target = cols - 1;
    for (int c = 0; c < cols; ++c) {
      if ((u -= p[c]) < 0) {
        target = c;
        break;
      }
    }
    (*targets)[i] = target;
  }
  return log_probs;
}

TEST(Calibration, FitRecoversTheTemperatureOfSyntheticLogits) {
  for (const double true_t : {0.5, 1.0, 2.0, 3.0}) {
    std::vector<int> targets;
    const std::vector<float> log_probs =
        SyntheticLogits(20000, 12, true_t, 7, &targets);
    const TemperatureFit fit = FitTemperature(log_probs, targets, 12);
    EXPECT_NEAR(fit.temperature, true_t, 0.05 * true_t) << "T = " << true_t;
    EXPECT_LE(fit.nll_after, fit.nll_before + 1e-9);
    EXPECT_FALSE(fit.at_bound);
    EXPECT_EQ(fit.samples, 20000);
    // The optimum: nearby temperatures are no better.
    EXPECT_LE(fit.nll_after,
              MeanNll(log_probs, targets, 12, fit.temperature * 1.05));
    EXPECT_LE(fit.nll_after,
              MeanNll(log_probs, targets, 12, fit.temperature / 1.05));
  }
}

TEST(Calibration, FitByEceFindsTheTemperatureOfAReliabilityDiagram) {
  for (const double true_t : {0.5, 2.0}) {
    std::vector<int> targets;
    const std::vector<float> log_probs =
        SyntheticLogits(20000, 12, true_t, 11, &targets);
    // The chosen label: each row's argmax.
    std::vector<int> chosen(targets.size());
    for (size_t i = 0; i < targets.size(); ++i) {
      const float* row = log_probs.data() + i * 12;
      chosen[i] = static_cast<int>(std::max_element(row, row + 12) - row);
    }
    const auto ece_at = [&](double t) {
      std::vector<double> confidence(targets.size());
      std::vector<bool> correct(targets.size());
      std::vector<float> row(12);
      for (size_t i = 0; i < targets.size(); ++i) {
        for (int c = 0; c < 12; ++c) row[c] = std::exp(log_probs[i * 12 + c]);
        ApplyTemperature(row.data(), 1, 12, t);
        confidence[i] = row[chosen[i]];
        correct[i] = chosen[i] == targets[i];
      }
      return ComputeReliability(confidence, correct, 15).ece;
    };
    const TemperatureFit fit =
        FitTemperatureByEce(log_probs, targets, chosen, 12, 15);
    EXPECT_NEAR(fit.temperature, true_t, 0.1 * true_t) << "T = " << true_t;
    EXPECT_FALSE(fit.at_bound);
    EXPECT_EQ(fit.samples, 20000);
    EXPECT_DOUBLE_EQ(fit.nll_after,
                     MeanNll(log_probs, targets, 12, fit.temperature));
    // No better ECE on either side, nor at T = 1.
    const double best = ece_at(fit.temperature);
    EXPECT_LT(best, ece_at(1.0) / 2);  // the model is miscalibrated at T = 1
    EXPECT_LE(best, ece_at(fit.temperature * 1.05) + 1e-12);
    EXPECT_LE(best, ece_at(fit.temperature / 1.05) + 1e-12);
  }
  // A chosen column out of range.
  std::vector<int> targets;
  const std::vector<float> log_probs = SyntheticLogits(10, 4, 1.0, 3, &targets);
  std::vector<int> chosen(10, 0);
  chosen[4] = 4;
  EXPECT_THROW(FitTemperatureByEce(log_probs, targets, chosen, 4, 15),
               ShapeError);
}

TEST(Calibration, MeanNllByHand) {
  // One sample, p = (0.5, 0.25, 0.25), target 1: NLL log 4 at T = 1; at
  // T = 0.5 the row becomes (1/4, 1/16, 1/16) / (6/16) -> p1 = 1/6.
  const std::vector<float> lp = {static_cast<float>(std::log(0.5)),
                                 static_cast<float>(std::log(0.25)),
                                 static_cast<float>(std::log(0.25))};
  EXPECT_NEAR(MeanNll(lp, {1}, 3, 1.0), std::log(4.0), 1e-6);
  EXPECT_NEAR(MeanNll(lp, {1}, 3, 0.5), std::log(6.0), 1e-6);
  EXPECT_THROW(MeanNll(lp, {3}, 3, 1.0), ShapeError);
  EXPECT_THROW(MeanNll(lp, {1, 1}, 3, 1.0), ShapeError);
  EXPECT_THROW(FitTemperature({}, {}, 3), ShapeError);
}

TEST(Calibration, ApplyTemperatureKeepsTheArgmaxAndMatchesTheFit) {
  std::vector<float> probs = {0.7f, 0.2f, 0.1f, 0.0f, 0.1f, 0.9f};
  std::vector<float> t1 = probs;
  ApplyTemperature(t1.data(), 2, 3, 1.0);
  for (size_t i = 0; i < probs.size(); ++i) EXPECT_NEAR(t1[i], probs[i], 1e-6);
  std::vector<float> t2 = probs;
  ApplyTemperature(t2.data(), 2, 3, 2.0);
  // sqrt(p) renormalised: argmax kept, the top probability lowered.
  const double s = std::sqrt(0.7) + std::sqrt(0.2) + std::sqrt(0.1);
  EXPECT_NEAR(t2[0], std::sqrt(0.7) / s, 1e-6);
  EXPECT_LT(t2[0], 0.7f);
  EXPECT_GT(t2[5], t2[4]);
  EXPECT_NEAR(t2[3] + t2[4] + t2[5], 1.0, 1e-6);
  // The same transform MeanNll scores.
  const std::vector<float> lp = {static_cast<float>(std::log(0.7)),
                                 static_cast<float>(std::log(0.2)),
                                 static_cast<float>(std::log(0.1))};
  EXPECT_NEAR(MeanNll(lp, {0}, 3, 2.0), -std::log(t2[0]), 1e-6);
  EXPECT_THROW(ApplyTemperature(t2.data(), 2, 3, 0.0), ConfigError);
}

TEST(Calibration, ReliabilityAndEceOfConstructedBins) {
  // 10 bins. Bin [0.9, 1.0]: four predictions at 0.95, three correct
  // (acc 0.75, gap 0.2). Bin [0.6, 0.7): four at 0.65, all correct (gap
  // 0.35). ECE = 4/8 * 0.2 + 4/8 * 0.35 = 0.275; MCE = 0.35.
  std::vector<double> conf = {0.95, 0.95, 0.95, 0.95, 0.65, 0.65, 0.65, 0.65};
  std::vector<bool> ok = {true, true, true, false, true, true, true, true};
  const Reliability r = ComputeReliability(conf, ok, 10);
  ASSERT_EQ(r.bins.size(), 10u);
  EXPECT_EQ(r.count, 8);
  EXPECT_EQ(r.bins[9].count, 4);
  EXPECT_NEAR(r.bins[9].accuracy, 0.75, kTol);
  EXPECT_NEAR(r.bins[9].mean_confidence, 0.95, kTol);
  EXPECT_EQ(r.bins[6].count, 4);
  EXPECT_TRUE(std::isnan(r.bins[0].accuracy));
  EXPECT_NEAR(r.ece, 0.275, kTol);
  EXPECT_NEAR(r.mce, 0.35, kTol);
  EXPECT_NEAR(r.accuracy, 7.0 / 8.0, kTol);
  // Confidence 1 goes into the last bin; a bin whose accuracy equals its
  // mean confidence adds nothing (mean 0.75, 3 of 4 right).
  const Reliability perfect =
      ComputeReliability({1.0, 1.0, 0.5, 0.5}, {true, true, true, false}, 2);
  EXPECT_EQ(perfect.bins[1].count, 4);  // [0.5, 1]
  EXPECT_NEAR(perfect.ece, 0.0, kTol);
  EXPECT_THROW(ComputeReliability({0.5}, {}, 10), ShapeError);
}

TEST(Calibration, PrecisionCoverageCurveAndCoverageAtPrecision) {
  // Confidences 0.99 .. 0.90 (10 predictions); the two lowest are wrong.
  std::vector<ThresholdedPrediction> preds;
  preds.reserve(10);
  for (int i = 0; i < 10; ++i) preds.push_back({0.99 - 0.01 * i, i < 8});
  const std::vector<CoveragePoint> curve =
      PrecisionCoverageCurve(preds, {0.0, 0.915, 0.95, 1.0});
  ASSERT_EQ(curve.size(), 4u);
  EXPECT_EQ(curve[0].kept, 10);
  EXPECT_NEAR(curve[0].precision, 0.8, kTol);
  EXPECT_NEAR(curve[0].coverage, 1.0, kTol);
  EXPECT_EQ(curve[1].kept, 8);  // 0.92 and above
  EXPECT_NEAR(curve[1].precision, 1.0, kTol);
  EXPECT_NEAR(curve[2].coverage, 0.5, kTol);  // 0.95 .. 0.99
  EXPECT_EQ(curve[3].kept, 0);
  EXPECT_NEAR(curve[3].precision, 1.0, kTol);
  const CoveragePoint at = CoverageAtPrecision(preds, 0.995);
  EXPECT_EQ(at.kept, 8);
  EXPECT_NEAR(at.coverage, 0.8, kTol);
  EXPECT_NEAR(at.threshold, 0.92, 1e-9);
  // Ties are kept or dropped together: a wrong one tied with the best.
  const CoveragePoint none =
      CoverageAtPrecision({{0.9, true}, {0.9, false}}, 0.995);
  EXPECT_EQ(none.kept, 0);
  EXPECT_TRUE(std::isinf(none.threshold));
  const std::vector<double> thresholds = DefaultThresholds();
  EXPECT_TRUE(std::is_sorted(thresholds.begin(), thresholds.end()));
  EXPECT_DOUBLE_EQ(thresholds.front(), 0.0);
  EXPECT_DOUBLE_EQ(thresholds.back(), 0.9999);
}

TEST(Calibration, LowConfidenceRangesAreContiguousPerLabel) {
  // 6 frames x 2 points, 3 labels (null = 3), threshold 0.5.
  // Label 0 low on frames 1-2 and 4; label 2 low on frame 5; label 1 never
  // low; null and padding (-1) points never listed.
  const std::vector<int> labels = {0, 1, 0, 1, 0, 3, 0, -1, 0, 2, 1, 2};
  const std::vector<float> conf = {
      .9f, .9f, .4f, .8f, .3f, .1f, .6f, .0f, .45f, .7f, .9f, .2f};
  const std::vector<ReviewRange> ranges =
      LowConfidenceRanges(labels, conf, 6, 2, 3, 0.5);
  ASSERT_EQ(ranges.size(), 3u);
  EXPECT_EQ(ranges[0], (ReviewRange{0, 1, 2, 2, 0.30000001192092896}));
  EXPECT_EQ(ranges[1].label, 0);
  EXPECT_EQ(ranges[1].first_frame, 4);
  EXPECT_EQ(ranges[1].last_frame, 4);
  EXPECT_NEAR(ranges[1].min_confidence, 0.45, 1e-6);
  EXPECT_EQ(ranges[2].label, 2);
  EXPECT_EQ(ranges[2].first_frame, 5);
  EXPECT_EQ(ranges[2].last_frame, 5);
  EXPECT_TRUE(LowConfidenceRanges(labels, conf, 6, 2, 3, 0.0).empty());
  // A gap of one frame (frame 3) merges label 0's two ranges.
  const std::vector<ReviewRange> merged =
      LowConfidenceRanges(labels, conf, 6, 2, 3, 0.5, /*max_gap=*/1);
  ASSERT_EQ(merged.size(), 2u);
  EXPECT_EQ(merged[0].label, 0);
  EXPECT_EQ(merged[0].first_frame, 1);
  EXPECT_EQ(merged[0].last_frame, 4);
  EXPECT_EQ(merged[0].low_frames, 3);
  EXPECT_NEAR(merged[0].min_confidence, 0.3, 1e-6);
  EXPECT_EQ(merged[1].label, 2);
  EXPECT_THROW(LowConfidenceRanges(labels, conf, 5, 2, 3, 0.5), ShapeError);
}

TEST(Calibration, FileRoundTripAndCheckpointMatching) {
  const fs::path dir = testing::CreateTestDir();
  const fs::path checkpoint = dir / "model.pt";
  WriteFileAtomic(checkpoint, "weights v1");
  // Nothing beside the checkpoint: T = 1.
  CalibrationChoice none = ResolveCalibration("auto", checkpoint);
  EXPECT_DOUBLE_EQ(none.temperature, 1.0);
  EXPECT_TRUE(none.file.empty());

  TemperatureCalibration c;
  c.temperature = 1.7;
  c.checkpoint = "model.pt";
  c.checkpoint_fnv1a64 = FileFingerprint(checkpoint);
  c.fitted_on = "2000 synthetic validation frames";
  c.frames = 2000;
  c.points = 90000;
  c.nll_before = 0.3;
  c.nll_after = 0.2;
  c.command = "soma calibrate: with 'quotes' and # hash";
  WriteCalibration(dir / kCalibrationFileName, c);
  const TemperatureCalibration back =
      ReadCalibration(dir / kCalibrationFileName);
  EXPECT_DOUBLE_EQ(back.temperature, 1.7);
  EXPECT_EQ(back.checkpoint_fnv1a64, c.checkpoint_fnv1a64);
  EXPECT_EQ(back.command, c.command);
  EXPECT_EQ(back.frames, 2000);

  const CalibrationChoice found = ResolveCalibration("auto", checkpoint);
  EXPECT_DOUBLE_EQ(found.temperature, 1.7);
  EXPECT_EQ(found.file, dir / kCalibrationFileName);
  EXPECT_DOUBLE_EQ(ResolveCalibration("none", checkpoint).temperature, 1.0);
  EXPECT_DOUBLE_EQ(
      ResolveCalibration((dir / kCalibrationFileName).string(), checkpoint)
          .temperature,
      1.7);

  // Other weights: auto ignores the file and says why; a path is an error.
  WriteFileAtomic(checkpoint, "weights v2");
  const CalibrationChoice stale = ResolveCalibration("auto", checkpoint);
  EXPECT_DOUBLE_EQ(stale.temperature, 1.0);
  EXPECT_THAT(stale.reason, HasSubstr("fitted for another checkpoint"));
  try {
    ResolveCalibration((dir / kCalibrationFileName).string(), checkpoint);
    FAIL() << "expected ConfigError";
  } catch (const ConfigError& e) {
    EXPECT_THAT(e.what(), HasSubstr("task.calibration="));
    EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos);
  }
  EXPECT_THROW(ResolveCalibration((dir / "nope.yaml").string(), checkpoint),
               ConfigError);
}

}  // namespace
}  // namespace soma
