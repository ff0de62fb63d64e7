// Shared fixtures of the body tests: the procedural body is built once per
// test process (it takes a fraction of a second) and mesh checks.
#pragma once

#include "framework/body/body_model.h"
#include "framework/body/procedural_body.h"

#include <Eigen/Core>

#include <cmath>

namespace soma::testing {

/// The default procedural body, built on first use.
inline const BodyModel& ProceduralBody() {
  static const BodyModel* const kBody = new BodyModel(MakeProceduralBody());
  return *kBody;
}

/// Ray-parity point-in-mesh test (three skew directions, majority vote).
inline bool PointInsideMesh(const Eigen::Matrix3Xd& vertices,
                            const Eigen::Matrix3Xi& faces,
                            const Eigen::Vector3d& point) {
  const Eigen::Vector3d dirs[3] = {
      Eigen::Vector3d(0.5773, 0.3119, 0.7543).normalized(),
      Eigen::Vector3d(-0.2134, 0.9111, -0.3527).normalized(),
      Eigen::Vector3d(0.8317, -0.4409, 0.3376).normalized()};
  int inside_votes = 0;
  for (const auto& dir : dirs) {
    int crossings = 0;
    for (Eigen::Index f = 0; f < faces.cols(); ++f) {
      const Eigen::Vector3d a = vertices.col(faces(0, f));
      const Eigen::Vector3d e1 = vertices.col(faces(1, f)) - a;
      const Eigen::Vector3d e2 = vertices.col(faces(2, f)) - a;
      const Eigen::Vector3d p = dir.cross(e2);
      const double det = e1.dot(p);
      if (std::abs(det) < 1e-15) continue;
      const Eigen::Vector3d s = point - a;
      const double u = s.dot(p) / det;
      if (u < 0 || u > 1) continue;
      const Eigen::Vector3d q = s.cross(e1);
      const double v = dir.dot(q) / det;
      if (v < 0 || u + v > 1) continue;
      if (e2.dot(q) / det > 0) ++crossings;
    }
    if (crossings % 2 == 1) ++inside_votes;
  }
  return inside_votes >= 2;
}

}  // namespace soma::testing
