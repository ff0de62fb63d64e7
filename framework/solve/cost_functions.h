// Ceres cost functions of the body solver, all with analytic Jacobians
// (finite-difference checked in tests/solve/cost_functions_test.cc). Linear
// terms (beta prior, marker-offset priors, pose velocity) use
// ceres::NormalPrior.
#pragma once

#include "framework/solve/marker_model.h"
#include "framework/solve/pose_prior.h"

#include <Eigen/Core>
#include <ceres/cost_function.h>

#include <vector>

namespace soma {

/// Data term with a fixed shape (stage II): residual_k = weight (p_{m_k} -
/// observed_k) over the markers `markers` (3K residuals); one parameter block,
/// the frame vector. `model` must outlive the cost function.
class MarkerDataCost : public ceres::CostFunction {
 public:
  MarkerDataCost(const MarkerModel* model,
                 std::vector<int> markers,
                 Eigen::Matrix3Xd observed,
                 double weight);
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override;

 private:
  const MarkerModel* model_;
  std::vector<int> markers_;
  Eigen::Matrix3Xd observed_;
  double weight_;
};

/// Data term with a free shape (stage I): parameter blocks frame
/// (frame_size), betas (num_betas), then the offset (3) of each marker in
/// `markers`, in that order.
class ShapeMarkerDataCost : public ceres::CostFunction {
 public:
  ShapeMarkerDataCost(const MarkerModel* model,
                      std::vector<int> markers,
                      Eigen::Matrix3Xd observed,
                      double weight);
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override;

 private:
  const MarkerModel* model_;
  std::vector<int> markers_;
  Eigen::Matrix3Xd observed_;
  double weight_;
};

/// weight * prior(body pose) on a frame vector (the body pose starts at
/// index 6: after t and the root rotation). `prior` must outlive it.
class PosePriorCost : public ceres::CostFunction {
 public:
  PosePriorCost(const PosePrior* prior, int frame_size, double weight);
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override;

 private:
  const PosePrior* prior_;
  int frame_size_;
  double weight_;
};

/// weight (frame[3:] - target), the rotations of a frame vector pulled to
/// `target` (3J: e.g. the constant-velocity extrapolation 2 p_{t-1} -
/// p_{t-2}); a ceres::NormalPrior.
ceres::CostFunction* MakePoseVelocityCost(const Eigen::VectorXd& target_frame,
                                          double weight);

}  // namespace soma
