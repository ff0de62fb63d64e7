#include "framework/solve/pose_prior.h"

#include "framework/core/error.h"
#include "framework/core/random.h"
#include "framework/motion/procedural_motion.h"

#include <Eigen/Cholesky>
#include <fmt/format.h>

namespace soma {

GaussianPosePrior::GaussianPosePrior(Eigen::VectorXd mean,
                                     Eigen::MatrixXd sqrt_information)
    : mean_(std::move(mean)), sqrt_information_(std::move(sqrt_information)) {
  if (sqrt_information_.cols() != mean_.size() || mean_.size() == 0) {
    throw ShapeError(
        fmt::format("GaussianPosePrior: mean has {} dofs, sqrt information "
                    "is {} x {}",
                    mean_.size(),
                    sqrt_information_.rows(),
                    sqrt_information_.cols()));
  }
}

GaussianPosePrior GaussianPosePrior::ZeroMean(int num_joints, double stddev) {
  SOMA_CHECK(num_joints >= 2 && stddev > 0) << "ZeroMean prior";
  const int dofs = 3 * (num_joints - 1);
  return GaussianPosePrior(Eigen::VectorXd::Zero(dofs),
                           Eigen::MatrixXd::Identity(dofs, dofs) / stddev);
}

GaussianPosePrior GaussianPosePrior::Fit(
    const std::vector<Eigen::VectorXd>& samples,
    double shrinkage,
    double min_stddev) {
  if (samples.size() < 2) {
    throw ShapeError(fmt::format(
        "GaussianPosePrior::Fit: needs >= 2 samples, got {}", samples.size()));
  }
  const int dofs = static_cast<int>(samples[0].size());
  Eigen::VectorXd mean = Eigen::VectorXd::Zero(dofs);
  for (const Eigen::VectorXd& s : samples) {
    if (s.size() != dofs) throw ShapeError("GaussianPosePrior::Fit: sizes");
    mean += s;
  }
  mean /= static_cast<double>(samples.size());
  Eigen::MatrixXd cov = Eigen::MatrixXd::Zero(dofs, dofs);
  for (const Eigen::VectorXd& s : samples) {
    cov.noalias() += (s - mean) * (s - mean).transpose();
  }
  cov /= static_cast<double>(samples.size() - 1);
  Eigen::MatrixXd reg = (1.0 - shrinkage) * cov;
  reg.diagonal() += shrinkage * cov.diagonal();
  reg.diagonal().array() += min_stddev * min_stddev;
  const Eigen::MatrixXd information = reg.inverse();
  const Eigen::LLT<Eigen::MatrixXd> llt(information);
  SOMA_CHECK(llt.info() == Eigen::Success) << "pose prior not positive";
  return GaussianPosePrior(mean, llt.matrixL().transpose());
}

void GaussianPosePrior::Evaluate(const double* body_pose,
                                 double* residuals,
                                 double* jacobian) const {
  const int n = num_dofs();
  const Eigen::Map<const Eigen::VectorXd> x(body_pose, n);
  Eigen::Map<Eigen::VectorXd>(residuals, num_residuals()) =
      sqrt_information_ * (x - mean_);
  if (jacobian != nullptr) {
    Eigen::Map<
        Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>(
        jacobian, num_residuals(), n) = sqrt_information_;
  }
}

GaussianPosePrior ProceduralPosePrior(
    const BodyModel& body, const ProceduralPosePriorOptions& options) {
  std::vector<std::string> types = options.types;
  if (types.empty()) {
    for (const std::string& type : ProceduralMotionTypes()) {
      if (type != "random_pose") types.push_back(type);
    }
  }
  const Rng rng(options.seed);
  std::vector<Eigen::VectorXd> samples;
  const int num_joints = body.num_joints();
  ProceduralMotionOptions motion;
  for (const std::string& type : types) {
    for (int c = 0; c < options.clips_per_type; ++c) {
      Rng clip_rng = rng.Stream(fmt::format("pose_prior/{}/{}", type, c));
      const PoseSequence seq =
          GenerateProceduralMotion(type, body, motion, clip_rng);
      for (int f = 0; f < seq.num_frames();
           f += std::max(1, options.frame_stride)) {
        const BodyPose& pose = seq.frames[f];
        Eigen::VectorXd s(3 * (num_joints - 1));
        for (int j = 1; j < num_joints; ++j) {
          s.segment<3>(3 * (j - 1)) = pose.rotations.col(j);
        }
        samples.push_back(std::move(s));
      }
    }
  }
  return GaussianPosePrior::Fit(samples, options.shrinkage, options.min_stddev);
}

}  // namespace soma
