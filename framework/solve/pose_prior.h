// Pose priors of the body solver (REFERENCE.md 7.3/7.4 "poseB"): a residual
// vector over the body pose (every joint but the root, 3 (J - 1) axis-angle
// dofs) whose squared norm is the prior's negative log-density up to a
// constant. MoSh++ uses a max-mixture GMM; PosePrior is the interface a GMM
// implements too (pick the best component per evaluation, residual
// [sqrt(1/2) L_k^T (x - mu_k), sqrt(-log w'_k)]). GaussianPosePrior is the
// one implemented: a single Gaussian, fitted to the procedural motion
// library (ProceduralPosePrior) or zero-mean isotropic.
#pragma once

#include "framework/body/body_model.h"

#include <Eigen/Core>

#include <string>
#include <vector>

namespace soma {

class PosePrior {
 public:
  virtual ~PosePrior() = default;
  /// Body pose dofs the prior reads: 3 (J - 1).
  virtual int num_dofs() const = 0;
  virtual int num_residuals() const = 0;
  /// Residuals at `body_pose` (num_dofs values: joints 1..J-1, axis-angle)
  /// and, if `jacobian` is not null, their row-major num_residuals x
  /// num_dofs Jacobian.
  virtual void Evaluate(const double* body_pose,
                        double* residuals,
                        double* jacobian) const = 0;
};

/// residual = S (x - mean), S = L^T with L L^T = Sigma^-1: |residual|^2 is
/// the Mahalanobis distance.
class GaussianPosePrior : public PosePrior {
 public:
  GaussianPosePrior(Eigen::VectorXd mean, Eigen::MatrixXd sqrt_information);

  /// Zero mean, isotropic standard deviation `stddev` (radians) per dof.
  static GaussianPosePrior ZeroMean(int num_joints, double stddev);
  /// Mean and covariance of `samples` (each num_dofs) with shrinkage of the
  /// covariance towards its diagonal (`shrinkage` in [0, 1]) and a floor
  /// min_stddev^2 added to the diagonal. Throws ShapeError for fewer than 2
  /// samples or inconsistent sizes.
  static GaussianPosePrior Fit(const std::vector<Eigen::VectorXd>& samples,
                               double shrinkage,
                               double min_stddev);

  int num_dofs() const override { return static_cast<int>(mean_.size()); }
  int num_residuals() const override {
    return static_cast<int>(sqrt_information_.rows());
  }
  void Evaluate(const double* body_pose,
                double* residuals,
                double* jacobian) const override;

  const Eigen::VectorXd& mean() const { return mean_; }
  const Eigen::MatrixXd& sqrt_information() const { return sqrt_information_; }

 private:
  Eigen::VectorXd mean_;
  Eigen::MatrixXd sqrt_information_;
};

struct ProceduralPosePriorOptions {
  /// Motion types sampled (empty: every type but random_pose, whose uniform
  /// joint-limit poses would flatten the prior).
  std::vector<std::string> types;
  int clips_per_type = 2;
  int frame_stride = 4;  // every n-th frame of each clip
  double shrinkage = 0.2;
  double min_stddev = 0.05;  // radians
  uint64_t seed = 100;
};

/// A Gaussian fitted to the body poses of procedural clips on `body`.
GaussianPosePrior ProceduralPosePrior(
    const BodyModel& body, const ProceduralPosePriorOptions& options);

}  // namespace soma
