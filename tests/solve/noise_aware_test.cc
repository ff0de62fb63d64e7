// Robust losses and the noise-aware data term (issue #8 item 2): derivative
// checks, outlier robustness of stage II and per-marker sigma estimates of
// both stages, option validation.
#include "framework/body/marker_layout.h"
#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/core/random.h"
#include "framework/motion/procedural_motion.h"
#include "framework/solve/body_solver.h"
#include "framework/solve/cost_functions.h"
#include "framework/solve/stage_i.h"
#include "framework/solve/stage_ii.h"
#include "framework/testing/body_fixture.h"

#include <ceres/gradient_checker.h>
#include <gtest/gtest.h>

#include <cmath>
#include <string>

namespace soma {
namespace {

using ::soma::testing::ProceduralBody;

struct BodySetup {
  std::vector<int> vids;
  std::vector<double> dist;
  Eigen::VectorXd betas;
};

BodySetup MakeBodySetup(uint64_t seed) {
  const BodyModel& body = ProceduralBody();
  const MarkerLayout layout = MakeBuiltinLayout(body, "cmu41");
  BodySetup s;
  for (const auto& m : layout.markers) {
    s.vids.push_back(m.vertex_ids[0]);
    s.dist.push_back(m.distance_from_skin);
  }
  Rng rng(seed);
  s.betas = Eigen::VectorXd(body.num_betas());
  for (int b = 0; b < s.betas.size(); ++b) s.betas(b) = 0.8 * rng.Normal();
  return s;
}

void ExpectGradientsMatch(const ceres::CostFunction* cost,
                          const std::vector<const double*>& params) {
  ceres::NumericDiffOptions options;
  const std::vector<const ceres::Manifold*>* no_manifolds = nullptr;
  ceres::GradientChecker checker(cost, no_manifolds, options);
  ceres::GradientChecker::ProbeResults results;
  EXPECT_TRUE(checker.Probe(params.data(), 1e-6, &results))
      << results.error_log;
}

TEST(NoiseAwareMarkerCost, JacobiansMatchFiniteDifferencesAndValue) {
  const BodyModel& body = ProceduralBody();
  const BodySetup s = MakeBodySetup(3);
  MarkerModel model(body, s.vids);
  Rng rng(5);
  Eigen::Matrix3Xd offsets(3, s.vids.size());
  for (int i = 0; i < offsets.size(); ++i) {
    offsets.data()[i] = 0.01 * rng.Normal();
  }
  model.SetShape(s.betas, offsets);
  Eigen::VectorXd frame(model.frame_size());
  for (int i = 0; i < frame.size(); ++i) frame(i) = 0.3 * rng.Normal();
  const Eigen::Vector3d observed(0.1, 0.2, 0.9);
  const double w = 37.0, sigma_ref = 0.01, sigma_min = 0.001;
  double log_sigma = std::log(0.02);
  // Pose-only (stage II) inner cost.
  const NoiseAwareMarkerCost pose_cost(
      new MarkerDataCost(&model, {7}, observed, w), w, sigma_ref, sigma_min);
  ExpectGradientsMatch(&pose_cost, {frame.data(), &log_sigma});
  // Value: 1/2 |f|^2 = w^2 sigma_ref^2 (|r|^2 / (2 s^2) + log s - log
  // sigma_min + 1/2).
  Eigen::Vector4d f;
  const double* p[] = {frame.data(), &log_sigma};
  ASSERT_TRUE(pose_cost.Evaluate(p, f.data(), nullptr));
  Eigen::Matrix3Xd sim;
  model.Evaluate(frame.data(), {7}, &sim, nullptr);
  const double sigma = std::exp(log_sigma);
  const double expected =
      w * w * sigma_ref * sigma_ref *
      ((sim.col(0) - observed).squaredNorm() / (2 * sigma * sigma) +
       std::log(sigma) - std::log(sigma_min) + 0.5);
  EXPECT_NEAR(0.5 * f.squaredNorm(), expected, 1e-9 * expected);
  // Free-shape (stage I) inner cost.
  Eigen::VectorXd betas = s.betas;
  Eigen::Vector3d offset = offsets.col(7);
  const NoiseAwareMarkerCost shape_cost(
      new ShapeMarkerDataCost(&model, {7}, observed, w), w, sigma_ref, 0.002);
  ExpectGradientsMatch(&shape_cost,
                       {frame.data(), betas.data(), offset.data(), &log_sigma});
}

struct OutlierResult {
  double clean_rms = 0;    // solved vs true clean markers, metres
  double joint_angle = 0;  // mean joint angle error, radians
  Eigen::VectorXd sigmas;  // noise-aware only (last frame)
};

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

constexpr int kOutliers[] = {3, 17, 30};

bool IsOutlier(int m) {
  for (int o : kOutliers) {
    if (o == m) return true;
  }
  return false;
}

/// Stage II over a few walk frames with 1 mm noise on every marker and the
/// markers kOutliers displaced by 5 cm (a fixed random direction each).
OutlierResult SolveWithOutliers(const DataTermOptions& data) {
  const BodyModel& body = ProceduralBody();
  const BodySetup s = MakeBodySetup(11);
  MarkerModel model(body, s.vids);
  model.SetShape(s.betas, NormalOffsets(body, s.betas, s.vids, s.dist));
  Rng rng(11);
  Rng clip_rng = rng.Stream("clip");
  const PoseSequence clip = GenerateProceduralMotion(
      "walk", body, ProceduralMotionOptions{}, clip_rng);
  Rng noise_rng(77);
  std::vector<Eigen::Vector3d> shift;
  for (size_t i = 0; i < std::size(kOutliers); ++i) {
    Eigen::Vector3d d(
        noise_rng.Normal(), noise_rng.Normal(), noise_rng.Normal());
    shift.push_back(0.05 * d.normalized());
  }
  const GaussianPosePrior prior =
      GaussianPosePrior::ZeroMean(model.num_joints(), 0.6);
  StageIIOptions options;
  options.data = data;
  StageIISolver solver(&model, &prior, options);
  OutlierResult result;
  double sq = 0;
  int count = 0;
  constexpr int kFrames = 3;
  for (int f = 0; f < kFrames; ++f) {
    const Eigen::VectorXd truth = PackFrameParams(clip.frames[5 * f]);
    Eigen::Matrix3Xd clean;
    model.Evaluate(truth.data(), {}, &clean, nullptr);
    Eigen::Matrix3Xd observed = clean;
    for (int m = 0; m < observed.cols(); ++m) {
      for (int k = 0; k < 3; ++k) observed(k, m) += 0.001 * noise_rng.Normal();
    }
    for (size_t i = 0; i < std::size(kOutliers); ++i) {
      observed.col(kOutliers[i]) += shift[i];
    }
    Eigen::VectorXd params;
    const SolveSummary summary = solver.SolveFrame(f, observed, &params);
    EXPECT_TRUE(summary.usable()) << summary.BriefReport();
    Eigen::Matrix3Xd sim;
    model.Evaluate(params.data(), {}, &sim, nullptr);
    for (int m = 0; m < sim.cols(); ++m) {
      if (IsOutlier(m)) continue;
      sq += (sim.col(m) - clean.col(m)).squaredNorm();
      ++count;
    }
    result.joint_angle +=
        MeanJointAngleError(params, truth, model.num_joints()) / kFrames;
  }
  result.clean_rms = std::sqrt(sq / count);
  result.sigmas = solver.noise_sigmas();
  return result;
}

TEST(RobustDataTerm, CauchyAndNoiseAwareBeatSquaredWithOutliers) {
  DataTermOptions squared;
  DataTermOptions cauchy;
  cauchy.data_loss = "cauchy";
  DataTermOptions huber;
  huber.data_loss = "huber";
  DataTermOptions noise_aware;
  noise_aware.data_term = "noise_aware";
  const OutlierResult rs = SolveWithOutliers(squared);
  const OutlierResult rc = SolveWithOutliers(cauchy);
  const OutlierResult rh = SolveWithOutliers(huber);
  const OutlierResult rn = SolveWithOutliers(noise_aware);
  std::printf(
      "outliers: clean-marker rms / joint angle: squared %.2f mm / %.2f deg, "
      "cauchy %.2f / %.2f, huber %.2f / %.2f, noise_aware %.2f / %.2f\n",
      1e3 * rs.clean_rms,
      rs.joint_angle * 180 / M_PI,
      1e3 * rc.clean_rms,
      rc.joint_angle * 180 / M_PI,
      1e3 * rh.clean_rms,
      rh.joint_angle * 180 / M_PI,
      1e3 * rn.clean_rms,
      rn.joint_angle * 180 / M_PI);
  EXPECT_LT(rc.clean_rms, 0.7 * rs.clean_rms);
  EXPECT_LT(rn.clean_rms, 0.7 * rs.clean_rms);
  EXPECT_LT(rh.clean_rms, rs.clean_rms);
  EXPECT_LT(rc.joint_angle, rs.joint_angle);
  EXPECT_LT(rn.joint_angle, rs.joint_angle);
  EXPECT_EQ(rs.sigmas.size(), 0);
  // (b) the outliers get larger sigmas than every clean marker.
  ASSERT_EQ(rn.sigmas.size(), 41);
  double max_clean = 0, min_noisy = 1e9;
  for (int m = 0; m < 41; ++m) {
    EXPECT_GE(rn.sigmas(m), 0.001 * (1 - 1e-9));
    if (IsOutlier(m)) {
      min_noisy = std::min(min_noisy, rn.sigmas(m));
    } else {
      max_clean = std::max(max_clean, rn.sigmas(m));
    }
  }
  std::printf("stage II sigmas: max clean %.2f mm, min outlier %.2f mm\n",
              1e3 * max_clean,
              1e3 * min_noisy);
  EXPECT_GT(min_noisy, 2 * max_clean);
  EXPECT_GT(min_noisy, 0.02);
}

TEST(RobustDataTerm, StageINoiseAwareSigmasFlagNoisyMarkers) {
  const BodyModel& body = ProceduralBody();
  const BodySetup s = MakeBodySetup(21);
  MarkerModel truth(body, s.vids);
  truth.SetShape(s.betas, NormalOffsets(body, s.betas, s.vids, s.dist));
  Rng rng(21);
  std::vector<Eigen::Matrix3Xd> frames;
  Rng noise_rng(8);
  for (const char* type : {"walk", "squat"}) {
    Rng clip_rng = rng.Stream(type);
    const PoseSequence clip = GenerateProceduralMotion(
        type, body, ProceduralMotionOptions{}, clip_rng);
    for (int k = 0; k < 2; ++k) {
      const Eigen::VectorXd f =
          PackFrameParams(clip.frames[(k * 37) % clip.num_frames()]);
      Eigen::Matrix3Xd p;
      truth.Evaluate(f.data(), {}, &p, nullptr);
      // Independent 3 cm noise per frame on the outlier markers (a constant
      // shift would be absorbed by the free offsets).
      for (int m : kOutliers) {
        for (int c = 0; c < 3; ++c) p(c, m) += 0.03 * noise_rng.Normal();
      }
      frames.push_back(p);
    }
  }
  const GaussianPosePrior prior =
      GaussianPosePrior::ZeroMean(body.num_joints(), 0.6);
  MarkerModel model(body, s.vids);
  StageIOptions options;
  options.annealing = {1.0, 0.25};
  options.data.data_term = "noise_aware";
  const StageIResult result =
      SolveStageI(body, &model, s.dist, frames, &prior, options);
  ASSERT_TRUE(result.summary.usable()) << result.summary.BriefReport();
  ASSERT_EQ(result.noise_sigmas.size(), 41);
  double max_clean = 0, min_noisy = 1e9;
  for (int m = 0; m < 41; ++m) {
    if (IsOutlier(m)) {
      min_noisy = std::min(min_noisy, result.noise_sigmas(m));
    } else {
      max_clean = std::max(max_clean, result.noise_sigmas(m));
    }
  }
  std::printf("stage I sigmas: max clean %.2f mm, min noisy %.2f mm\n",
              1e3 * max_clean,
              1e3 * min_noisy);
  EXPECT_GT(min_noisy, 2 * max_clean);
}

std::string ConfigErrorOf(const std::string& yaml) {
  try {
    DecodeBodySolveOptions(ParseYaml(yaml, "test"));
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

TEST(RobustDataTerm, BadOptionsAreOneLineConfigErrorsNamingTheKey) {
  const struct {
    const char* yaml;
    const char* key;
  } cases[] = {
      {"stageii: {data_loss: tukey}\n", "stageii.data_loss"},
      {"stagei: {data_loss: l1}\n", "stagei.data_loss"},
      {"stageii: {data_term: barron}\n", "stageii.data_term"},
      {"stagei: {data_loss_scale: 0}\n", "stagei.data_loss_scale"},
      {"stageii: {noise_sigma_min: -1}\n", "stageii.noise_sigma_min"},
      {"stageii: {data_term: noise_aware, data_loss: cauchy}\n",
       "stageii.data_loss"},
  };
  for (const auto& c : cases) {
    const std::string message = ConfigErrorOf(c.yaml);
    EXPECT_NE(message.find(c.key), std::string::npos)
        << c.yaml << " -> " << message;
    EXPECT_EQ(message.find('\n'), std::string::npos) << message;
  }
  const BodySolveOptions o = DecodeBodySolveOptions(
      ParseYaml("stagei: {data_term: noise_aware, noise_sigma_min: 0.002}\n"
                "stageii: {data_loss: huber, data_loss_scale: 0.02}\n",
                "test"));
  EXPECT_EQ(o.stagei.data.data_term, "noise_aware");
  EXPECT_EQ(o.stagei.data.noise_sigma_min, 0.002);
  EXPECT_EQ(o.stageii.data.data_loss, "huber");
  EXPECT_EQ(o.stageii.data.data_loss_scale, 0.02);
}

}  // namespace
}  // namespace soma
