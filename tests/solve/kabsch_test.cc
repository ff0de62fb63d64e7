#include "framework/solve/kabsch.h"

#include "framework/core/error.h"
#include "framework/core/random.h"

#include <gtest/gtest.h>

namespace soma {
namespace {

constexpr double kTol = 1e-10;

TEST(KabschAlign, RecoversRigidTransform) {
  Rng rng(1);
  Eigen::Matrix3Xd source(3, 10);
  for (int i = 0; i < source.size(); ++i) source.data()[i] = rng.Normal();
  const Eigen::Matrix3d r =
      Eigen::AngleAxisd(2.5, Eigen::Vector3d(1, -2, 0.5).normalized())
          .toRotationMatrix();
  const Eigen::Vector3d t(0.3, -1.0, 2.0);
  const Eigen::Matrix3Xd target = (r * source).colwise() + t;
  const Eigen::Isometry3d align = KabschAlign(source, target);
  EXPECT_LT((align.linear() - r).norm(), kTol);
  EXPECT_LT((align.translation() - t).norm(), kTol);
}

TEST(KabschAlign, NeverReturnsAReflection) {
  Rng rng(2);
  Eigen::Matrix3Xd source(3, 6);
  for (int i = 0; i < source.size(); ++i) source.data()[i] = rng.Normal();
  // Mirrored target: the best proper rotation, det +1.
  Eigen::Matrix3Xd target = source;
  target.row(0) *= -1.0;
  const Eigen::Isometry3d align = KabschAlign(source, target);
  EXPECT_NEAR(align.linear().determinant(), 1.0, kTol);
  EXPECT_LT((align.linear() * align.linear().transpose() -
             Eigen::Matrix3d::Identity())
                .norm(),
            kTol);
}

TEST(KabschAlign, LeastSquaresUnderNoise) {
  Rng rng(3);
  Eigen::Matrix3Xd source(3, 200);
  for (int i = 0; i < source.size(); ++i) source.data()[i] = rng.Normal();
  const Eigen::Matrix3d r =
      Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  Eigen::Matrix3Xd target = r * source;
  for (int i = 0; i < target.size(); ++i)
    target.data()[i] += 0.01 * rng.Normal();
  const Eigen::Isometry3d align = KabschAlign(source, target);
  EXPECT_LT((align.linear() - r).norm(), 5e-3);
}

TEST(KabschAlign, BadInput) {
  const Eigen::Matrix3Xd two = Eigen::Matrix3Xd::Random(3, 2);
  EXPECT_THROW(KabschAlign(two, two), ShapeError);
  const Eigen::Matrix3Xd four = Eigen::Matrix3Xd::Random(3, 4);
  EXPECT_THROW(KabschAlign(four, Eigen::Matrix3Xd::Random(3, 5)), ShapeError);
  Eigen::Matrix3Xd nan = four;
  nan(1, 2) = std::nan("");
  EXPECT_THROW(KabschAlign(four, nan), ShapeError);
}

}  // namespace
}  // namespace soma
