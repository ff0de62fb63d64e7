// ReduceLROnPlateau, warm-up + cosine and early stopping against hand-computed
// sequences (PyTorch / Lightning semantics, REFERENCE 2.4), their state round
// trip, and the labelling metrics (REFERENCE 4.2).
#include "framework/train/schedule.h"

#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/train/metrics.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <vector>

namespace soma {
namespace {

constexpr double kTol = 1e-12;

std::vector<double> RunPlateau(ReduceLrOnPlateau& scheduler,
                               const std::vector<double>& metrics,
                               double lr) {
  std::vector<double> lrs;
  for (double m : metrics) {
    lr = scheduler.Step(m, lr);
    lrs.push_back(lr);
  }
  return lrs;
}

TEST(ReduceLrOnPlateau, PatienceThreeFactorTenth) {
  ReduceLrOnPlateau scheduler;  // patience 3, factor 0.1, threshold 1e-4 rel
  // 9 improves on 10; 8.9995 is not below 9 * (1 - 1e-4) = 8.9991, so epochs
  // 3..6 are bad (1, 2, 3, 4 > 3): reduce after epoch 6; then 4 more bad
  // epochs reduce again after epoch 10; 5 is better and resets.
  const std::vector<double> metrics = {
      10, 9, 9, 8.9995, 9, 9, 9, 9, 9, 9, 5, 5};
  const std::vector<double> expected = {
      1, 1, 1, 1, 1, 0.1, 0.1, 0.1, 0.1, 0.01, 0.01, 0.01};
  const std::vector<double> lrs = RunPlateau(scheduler, metrics, 1.0);
  ASSERT_EQ(lrs.size(), expected.size());
  for (size_t i = 0; i < lrs.size(); ++i) {
    EXPECT_NEAR(lrs[i], expected[i], kTol) << "epoch " << i + 1;
  }
  EXPECT_EQ(scheduler.best(), 5);
  EXPECT_EQ(scheduler.num_bad_epochs(), 1);
}

TEST(ReduceLrOnPlateau, CooldownAndMinLr) {
  PlateauOptions options;
  options.patience = 1;
  options.cooldown = 2;
  options.min_lr = 0.05;
  ReduceLrOnPlateau scheduler(options);
  // Constant metric: bad counts 0,1,2->reduce (cooldown 2), cooldown eats
  // epochs 4 and 5, then 1, 2->reduce at epoch 7 (clamped to min_lr), and
  // the next reduction changes nothing.
  const std::vector<double> lrs =
      RunPlateau(scheduler, std::vector<double>(11, 5.0), 1.0);
  const std::vector<double> expected = {
      1, 1, 0.1, 0.1, 0.1, 0.1, 0.05, 0.05, 0.05, 0.05, 0.05};
  for (size_t i = 0; i < lrs.size(); ++i) {
    EXPECT_NEAR(lrs[i], expected[i], kTol) << "epoch " << i + 1;
  }
}

TEST(ReduceLrOnPlateau, NanIsABadEpoch) {
  ReduceLrOnPlateau scheduler;
  double lr = 1;
  lr = scheduler.Step(1.0, lr);
  for (int i = 0; i < 4; ++i) {
    lr = scheduler.Step(std::numeric_limits<double>::quiet_NaN(), lr);
  }
  EXPECT_NEAR(lr, 0.1, kTol);
}

TEST(ReduceLrOnPlateau, StateRoundTripContinuesIdentically) {
  const std::vector<double> metrics = {3, 2.5, 2.6, 2.7, 2.8, 2.9, 2.0, 2.1};
  ReduceLrOnPlateau a;
  const std::vector<double> full = RunPlateau(a, metrics, 1e-3);
  ReduceLrOnPlateau b;
  std::vector<double> first(metrics.begin(), metrics.begin() + 4);
  std::vector<double> rest(metrics.begin() + 4, metrics.end());
  const std::vector<double> head = RunPlateau(b, first, 1e-3);
  ReduceLrOnPlateau c;
  c.LoadState(b.SaveState());
  const std::vector<double> tail = RunPlateau(c, rest, head.back());
  for (size_t i = 0; i < rest.size(); ++i) {
    EXPECT_EQ(tail[i], full[4 + i]);
  }
  EXPECT_EQ(c.SaveState(), a.SaveState());
  EXPECT_THROW(c.LoadState("best=1\n"), InternalError);
}

TEST(PlateauOptions, RejectsBadFactor) {
  PlateauOptions options;
  options.factor = 1.5;
  EXPECT_THROW(ReduceLrOnPlateau{options}, ConfigError);
}

TEST(WarmupCosineLr, RampsThenFollowsAHalfCosineToTheFinalFactor) {
  CosineOptions options;
  options.warmup_steps = 4;
  options.final_factor = 0.1;
  const WarmupCosineLr schedule(options);
  const int64_t total = 24;
  const double lr = 2e-3;
  EXPECT_NEAR(schedule.StepLr(0, total, lr), lr / 4, kTol);
  EXPECT_NEAR(schedule.StepLr(1, total, lr), lr / 2, kTol);
  EXPECT_NEAR(schedule.StepLr(3, total, lr), lr, kTol);
  EXPECT_NEAR(schedule.StepLr(4, total, lr), lr, kTol);  // cosine at 0
  // Half way through the decay: the mean of lr and final_factor * lr.
  EXPECT_NEAR(schedule.StepLr(14, total, lr), lr * 0.55, kTol);
  EXPECT_NEAR(schedule.StepLr(total, total, lr), lr * 0.1, kTol);
  EXPECT_NEAR(schedule.StepLr(total + 5, total, lr), lr * 0.1, kTol);
  for (int64_t s = 4; s < total; ++s) {
    EXPECT_LT(schedule.StepLr(s + 1, total, lr), schedule.StepLr(s, total, lr))
        << "step " << s;
  }
  // Epoch ends leave the rate to the per-step schedule.
  WarmupCosineLr stepped(options);
  EXPECT_EQ(stepped.Step(1.0, lr), lr);
  // No warm-up: the first step runs at the full rate.
  EXPECT_NEAR(
      WarmupCosineLr(CosineOptions{0, 0.0}).StepLr(0, 10, lr), lr, kTol);
}

TEST(WarmupCosineLr, RejectsBadOptions) {
  EXPECT_THROW(WarmupCosineLr(CosineOptions{-1, 0.1}), ConfigError);
  EXPECT_THROW(WarmupCosineLr(CosineOptions{10, 1.5}), ConfigError);
  EXPECT_THROW(DecodeCosineOptions(ParseYaml("warmup: 3\n", "t")), ConfigError);
  const CosineOptions decoded = DecodeCosineOptions(
      ParseYaml("warmup_steps: 7\nfinal_factor: 0.5\n", "t"));
  EXPECT_EQ(decoded.warmup_steps, 7);
  EXPECT_EQ(decoded.final_factor, 0.5);
}

TEST(ConstantLr, KeepsTheRateAtEveryStep) {
  ConstantLr constant;
  EXPECT_EQ(constant.StepLr(5, 10, 0.25), 0.25);
  EXPECT_EQ(constant.Step(1.0, 0.25), 0.25);
}

TEST(EarlyStopping, PatienceCountsEpochsWithoutImprovement) {
  EarlyStoppingOptions options;
  options.patience = 3;
  EarlyStopping stopping(options);
  // 4 == best is not an improvement (min_delta 0, strict).
  EXPECT_FALSE(stopping.Update(5));
  EXPECT_FALSE(stopping.Update(4));
  EXPECT_FALSE(stopping.Update(4));
  EXPECT_FALSE(stopping.Update(4.5));
  EXPECT_EQ(stopping.wait_count(), 2);
  EXPECT_TRUE(stopping.Update(4));
  EXPECT_EQ(stopping.best(), 4);
  EXPECT_FALSE(stopping.reason().empty());
}

TEST(EarlyStopping, ImprovementResetsAndMinDelta) {
  EarlyStoppingOptions options;
  options.patience = 2;
  options.min_delta = 0.5;
  EarlyStopping stopping(options);
  EXPECT_FALSE(stopping.Update(10));
  EXPECT_FALSE(stopping.Update(9.6));  // not < 10 - 0.5
  EXPECT_FALSE(stopping.Update(9.0));  // improvement: reset
  EXPECT_EQ(stopping.wait_count(), 0);
  EXPECT_FALSE(stopping.Update(8.9));
  EXPECT_TRUE(stopping.Update(8.8));
}

TEST(EarlyStopping, DefaultPatienceEightAndNonFinite) {
  EarlyStopping stopping;  // patience 8
  EXPECT_FALSE(stopping.Update(1.0));
  for (int i = 0; i < 7; ++i) EXPECT_FALSE(stopping.Update(1.0));
  EXPECT_TRUE(stopping.Update(1.0));

  EarlyStopping nan_stop;
  EXPECT_FALSE(nan_stop.Update(1.0));
  EXPECT_TRUE(nan_stop.Update(std::numeric_limits<double>::infinity()));
  EXPECT_NE(nan_stop.reason().find("not finite"), std::string::npos);
}

TEST(EarlyStopping, StateRoundTrip) {
  EarlyStopping a;
  a.Update(3);
  a.Update(4);
  EarlyStopping b;
  b.LoadState(a.SaveState());
  EXPECT_EQ(b.best(), 3);
  EXPECT_EQ(b.wait_count(), 1);
  EXPECT_EQ(b.SaveState(), a.SaveState());
}

TEST(ScoreLabels, AccuracyAndMacroF1) {
  // L = 3 (null = 3). Pairs (gt, pred): (0,0) (1,1) (2,0) (3,3) (3,1); the
  // last point is invalid (a zero point) and ignored.
  const std::vector<int64_t> gt = {0, 1, 2, 3, 3, 0};
  const std::vector<int64_t> pred = {0, 1, 0, 3, 1, 2};
  const bool valid[] = {true, true, true, true, true, false};
  const LabelingScore s = ScoreLabels(gt.data(), pred.data(), valid, 6, 3);
  EXPECT_EQ(s.num_pairs, 5);
  EXPECT_NEAR(s.accuracy, 3.0 / 5.0, kTol);
  // Class 0: tp1 fp1 fn0 -> 2/3; class 1: tp1 fp1 fn0 -> 2/3; class 2: tp0
  // fn1 -> 0; class 3 (null): tp1 fn1 -> 2/3. Macro over 4 classes.
  EXPECT_NEAR(s.f1, (2.0 / 3 + 2.0 / 3 + 0 + 2.0 / 3) / 4, kTol);
}

TEST(LabelingMetrics, BatchPooledAndPerFrame) {
  // Two frames of 2 points, L = 2: frame 0 all correct, frame 1 half.
  const std::vector<int64_t> gt = {0, 1, 0, 2};
  const std::vector<int64_t> pred = {0, 1, 1, 2};
  const bool valid[] = {true, true, true, true};
  LabelingMetrics metrics(2);
  metrics.AddBatch(gt.data(), pred.data(), valid, 2, 2);
  EXPECT_NEAR(metrics.batch_accuracy(), 0.75, kTol);
  EXPECT_NEAR(metrics.frame_accuracy(), 0.75, kTol);
  // Frame 1: classes {0, 1, 2}: F1 0, 0, 1 -> 1/3; frame 0 -> 1.
  EXPECT_NEAR(metrics.frame_f1(), (1.0 + 1.0 / 3) / 2, kTol);
  // Pooled: class 0 tp1 fn1 -> 2/3; class 1 tp1 fp1 -> 2/3; class 2 -> 1.
  EXPECT_NEAR(metrics.batch_f1(), (2.0 / 3 + 2.0 / 3 + 1) / 3, kTol);
}

}  // namespace
}  // namespace soma
