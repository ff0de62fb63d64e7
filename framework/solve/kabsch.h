// Rigid (Kabsch / Procrustes) alignment of two point sets, the
// initialisation of stage I and of the first frame of stage II
// (REFERENCE.md 7.3: "SVD with reflection fix").
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace soma {

/// The rotation and translation minimising sum_i |R a_i + t - b_i|^2 over
/// the columns of `source` (a) and `target` (b), 3 x N each. R is a proper
/// rotation (det +1; a reflection of the SVD solution is flipped). Throws
/// ShapeError for N < 3, different sizes or non-finite points. Degenerate
/// (collinear) sets give one of the minimisers.
Eigen::Isometry3d KabschAlign(const Eigen::Matrix3Xd& source,
                              const Eigen::Matrix3Xd& target);

}  // namespace soma
