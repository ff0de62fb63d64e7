#include "framework/solve/cost_functions.h"

#include "framework/core/error.h"

#include <ceres/normal_prior.h>

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
