#include "framework/solve/kabsch.h"

#include "framework/core/error.h"

#include <Eigen/SVD>
#include <fmt/format.h>

namespace soma {

Eigen::Isometry3d KabschAlign(const Eigen::Matrix3Xd& source,
                              const Eigen::Matrix3Xd& target) {
  if (source.cols() != target.cols()) {
    throw ShapeError(fmt::format("KabschAlign: {} source points, {} target",
                                 source.cols(),
                                 target.cols()));
  }
  if (source.cols() < 3) {
    throw ShapeError(fmt::format("KabschAlign: needs at least 3 points, got {}",
                                 source.cols()));
  }
  if (!source.allFinite() || !target.allFinite()) {
    throw ShapeError("KabschAlign: non-finite point");
  }
  const Eigen::Vector3d source_mean = source.rowwise().mean();
  const Eigen::Vector3d target_mean = target.rowwise().mean();
  const Eigen::Matrix3d cov = (target.colwise() - target_mean) *
                              (source.colwise() - source_mean).transpose();
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(
      cov, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
  if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0) {
    d(2, 2) = -1.0;
  }
  Eigen::Isometry3d target_from_source = Eigen::Isometry3d::Identity();
  target_from_source.linear() = svd.matrixU() * d * svd.matrixV().transpose();
  target_from_source.translation() =
      target_mean - target_from_source.linear() * source_mean;
  return target_from_source;
}

}  // namespace soma
