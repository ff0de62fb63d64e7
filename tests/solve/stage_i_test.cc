#include "framework/solve/stage_i.h"

#include "framework/body/marker_layout.h"
#include "framework/core/error.h"
#include "framework/core/random.h"
#include "framework/motion/procedural_motion.h"
#include "framework/testing/body_fixture.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include <cmath>

namespace soma {
namespace {

using ::soma::testing::ProceduralBody;

TEST(StageI, RecoversShapeAndMarkerPlacementFromSyntheticFrames) {
  const BodyModel& body = ProceduralBody();
  const MarkerLayout layout = MakeBuiltinLayout(body, "cmu41");
  const auto [vids, dist] = MarkerVertices(layout);
  Rng rng(21);
  Eigen::VectorXd betas(body.num_betas());
  for (int b = 0; b < betas.size(); ++b) betas(b) = 1.0 * rng.Normal();
  MarkerModel truth(body, vids);
  truth.SetShape(betas, NormalOffsets(body, betas, vids, dist));
  // 8 frames from different motions.
  std::vector<Eigen::Matrix3Xd> frames;
  for (const char* type : {"walk", "squat", "reach", "kick"}) {
    Rng clip_rng = rng.Stream(type);
    const PoseSequence clip = GenerateProceduralMotion(
        type, body, ProceduralMotionOptions{}, clip_rng);
    for (int k = 0; k < 2; ++k) {
      const Eigen::VectorXd f =
          PackFrameParams(clip.frames[(k * 37) % clip.num_frames()]);
      Eigen::Matrix3Xd p;
      truth.Evaluate(f.data(), {}, &p, nullptr);
      frames.push_back(p);
    }
  }
  const GaussianPosePrior prior =
      GaussianPosePrior::ZeroMean(body.num_joints(), 0.6);
  MarkerModel model(body, vids);
  const StageIResult result =
      SolveStageI(body, &model, dist, frames, &prior, StageIOptions{});
  ASSERT_TRUE(result.summary.usable()) << result.summary.BriefReport();
  EXPECT_EQ(result.rounds.size(), 4u);
  const double latent_error =
      (model.latent_markers() - truth.latent_markers()).colwise().norm().mean();
  std::printf(
      "stage I synthetic: fit rms %.3f mm, mean latent marker error %.2f mm, "
      "beta error %.3f (|beta| %.3f), %d iterations, %.2f s\n",
      1e3 * result.summary.rms_m,
      1e3 * latent_error,
      (result.betas - betas).norm(),
      betas.norm(),
      result.summary.iterations,
      result.summary.time_s);
  EXPECT_LT(result.summary.rms_m, 3e-3);
  EXPECT_LT(latent_error, 10e-3);
  EXPECT_LT((result.betas - betas).norm(), 0.5 * betas.norm());
}

TEST(StageI, PicksFramesWithEnoughMarkers) {
  std::vector<Eigen::Matrix3Xd> frames(30, Eigen::Matrix3Xd::Zero(3, 10));
  for (int f = 0; f < 30; f += 2) frames[f](0, 3) = std::nan("");
  StageIOptions options;
  options.num_frames = 12;
  const std::vector<int> picked = PickStageIFrames(frames, options);
  ASSERT_EQ(picked.size(), 12u);
  for (int f : picked) EXPECT_EQ(f % 2, 1);
  EXPECT_TRUE(std::is_sorted(picked.begin(), picked.end()));
  EXPECT_EQ(PickStageIFrames(frames, options), picked);  // seeded
  // Too few complete frames: relaxed to 90%.
  options.num_frames = 20;
  EXPECT_EQ(PickStageIFrames(frames, options).size(), 20u);
  // Nothing close: an error naming the best fraction.
  std::vector<Eigen::Matrix3Xd> empty(5,
                                      Eigen::Matrix3Xd::Constant(3, 10, NAN));
  const std::string message = soma::testing::ErrorMessage<Error>(
      [&] { PickStageIFrames(empty, options); });
  EXPECT_NE(message.find("not enough frames"), std::string::npos) << message;
}

TEST(StageI, BadInput) {
  const BodyModel& body = ProceduralBody();
  MarkerModel model(body, {10, 20, 30, 40});
  const std::vector<double> dist(4, 0.0095);
  EXPECT_THROW(SolveStageI(body,
                           &model,
                           {0.01},
                           {Eigen::Matrix3Xd::Zero(3, 4)},
                           nullptr,
                           StageIOptions{}),
               ShapeError);
  EXPECT_THROW(SolveStageI(body,
                           &model,
                           dist,
                           {Eigen::Matrix3Xd::Zero(3, 5)},
                           nullptr,
                           StageIOptions{}),
               ShapeError);
  Eigen::Matrix3Xd two = Eigen::Matrix3Xd::Constant(3, 4, NAN);
  two.leftCols(2).setZero();
  EXPECT_THROW(SolveStageI(body, &model, dist, {two}, nullptr, StageIOptions{}),
               Error);
  StageIOptions bad;
  bad.annealing = {};
  EXPECT_THROW(bad.Validate(), ConfigError);
}

}  // namespace
}  // namespace soma
