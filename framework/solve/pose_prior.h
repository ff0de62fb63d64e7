// Pose priors of the body solver (REFERENCE.md 7.3/7.4 "poseB"): a residual
// vector over the body pose (every joint but the root, 3 (J - 1) axis-angle
// dofs) whose squared norm is twice the prior's negative log-density up to
// a constant. Implementations:
//   GaussianPosePrior  a single Gaussian: fitted to the procedural motion
//                      library (ProceduralPosePrior) or zero-mean isotropic;
//   GmmPosePrior       MoSh++'s max-mixture of Gaussians (the best component
//                      per evaluation), read from a `soma fit_prior` file.
// Solver configs pick one through the `pose_prior` registry
// (PosePriorSource, configs/pose_prior/).
#pragma once

#include "framework/body/body_model.h"
#include "framework/motion/pose_sequence.h"
#include "framework/solve/gaussian_mixture.h"

#include <Eigen/Core>

#include <memory>
#include <string>
#include <string_view>
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
  /// Mean and covariance of the columns of `samples` (num_dofs x N) with
  /// shrinkage of the covariance towards its diagonal (`shrinkage` in
  /// [0, 1]) and a floor min_stddev^2 added to the diagonal. Throws
  /// ShapeError for fewer than 2 samples.
  static GaussianPosePrior Fit(const Eigen::MatrixXd& samples,
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

/// MoSh++'s max-mixture prior: for component k with x - mu_k = e_k,
///   c_k(x) = e_k^T Sigma_k^-1 e_k + 2 (-log w_k + 1/2 log det Sigma_k),
/// the residual of the component k* with the smallest c_k is
///   [S_k* e_k*; sqrt(c0_k* - min_k c0_k)],  S_k = L_k^T, L_k L_k^T =
///   Sigma_k^-1, c0_k = c_k(mu_k),
/// so |residual|^2 = min_k c_k - min_k c0_k >= 0 (num_dofs + 1 residuals;
/// the constant row has zero Jacobian). Piecewise smooth: the gradient is
/// exact within each component's region.
class GmmPosePrior : public PosePrior {
 public:
  /// Throws ShapeError if the mixture is invalid.
  explicit GmmPosePrior(const GaussianMixture& gmm);

  int num_dofs() const override { return dofs_; }
  int num_residuals() const override { return dofs_ + 1; }
  void Evaluate(const double* body_pose,
                double* residuals,
                double* jacobian) const override;

  /// The component Evaluate uses at `body_pose`.
  int BestComponent(const double* body_pose) const;

 private:
  int dofs_ = 0;
  std::vector<Eigen::VectorXd> means_;
  std::vector<Eigen::MatrixXd> sqrt_information_;
  Eigen::VectorXd offsets_;  // c0_k - min c0
};

/// Joint rotations (joints 1..J-1, axis-angle, 3 (J - 1) rows) of every
/// `stride`-th frame of `sequences`, one column per frame: the samples a
/// pose prior is fitted to.
Eigen::MatrixXd BodyPoseSamples(const std::vector<PoseSequence>& sequences,
                                int num_joints,
                                int stride);

/// A pose prior as a registered component (kind `pose_prior`,
/// configs/pose_prior/): builds the prior for the body being solved.
class PosePriorSource {
 public:
  static constexpr std::string_view kRegistryName = "pose_prior";
  virtual ~PosePriorSource() = default;
  /// The prior for `body`; null for no prior. Throws ShapeError if the
  /// prior does not fit the body (e.g. a GMM fitted for other joints).
  virtual std::unique_ptr<PosePrior> Make(const BodyModel& body) const = 0;
};

/// Registers `procedural`, `zero_mean`, `gmm` and `none` and the
/// `pose_prior` config group.
void RegisterPosePriors();

}  // namespace soma
