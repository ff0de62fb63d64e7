#include "framework/solve/cost_functions.h"

#include "framework/core/error.h"

#include <ceres/loss_function.h>
#include <ceres/normal_prior.h>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>

namespace soma {

MarkerDataCost::MarkerDataCost(const MarkerModel* model,
                               std::vector<int> markers,
                               Eigen::Matrix3Xd observed,
                               double weight)
    : model_(model),
      markers_(std::move(markers)),
      observed_(std::move(observed)),
      weight_(weight) {
  SOMA_CHECK_EQ(static_cast<int>(markers_.size()), observed_.cols());
  SOMA_CHECK(!markers_.empty()) << "MarkerDataCost: no markers";
  set_num_residuals(3 * static_cast<int>(markers_.size()));
  mutable_parameter_block_sizes()->push_back(model_->frame_size());
}

bool MarkerDataCost::Evaluate(double const* const* parameters,
                              double* residuals,
                              double** jacobians) const {
  Eigen::Matrix3Xd positions;
  double* jac = jacobians != nullptr ? jacobians[0] : nullptr;
  model_->Evaluate(parameters[0], markers_, &positions, jac);
  Eigen::Map<Eigen::Matrix3Xd>(residuals, 3, observed_.cols()) =
      weight_ * (positions - observed_);
  if (jac != nullptr) {
    Eigen::Map<Eigen::VectorXd>(jac, num_residuals() * model_->frame_size()) *=
        weight_;
  }
  return true;
}

ShapeMarkerDataCost::ShapeMarkerDataCost(const MarkerModel* model,
                                         std::vector<int> markers,
                                         Eigen::Matrix3Xd observed,
                                         double weight)
    : model_(model),
      markers_(std::move(markers)),
      observed_(std::move(observed)),
      weight_(weight) {
  SOMA_CHECK_EQ(static_cast<int>(markers_.size()), observed_.cols());
  SOMA_CHECK(!markers_.empty()) << "ShapeMarkerDataCost: no markers";
  SOMA_CHECK(model_->num_betas() > 0) << "ShapeMarkerDataCost: no betas";
  set_num_residuals(3 * static_cast<int>(markers_.size()));
  mutable_parameter_block_sizes()->push_back(model_->frame_size());
  mutable_parameter_block_sizes()->push_back(model_->num_betas());
  for (size_t i = 0; i < markers_.size(); ++i) {
    mutable_parameter_block_sizes()->push_back(3);
  }
}

bool ShapeMarkerDataCost::Evaluate(double const* const* parameters,
                                   double* residuals,
                                   double** jacobians) const {
  const int count = static_cast<int>(markers_.size());
  Eigen::Matrix3Xd offsets = Eigen::Matrix3Xd::Zero(3, model_->num_markers());
  for (int i = 0; i < count; ++i) {
    offsets.col(markers_[i]) =
        Eigen::Map<const Eigen::Vector3d>(parameters[2 + i]);
  }
  bool want_offsets = false;
  if (jacobians != nullptr) {
    for (int i = 0; i < count; ++i) want_offsets |= jacobians[2 + i] != nullptr;
  }
  Eigen::Matrix3Xd positions;
  double* jf = jacobians != nullptr ? jacobians[0] : nullptr;
  double* jb = jacobians != nullptr ? jacobians[1] : nullptr;
  RowMajorMatrix jo(want_offsets ? 3 * count : 0, 3);
  model_->EvaluateWithShape(parameters[0],
                            parameters[1],
                            offsets.data(),
                            markers_,
                            &positions,
                            jf,
                            jb,
                            want_offsets ? jo.data() : nullptr);
  Eigen::Map<Eigen::Matrix3Xd>(residuals, 3, observed_.cols()) =
      weight_ * (positions - observed_);
  const int rows = num_residuals();
  if (jf != nullptr) {
    Eigen::Map<Eigen::VectorXd>(jf, rows * model_->frame_size()) *= weight_;
  }
  if (jb != nullptr) {
    Eigen::Map<Eigen::VectorXd>(jb, rows * model_->num_betas()) *= weight_;
  }
  for (int i = 0; want_offsets && i < count; ++i) {
    if (jacobians[2 + i] == nullptr) continue;
    Eigen::Map<RowMajorMatrix> jac(jacobians[2 + i], rows, 3);
    jac.setZero();
    jac.middleRows<3>(3 * i) = weight_ * jo.middleRows<3>(3 * i);
  }
  return true;
}

PosePriorCost::PosePriorCost(const PosePrior* prior,
                             int frame_size,
                             double weight)
    : prior_(prior), frame_size_(frame_size), weight_(weight) {
  SOMA_CHECK_EQ(prior_->num_dofs(), frame_size - 6)
      << "PosePriorCost: prior dofs vs body pose (body/prior mismatch)";
  set_num_residuals(prior_->num_residuals());
  mutable_parameter_block_sizes()->push_back(frame_size);
}

bool PosePriorCost::Evaluate(double const* const* parameters,
                             double* residuals,
                             double** jacobians) const {
  const int rows = num_residuals();
  const int dofs = prior_->num_dofs();
  if (jacobians == nullptr || jacobians[0] == nullptr) {
    prior_->Evaluate(parameters[0] + 6, residuals, nullptr);
  } else {
    RowMajorMatrix body_jac(rows, dofs);
    prior_->Evaluate(parameters[0] + 6, residuals, body_jac.data());
    Eigen::Map<RowMajorMatrix> jac(jacobians[0], rows, frame_size_);
    jac.leftCols<6>().setZero();
    jac.rightCols(dofs) = weight_ * body_jac;
  }
  Eigen::Map<Eigen::VectorXd>(residuals, rows) *= weight_;
  return true;
}

ceres::CostFunction* MakePoseVelocityCost(const Eigen::VectorXd& target_frame,
                                          double weight) {
  const int n = static_cast<int>(target_frame.size());
  ceres::Matrix a = ceres::Matrix::Zero(n - 3, n);
  a.rightCols(n - 3).diagonal().setConstant(weight);
  return new ceres::NormalPrior(a, target_frame);
}

}  // namespace soma

namespace soma {

void DataTermOptions::Validate(std::string_view stage) const {
  const auto bad = [&](std::string_view key,
                       const std::string& value,
                       std::string_view constraint) {
    return ConfigError(fmt::format(
        "Invalid configuration. {}.{} = {}. Violated constraint: {} "
        "(cost_functions.cc)",
        stage,
        key,
        value,
        constraint));
  };
  if (data_term != "standard" && data_term != "noise_aware") {
    throw bad("data_term", data_term, "standard | noise_aware");
  }
  if (data_loss != "squared" && data_loss != "cauchy" && data_loss != "huber") {
    throw bad("data_loss", data_loss, "squared | cauchy | huber");
  }
  if (!(data_loss_scale > 0) || !std::isfinite(data_loss_scale)) {
    throw bad("data_loss_scale",
              fmt::format("{}", data_loss_scale),
              "data_loss_scale > 0 (metres)");
  }
  if (!(noise_sigma_min > 0) || !(noise_sigma_min < data_loss_scale)) {
    throw bad("noise_sigma_min",
              fmt::format("{}", noise_sigma_min),
              "0 < noise_sigma_min < data_loss_scale (metres)");
  }
  if (noise_aware() && data_loss != "squared") {
    throw bad("data_loss",
              data_loss,
              "data_loss = squared when data_term = noise_aware");
  }
}

ceres::LossFunction* MakeDataLoss(const DataTermOptions& options,
                                  double weight) {
  // The residual is weight * (sim - obs): the loss scale in residual units.
  const double a = weight * options.data_loss_scale;
  if (options.data_loss == "cauchy") return new ceres::CauchyLoss(a);
  if (options.data_loss == "huber") return new ceres::HuberLoss(a);
  return nullptr;
}

NoiseAwareMarkerCost::NoiseAwareMarkerCost(ceres::CostFunction* inner,
                                           double weight,
                                           double sigma_ref,
                                           double sigma_min)
    : inner_(inner),
      weight_(weight),
      sigma_ref_(sigma_ref),
      log_sigma_min_(std::log(sigma_min)) {
  SOMA_CHECK_EQ(inner_->num_residuals(), 3)
      << "NoiseAwareMarkerCost: one marker per block";
  set_num_residuals(4);
  *mutable_parameter_block_sizes() = inner_->parameter_block_sizes();
  mutable_parameter_block_sizes()->push_back(1);
}

NoiseAwareMarkerCost::~NoiseAwareMarkerCost() { delete inner_; }

bool NoiseAwareMarkerCost::Evaluate(double const* const* parameters,
                                    double* residuals,
                                    double** jacobians) const {
  const std::vector<int32_t>& sizes = inner_->parameter_block_sizes();
  const int n = static_cast<int>(sizes.size());
  const double s = parameters[n][0];
  const double scale = sigma_ref_ * std::exp(-s);
  const double arg = std::max(0.0, 2.0 * (s - log_sigma_min_)) + 1.0;
  double g[3];
  std::vector<double*> inner_jac;
  bool any = false;
  if (jacobians != nullptr) {
    inner_jac.assign(n, nullptr);
    for (int i = 0; i < n; ++i) {
      inner_jac[i] = jacobians[i];
      any |= jacobians[i] != nullptr;
    }
  }
  // The inner Jacobians (3 x size_i, row-major) are written to the top of the
  // outer ones (4 x size_i) and rescaled; the last row is zero.
  if (!inner_->Evaluate(parameters, g, any ? inner_jac.data() : nullptr)) {
    return false;
  }
  for (int k = 0; k < 3; ++k) residuals[k] = scale * g[k];
  residuals[3] = weight_ * sigma_ref_ * std::sqrt(arg);
  if (jacobians == nullptr) return true;
  for (int i = 0; i < n; ++i) {
    if (jacobians[i] == nullptr) continue;
    Eigen::Map<RowMajorMatrix> jac(jacobians[i], 4, sizes[i]);
    jac.topRows<3>() *= scale;
    jac.row(3).setZero();
  }
  if (jacobians[n] != nullptr) {
    for (int k = 0; k < 3; ++k) jacobians[n][k] = -residuals[k];
    jacobians[n][3] = weight_ * sigma_ref_ / std::sqrt(arg);
    if (2.0 * (s - log_sigma_min_) < 0) jacobians[n][3] = 0.0;
  }
  return true;
}

}  // namespace soma
