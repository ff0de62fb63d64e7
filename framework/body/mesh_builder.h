// Generic meshing used by the procedural body (procedural_body.cc): implicit
// primitives (tapered capsules with elliptic cross-sections, ellipsoids)
// blended by an exponential soft-min into one surface with flat soles, and
// the mesher that turns that mirror-symmetric surface into a closed,
// exactly left/right symmetric triangle mesh (marching tetrahedra over
// x >= 0, shortest-edge-first collapse decimation, quality edge flips,
// mirroring and tangential relaxation). Nothing here knows about joints
// beyond the `owner` tags a primitive carries. Internal to the body module.
#pragma once

#include "framework/core/error.h"

#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <utility>
#include <vector>

namespace soma {
namespace internal {

/// The mirror image of `p` across the plane x = 0.
inline Eigen::Vector3d Mirror(const Eigen::Vector3d& p) {
  return {-p.x(), p.y(), p.z()};
}

// ---------------------------------------------------------------------------
// Primitives: tapered capsules with elliptic cross-sections (and ellipsoids,
// length 0), in a frame (d, e1, e2): d along the axis a -> b, e1 from `hint1`,
// e2 = d x e1 oriented along `hint2`.

struct Section {
  double t;   // position along the axis, 0 at a, 1 at b
  double r1;  // semi-axis along e1, metres
  double r2;  // semi-axis along e2
  double c1;  // centre offset along e1
  double c2;  // centre offset along e2
};

struct Primitive {
  Eigen::Vector3d a = Eigen::Vector3d::Zero();
  Eigen::Vector3d b = Eigen::Vector3d::Zero();
  Eigen::Vector3d hint1 = Eigen::Vector3d::UnitX();
  Eigen::Vector3d hint2 = Eigen::Vector3d::UnitY();
  Eigen::Vector3d axis_if_degenerate = Eigen::Vector3d::UnitZ();
  std::vector<Section> sections;  // t ascending, first 0, last 1
  double cap0 = 0.0;              // axial semi-length of the cap at a
  double cap1 = 0.0;              // ... at b
  int owner = 0;                  // joint whose segment this part is
  // Optional partition of the part among joints along t: (t, joint) means
  // "from t upwards the owner is joint"; blended over +-owner_blend metres.
  std::vector<std::pair<double, int>> owner_breaks;
  double owner_blend = 0.0;

  // Derived by Finalize().
  Eigen::Vector3d d = Eigen::Vector3d::UnitZ();
  Eigen::Vector3d e1 = Eigen::Vector3d::UnitX();
  Eigen::Vector3d e2 = Eigen::Vector3d::UnitY();
  double length = 0.0;

  void Finalize() {
    const Eigen::Vector3d ab = b - a;
    length = ab.norm();
    d = length > 1e-9 ? Eigen::Vector3d(ab / length)
                      : axis_if_degenerate.normalized();
    e1 = hint1 - hint1.dot(d) * d;
    SOMA_CHECK_GT(e1.norm(), 1e-6)
        << "primitive frame hint parallel to its axis";
    e1.normalize();
    e2 = d.cross(e1);
    if (e2.dot(hint2) < 0.0) e2 = -e2;
  }

  Section SectionAt(double t) const {
    if (t <= sections.front().t) return sections.front();
    for (size_t k = 1; k < sections.size(); ++k) {
      if (t <= sections[k].t) {
        const Section& s0 = sections[k - 1];
        const Section& s1 = sections[k];
        const double u = (t - s0.t) / std::max(s1.t - s0.t, 1e-12);
        return {t,
                s0.r1 + u * (s1.r1 - s0.r1),
                s0.r2 + u * (s1.r2 - s0.r2),
                s0.c1 + u * (s1.c1 - s0.c1),
                s0.c2 + u * (s1.c2 - s0.c2)};
      }
    }
    return sections.back();
  }

  void Bounds(Eigen::Vector3d* lo, Eigen::Vector3d* hi) const {
    double reach = std::max(cap0, cap1);
    for (const Section& s : sections) {
      reach = std::max(reach,
                       std::max(s.r1, s.r2) + std::abs(s.c1) + std::abs(s.c2));
    }
    *lo = a.cwiseMin(b) - Eigen::Vector3d::Constant(reach);
    *hi = a.cwiseMax(b) + Eigen::Vector3d::Constant(reach);
  }
};

/// Where a point sits relative to a primitive: axial position, normalised
/// radial coordinates and normalised overshoot past an end cap.
struct PrimitiveCoords {
  double t = 0.0;
  double n1 = 0.0;
  double n2 = 0.0;
  double nw = 0.0;
};

/// Approximate signed distance (Quilez' ellipsoid bound: exact on the
/// surface, first-order accurate nearby) and the point's coordinates
/// (`coords` may be null).
double PrimitiveField(const Primitive& prim,
                      const Eigen::Vector3d& p,
                      PrimitiveCoords* coords);

/// Inverse of the coordinates: the point with `coords` on (possibly another
/// anthropometry's version of) the same primitive.
Eigen::Vector3d PrimitivePoint(const Primitive& prim,
                               const PrimitiveCoords& coords);

/// A tapered capsule from `a` to `b` with the cross-sections `sections`
/// (t ascending, first 0, last 1) and end caps of `cap*_ratio` times the
/// smaller semi-axis of the end section; frame hints as in Primitive.
Primitive MakeSweep(const Eigen::Vector3d& a,
                    const Eigen::Vector3d& b,
                    std::vector<Section> sections,
                    double cap0_ratio,
                    double cap1_ratio,
                    int owner,
                    const Eigen::Vector3d& hint1,
                    const Eigen::Vector3d& hint2);

/// An axis-aligned ellipsoid with semi-axes rx, ry, rz.
Primitive MakeEllipsoid(
    const Eigen::Vector3d& centre, double rx, double ry, double rz, int owner);

/// A closed triangle mesh, exactly symmetric under x -> -x.
struct SymmetricMesh {
  Eigen::Matrix3Xd vertices;
  Eigen::Matrix3Xi faces;
  std::vector<int> mirror;  // mirror[v] = vertex at (-x, y, z)
  std::vector<char> seam;   // on the mirror plane x = 0
};

/// Options of MeshPrimitives (ProceduralBodyOptions checks the ranges).
struct MeshPrimitivesOptions {
  double grid_spacing = 0.010;  // marching-tetrahedra grid step, metres
  double blend_radius = 0.012;  // soft-min blend radius, metres
  int target_vertices = 7000;   // vertex count of the full mesh
  int relax_iterations = 4;     // tangential relaxation passes
};

/// Meshes the soft union of `prims` intersected with z >= 0. The primitives
/// must describe a body symmetric under x -> -x (only x >= 0 is sampled).
/// The result is checked to be a closed, consistently oriented 2-manifold
/// (SOMA_CHECK).
SymmetricMesh MeshPrimitives(const std::vector<Primitive>& prims,
                             const MeshPrimitivesOptions& options);

}  // namespace internal
}  // namespace soma
