#include "framework/eval/body_metrics.h"

#include "framework/core/error.h"
#include "framework/core/random.h"
#include "framework/motion/procedural_motion.h"
#include "framework/solve/marker_model.h"
#include "framework/testing/body_fixture.h"
#include "framework/testing/testing.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <sstream>
#include <string>
#include <vector>

namespace soma {
namespace {

using ::soma::testing::ErrorMessage;
using ::soma::testing::ProceduralBody;
using ::testing::HasSubstr;

constexpr double kTol = 1e-9;  // mm
constexpr int kFrames = 6;

/// A fit of a shaped procedural body following a procedural walk; every
/// frame converged.
SolveOutput MakeFit(int num_frames = kFrames) {
  const BodyModel& body = ProceduralBody();
  Rng rng(7);
  SolveOutput fit;
  fit.body = body.name;
  fit.joint_names = body.joint_names;
  fit.frame_rate = 120.0;
  fit.betas.resize(body.num_betas());
  for (int b = 0; b < body.num_betas(); ++b) fit.betas(b) = 0.8 * rng.Normal();
  Rng clip_rng = rng.Stream("clip");
  const PoseSequence clip = GenerateProceduralMotion(
      "walk", body, ProceduralMotionOptions{}, clip_rng);
  for (int t = 0; t < num_frames; ++t) {
    fit.frame_params.push_back(PackFrameParams(clip.frames.at(t)));
    SolveSummary summary;
    summary.frame = t;
    summary.termination = SolveTermination::kConverged;
    fit.summaries.push_back(summary);
  }
  return fit;
}

/// Marks frame `t` of `fit` as not solved (as the solver writes such a
/// frame: NaN parameters).
void Unsolve(SolveOutput* fit, int t, SolveTermination termination) {
  fit->frame_params[t].setConstant(std::nan(""));
  fit->summaries[t].termination = termination;
}

/// Joints below `joint` in the kinematic tree (not `joint` itself).
std::vector<int> Descendants(const BodyModel& body, int joint) {
  std::vector<int> out;
  for (int j = 0; j < body.num_joints(); ++j) {
    for (int p = body.parents[j]; p >= 0; p = body.parents[p]) {
      if (p == joint) {
        out.push_back(j);
        break;
      }
    }
  }
  return out;
}

TEST(BodyMetrics, IdenticalFitsScoreZeroAndFullPck) {
  const SolveOutput fit = MakeFit();
  const BodyMetrics m = ComputeBodyMetrics(ProceduralBody(), fit, fit);
  EXPECT_EQ(m.frames_total, kFrames);
  EXPECT_EQ(m.frames_compared, kFrames);
  EXPECT_EQ(m.frames_excluded, 0);
  EXPECT_TRUE(m.excluded_by_reason.empty());
  EXPECT_EQ(m.v2v_mm, 0.0);
  EXPECT_EQ(m.joint_err_mm, 0.0);
  EXPECT_EQ(m.max_v2v_mm, 0.0);
  EXPECT_EQ(m.pck_thresholds_mm, (std::vector<double>{10.0, 30.0, 70.0}));
  EXPECT_EQ(m.pck, (std::vector<double>{100.0, 100.0, 100.0}));
  for (const BodyFrameMetrics& f : m.frames) {
    EXPECT_TRUE(f.compared());
    EXPECT_EQ(f.max_joint_err_mm, 0.0);
  }
}

TEST(BodyMetrics, TranslationOffsetIsTheErrorOfEveryVertexAndJoint) {
  const SolveOutput reference = MakeFit();
  const Eigen::Vector3d direction =
      Eigen::Vector3d(1.0, -2.0, 0.5).normalized();
  for (const double d_mm : {5.0, 20.0, 50.0, 100.0}) {
    SCOPED_TRACE(d_mm);
    SolveOutput candidate = reference;
    for (Eigen::VectorXd& p : candidate.frame_params) {
      p.head<3>() += 1e-3 * d_mm * direction;
    }
    const BodyMetrics m =
        ComputeBodyMetrics(ProceduralBody(), reference, candidate);
    ASSERT_EQ(m.frames_compared, kFrames);
    EXPECT_NEAR(m.v2v_mm, d_mm, kTol);
    EXPECT_NEAR(m.joint_err_mm, d_mm, kTol);
    EXPECT_NEAR(m.max_v2v_mm, d_mm, kTol);
    // PCK: every joint is d away, so all or none are within a threshold.
    ASSERT_EQ(m.pck.size(), 3u);
    EXPECT_EQ(m.pck[0], d_mm < 10.0 ? 100.0 : 0.0);
    EXPECT_EQ(m.pck[1], d_mm < 30.0 ? 100.0 : 0.0);
    EXPECT_EQ(m.pck[2], d_mm < 70.0 ? 100.0 : 0.0);
    for (const BodyFrameMetrics& f : m.frames) {
      EXPECT_NEAR(f.v2v_mm, d_mm, kTol);
      EXPECT_NEAR(f.max_joint_err_mm, d_mm, kTol);
    }
  }
}

TEST(BodyMetrics, RotatedJointMovesOnlyItsDescendants) {
  const BodyModel& body = ProceduralBody();
  const SolveOutput reference = MakeFit();
  SolveOutput candidate = reference;
  for (Eigen::VectorXd& p : candidate.frame_params) {
    p.segment<3>(3 + 3 * kLeftElbow) += Eigen::Vector3d(0.1, 0.2, 0.4);
  }
  const std::vector<int> moved = Descendants(body, kLeftElbow);
  ASSERT_FALSE(moved.empty());  // wrist and hand
  // A threshold far below any real motion counts the joints that stayed.
  BodyMetricsOptions options;
  options.pck_thresholds_mm = {1e-6, 1e4};
  const BodyMetrics m = ComputeBodyMetrics(body, reference, candidate, options);
  ASSERT_EQ(m.frames_compared, kFrames);
  EXPECT_GT(m.joint_err_mm, 1.0);
  EXPECT_GT(m.v2v_mm, 0.1);
  const double unmoved = body.num_joints() - static_cast<double>(moved.size());
  EXPECT_NEAR(m.pck[0], 100.0 * unmoved / body.num_joints(), kTol);
  EXPECT_EQ(m.pck[1], 100.0);
  // The mean joint error is the moved joints' error spread over all joints.
  for (const BodyFrameMetrics& f : m.frames) {
    EXPECT_GT(f.max_joint_err_mm, 10.0);
    EXPECT_LE(f.joint_err_mm,
              f.max_joint_err_mm * moved.size() / body.num_joints() + kTol);
  }

  // The same rotation on the root joint moves every joint but the root.
  SolveOutput turned = reference;
  for (Eigen::VectorXd& p : turned.frame_params) {
    p.segment<3>(3 + 3 * kPelvis) += Eigen::Vector3d(0.3, 0.2, 0.1);
  }
  const BodyMetrics root = ComputeBodyMetrics(body, reference, turned, options);
  EXPECT_NEAR(root.pck[0], 100.0 / body.num_joints(), kTol);
}

TEST(BodyMetrics, UnsolvedFramesAreExcludedAndCounted) {
  const SolveOutput base = MakeFit();
  SolveOutput reference = base;
  SolveOutput candidate = base;
  for (Eigen::VectorXd& p : candidate.frame_params) p(2) += 0.02;  // 20 mm
  Unsolve(&reference, 1, SolveTermination::kSkipped);
  Unsolve(&candidate, 2, SolveTermination::kFailure);
  Unsolve(&reference, 3, SolveTermination::kSkipped);
  Unsolve(&candidate, 3, SolveTermination::kSkipped);
  // Reported usable but with non-finite parameters: not compared either.
  candidate.frame_params[4](7) = std::nan("");
  const BodyMetrics m =
      ComputeBodyMetrics(ProceduralBody(), reference, candidate);
  EXPECT_EQ(m.frames_total, kFrames);
  EXPECT_EQ(m.frames_compared, 2);
  EXPECT_EQ(m.frames_excluded, 4);
  EXPECT_EQ(
      m.excluded_by_reason,
      (std::map<std::string, int>{{"reference_skipped", 1},
                                  {"candidate_failed", 1},
                                  {"reference_skipped+candidate_skipped", 1},
                                  {"candidate_non_finite", 1}}));
  EXPECT_NEAR(m.v2v_mm, 20.0, kTol);
  EXPECT_NEAR(m.joint_err_mm, 20.0, kTol);
  EXPECT_EQ(m.pck, (std::vector<double>{0.0, 100.0, 100.0}));
  EXPECT_TRUE(m.frames[0].compared());
  EXPECT_TRUE(m.frames[5].compared());
  EXPECT_TRUE(std::isnan(m.frames[1].v2v_mm));
  EXPECT_THAT(
      m.BriefReport(),
      HasSubstr("2/6 frames compared (4 excluded: "
                "candidate_failed 1, candidate_non_finite 1, "
                "reference_skipped 1, "
                "reference_skipped+candidate_skipped 1), V2V 20.00 mm"));

  const std::string csv = BodyMetricsToCsv(m);
  std::istringstream lines(csv);
  std::string line;
  std::vector<std::string> rows;
  while (std::getline(lines, line)) rows.push_back(line);
  ASSERT_EQ(rows.size(), 1u + kFrames);
  EXPECT_EQ(rows[0],
            "frame,compared,excluded_reason,v2v_mm,joint_err_mm,"
            "max_joint_err_mm,pck10,pck30,pck70");
  EXPECT_EQ(rows[1],
            "0,1,,20.000000,20.000000,20.000000,0.0000,100.0000,100.0000");
  EXPECT_EQ(rows[2], "1,0,reference_skipped,,,,,,");
  EXPECT_EQ(rows[4], "3,0,reference_skipped+candidate_skipped,,,,,,");

  // Nothing in common: the means are NaN, not zero.
  SolveOutput none = candidate;
  for (int t = 0; t < kFrames; ++t) {
    Unsolve(&none, t, SolveTermination::kSkipped);
  }
  const BodyMetrics empty = ComputeBodyMetrics(ProceduralBody(), base, none);
  EXPECT_EQ(empty.frames_compared, 0);
  EXPECT_TRUE(std::isnan(empty.v2v_mm));
  EXPECT_TRUE(std::isnan(empty.pck[0]));
}

TEST(BodyMetrics, FitsThatDoNotBelongTogetherThrow) {
  const BodyModel& body = ProceduralBody();
  const SolveOutput reference = MakeFit();

  const SolveOutput shorter = MakeFit(kFrames - 1);
  EXPECT_THAT(ErrorMessage<ShapeError>(
                  [&] { ComputeBodyMetrics(body, reference, shorter); }),
              HasSubstr("the reference fit has 6 frames, the candidate 5"));

  SolveOutput slower = reference;
  slower.frame_rate = 60.0;
  EXPECT_THAT(ErrorMessage<ShapeError>(
                  [&] { ComputeBodyMetrics(body, reference, slower); }),
              HasSubstr("reference fit is at 120 Hz, the candidate at 60 Hz"));

  SolveOutput fewer_betas = reference;
  fewer_betas.betas.conservativeResize(4);
  EXPECT_THAT(ErrorMessage<ShapeError>(
                  [&] { ComputeBodyMetrics(body, reference, fewer_betas); }),
              HasSubstr("reference fit has 12 betas, the candidate 4"));

  SolveOutput too_many_betas = reference;
  too_many_betas.betas = Eigen::VectorXd::Zero(body.num_betas() + 1);
  EXPECT_THAT(
      ErrorMessage<ShapeError>(
          [&] { ComputeBodyMetrics(body, too_many_betas, too_many_betas); }),
      HasSubstr("reference fit has 13 betas, body 'procedural' has 12"));

  SolveOutput fewer_joints = reference;
  fewer_joints.joint_names.pop_back();
  for (Eigen::VectorXd& p : fewer_joints.frame_params) {
    p.conservativeResize(p.size() - 3);
  }
  EXPECT_THAT(ErrorMessage<ShapeError>(
                  [&] { ComputeBodyMetrics(body, reference, fewer_joints); }),
              HasSubstr("candidate fit has 23 joints, body 'procedural' has "
                        "24"));

  SolveOutput short_frame = reference;
  short_frame.frame_params[2].conservativeResize(10);
  EXPECT_THAT(ErrorMessage<ShapeError>(
                  [&] { ComputeBodyMetrics(body, short_frame, reference); }),
              HasSubstr("frame 2 of the reference fit has 10 parameters"));

  SolveOutput other_body = reference;
  other_body.body = "smplx";
  EXPECT_THAT(ErrorMessage<ShapeError>(
                  [&] { ComputeBodyMetrics(body, reference, other_body); }),
              HasSubstr("candidate fit is of body 'smplx'"));

  BodyMetricsOptions no_thresholds;
  no_thresholds.pck_thresholds_mm.clear();
  EXPECT_THROW(ComputeBodyMetrics(body, reference, reference, no_thresholds),
               ConfigError);
  BodyMetricsOptions negative;
  negative.pck_thresholds_mm = {10.0, -1.0};
  EXPECT_THROW(ComputeBodyMetrics(body, reference, reference, negative),
               ConfigError);
}

}  // namespace
}  // namespace soma
