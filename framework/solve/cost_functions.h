// Ceres cost functions of the body solver, all with analytic Jacobians
// (finite-difference checked in tests/solve/cost_functions_test.cc). Linear
// terms (beta prior, marker-offset priors, pose velocity) use
// ceres::NormalPrior.
#pragma once

#include "framework/solve/marker_model.h"
#include "framework/solve/pose_prior.h"

#include <Eigen/Core>
#include <ceres/cost_function.h>

#include <string>
#include <string_view>
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

namespace ceres {
class LossFunction;
}

namespace soma {

/// Selectable marker data term of stage I and stage II (issue #8 item 2).
///   data_term: standard     sum_m w^2 ||r_m||^2 / 2 (Ceres' 1/2 |f|^2), with
///                           an optional robust loss per marker (data_loss);
///              noise_aware  Noise-in Bias-out (Sec. 3.3, Eqs. 5-6): a
///                           per-marker noise sigma_m optimised jointly with
///                           the body,  sum_m ||r_m||^2 / (2 sigma_m^2) +
///                           log sigma_m, scaled by w^2 sigma_ref^2 so that a
///                           marker with sigma_m = sigma_ref (=
///                           data_loss_scale) weighs as in the standard term.
///   data_loss: squared | cauchy | huber (ceres::CauchyLoss / HuberLoss on
///              each marker's 3-vector residual, scale data_loss_scale in
///              metres). Cauchy is the alpha = 0 case of Barron's general
///              robust loss (Barron, CVPR 2019); the general loss is not
///              implemented. Only with data_term = standard.
struct DataTermOptions {
  std::string data_term = "standard";
  std::string data_loss = "squared";
  double data_loss_scale = 0.01;   // metres: robust-loss scale / sigma_ref
  double noise_sigma_min = 0.001;  // metres: lower bound of sigma_m
  /// ConfigError naming `<stage>.<key>`.
  void Validate(std::string_view stage) const;
  bool noise_aware() const { return data_term == "noise_aware"; }
};

/// The robust loss of a marker residual block whose residual is
/// weight * (sim - obs); nullptr for squared. Ownership passes to the caller
/// (ceres::Problem takes it).
ceres::LossFunction* MakeDataLoss(const DataTermOptions& options,
                                  double weight);

/// Wraps a marker data cost with 3 residuals g = w (sim - obs) into the
/// noise-aware term of one marker: the inner parameter blocks followed by
/// one block s = log sigma (1 value, bounded below by log sigma_min by the
/// caller). Residuals (4):
///   f_0..2 = sigma_ref exp(-s) g,
///   f_3    = w sigma_ref sqrt(2 (s - log sigma_min) + 1),
/// so 1/2 |f|^2 = w^2 sigma_ref^2 (||sim - obs||^2 / (2 sigma^2) + log sigma)
/// + const (the +1 keeps the square root differentiable at the bound).
/// Takes ownership of `inner`.
class NoiseAwareMarkerCost : public ceres::CostFunction {
 public:
  NoiseAwareMarkerCost(ceres::CostFunction* inner,
                       double weight,
                       double sigma_ref,
                       double sigma_min);
  ~NoiseAwareMarkerCost() override;
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override;

 private:
  ceres::CostFunction* inner_;
  double weight_;
  double sigma_ref_;
  double log_sigma_min_;
};

}  // namespace soma
