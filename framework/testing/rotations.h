// Elementary rotations written out explicitly, for tests that check
// kinematics against matrices computed independently of the code under test.
#pragma once

#include <Eigen/Core>

#include <cmath>

namespace soma::testing {

inline constexpr double kPi = 3.14159265358979323846;

/// Rotation about +X by `degrees` (right-handed).
inline Eigen::Matrix3d Rx(double degrees) {
  const double c = std::cos(degrees * kPi / 180),
               s = std::sin(degrees * kPi / 180);
  Eigen::Matrix3d m;
  m << 1, 0, 0, 0, c, -s, 0, s, c;
  return m;
}

/// Rotation about +Y by `degrees`.
inline Eigen::Matrix3d Ry(double degrees) {
  const double c = std::cos(degrees * kPi / 180),
               s = std::sin(degrees * kPi / 180);
  Eigen::Matrix3d m;
  m << c, 0, s, 0, 1, 0, -s, 0, c;
  return m;
}

/// Rotation about +Z by `degrees`.
inline Eigen::Matrix3d Rz(double degrees) {
  const double c = std::cos(degrees * kPi / 180),
               s = std::sin(degrees * kPi / 180);
  Eigen::Matrix3d m;
  m << c, -s, 0, s, c, 0, 0, 0, 1;
  return m;
}

}  // namespace soma::testing
