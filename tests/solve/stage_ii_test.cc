#include "framework/solve/stage_ii.h"

#include "framework/body/marker_layout.h"
#include "framework/core/error.h"
#include "framework/core/random.h"
#include "framework/motion/procedural_motion.h"
#include "framework/testing/body_fixture.h"

#include <gtest/gtest.h>

#include <cmath>

namespace soma {
namespace {

using ::soma::testing::ProceduralBody;

struct Synthetic {
  MarkerModel model;
  std::vector<Eigen::VectorXd> frames;  // ground truth
  std::vector<Eigen::Matrix3Xd> markers;
};

/// cmu41 markers on a shaped procedural body following a procedural walk.
Synthetic MakeSynthetic(int num_frames, uint64_t seed) {
  const BodyModel& body = ProceduralBody();
  const MarkerLayout layout = MakeBuiltinLayout(body, "cmu41");
  const auto [vids, dist] = MarkerVertices(layout);
  Rng rng(seed);
  Eigen::VectorXd betas(body.num_betas());
  for (int b = 0; b < betas.size(); ++b) betas(b) = 0.8 * rng.Normal();
  Synthetic s{MarkerModel(body, vids), {}, {}};
  s.model.SetShape(betas, NormalOffsets(body, betas, vids, dist));
  Rng clip_rng = rng.Stream("clip");
  const PoseSequence clip = GenerateProceduralMotion(
      "walk", body, ProceduralMotionOptions{}, clip_rng);
  for (int f = 0; f < num_frames && f < clip.num_frames(); ++f) {
    s.frames.push_back(PackFrameParams(clip.frames[f]));
    Eigen::Matrix3Xd p;
    s.model.Evaluate(s.frames.back().data(), {}, &p, nullptr);
    s.markers.push_back(p);
  }
  return s;
}

/// Mean over joints of the rotation angle between two frames' joints.
double MeanJointAngleError(const Eigen::VectorXd& a,
                           const Eigen::VectorXd& b,
                           int num_joints) {
  double sum = 0;
  for (int j = 0; j < num_joints; ++j) {
    const auto rot = [&](const Eigen::VectorXd& f) {
      const Eigen::Vector3d w = f.segment<3>(3 + 3 * j);
      const double angle = w.norm();
      return angle < 1e-12
                 ? Eigen::Matrix3d::Identity().eval()
                 : Eigen::AngleAxisd(angle, w / angle).toRotationMatrix();
    };
    sum += Eigen::AngleAxisd(rot(a).transpose() * rot(b)).angle();
  }
  return sum / num_joints;
}

TEST(StageIISolver, RecoversKnownPosesFromSyntheticMarkers) {
  Synthetic s = MakeSynthetic(20, 11);
  const GaussianPosePrior prior =
      GaussianPosePrior::ZeroMean(s.model.num_joints(), 0.6);
  StageIISolver solver(&s.model, &prior, StageIIOptions{});
  double worst_rms = 0, worst_angle = 0, worst_trans = 0;
  for (size_t f = 0; f < s.frames.size(); ++f) {
    Eigen::VectorXd params;
    const SolveSummary summary =
        solver.SolveFrame(static_cast<int>(f), s.markers[f], &params);
    ASSERT_TRUE(summary.usable()) << summary.BriefReport();
    EXPECT_EQ(summary.markers_used, 41);
    worst_rms = std::max(worst_rms, summary.rms_m);
    worst_trans = std::max(worst_trans,
                           (params.head<3>() - s.frames[f].head<3>()).norm());
    // Joints without markers below them (hands, toes) are prior-driven.
    worst_angle =
        std::max(worst_angle, MeanJointAngleError(params, s.frames[f], 22));
  }
  std::printf(
      "stage II synthetic: worst rms %.3f mm, worst mean joint angle "
      "error %.4f rad, worst translation error %.2f mm\n",
      1e3 * worst_rms,
      worst_angle,
      1e3 * worst_trans);
  EXPECT_LT(worst_rms, 2e-3);
  EXPECT_LT(worst_angle, 0.05);
  EXPECT_LT(worst_trans, 5e-3);
}

TEST(StageIISolver, SkipsFramesWithTooFewMarkersAndCountsMissing) {
  Synthetic s = MakeSynthetic(3, 12);
  const GaussianPosePrior prior =
      GaussianPosePrior::ZeroMean(s.model.num_joints(), 0.6);
  StageIISolver solver(&s.model, &prior, StageIIOptions{});
  Eigen::Matrix3Xd few = Eigen::Matrix3Xd::Constant(3, 41, std::nan(""));
  few.col(0) = s.markers[0].col(0);
  few.col(1) = s.markers[0].col(1);
  Eigen::VectorXd params;
  SolveSummary summary = solver.SolveFrame(0, few, &params);
  EXPECT_EQ(summary.termination, SolveTermination::kSkipped);
  EXPECT_EQ(summary.skipped_reason, "too_few_markers");
  EXPECT_EQ(summary.markers_used, 2);
  EXPECT_FALSE(params.allFinite());
  // NaN points are missing markers, not errors.
  Eigen::Matrix3Xd holes = s.markers[1];
  holes.col(3).setConstant(std::nan(""));
  holes(1, 7) = std::numeric_limits<double>::infinity();
  summary = solver.SolveFrame(1, holes, &params);
  ASSERT_TRUE(summary.usable()) << summary.BriefReport();
  EXPECT_EQ(summary.markers_used, 39);
  EXPECT_EQ(summary.markers_missing, 2);
  EXPECT_LT(summary.rms_m, 2e-3);
  const SequenceSolveStats stats = Summarize({SolveSummary{}, summary});
  EXPECT_EQ(stats.skipped, 1);
}

TEST(StageIISolver, BadInput) {
  Synthetic s = MakeSynthetic(1, 13);
  const GaussianPosePrior prior =
      GaussianPosePrior::ZeroMean(s.model.num_joints(), 0.6);
  StageIISolver solver(&s.model, &prior, StageIIOptions{});
  Eigen::VectorXd params;
  EXPECT_THROW(solver.SolveFrame(0, Eigen::Matrix3Xd::Zero(3, 40), &params),
               ShapeError);
  const GaussianPosePrior wrong = GaussianPosePrior::ZeroMean(10, 0.6);
  EXPECT_THROW(StageIISolver(&s.model, &wrong, StageIIOptions{}), ShapeError);
  StageIIOptions bad;
  bad.min_markers = 2;
  EXPECT_THROW(StageIISolver(&s.model, &prior, bad), ConfigError);
  bad = StageIIOptions{};
  bad.solver.trust_region = "newton";
  EXPECT_THROW(StageIISolver(&s.model, &prior, bad), ConfigError);
}

}  // namespace
}  // namespace soma
