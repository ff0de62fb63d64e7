#include "framework/body/mesh_builder.h"

#include <Eigen/Core>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <set>
#include <utility>
#include <vector>

namespace soma::internal {
namespace {

using Eigen::Vector3d;

TEST(Primitive, CoordinatesRoundTripThroughPrimitivePoint) {
  const Primitive sweep = MakeSweep({0.1, 0.0, 0.2},
                                    {0.1, 0.05, 0.6},
                                    {{0.0, 0.05, 0.04, 0.0, 0.0},
                                     {0.5, 0.07, 0.05, 0.01, 0.0},
                                     {1.0, 0.04, 0.03, 0.0, 0.01}},
                                    1.0,
                                    0.5,
                                    /*owner=*/3,
                                    Vector3d::UnitX(),
                                    Vector3d::UnitY());
  EXPECT_EQ(sweep.owner, 3);
  for (const Vector3d& p : {Vector3d(0.1, 0.0, 0.4),
                            Vector3d(0.15, 0.02, 0.1),
                            Vector3d(0.0, -0.1, 0.7)}) {
    PrimitiveCoords coords;
    PrimitiveField(sweep, p, &coords);
    EXPECT_LT((PrimitivePoint(sweep, coords) - p).norm(), 1e-12);
  }
}

TEST(Primitive, EllipsoidFieldIsZeroOnItsSurfaceAndNegativeInside) {
  const Primitive e = MakeEllipsoid({0.0, 0.0, 0.5}, 0.1, 0.2, 0.3, 0);
  EXPECT_NEAR(PrimitiveField(e, {0.1, 0.0, 0.5}, nullptr), 0.0, 1e-12);
  EXPECT_NEAR(PrimitiveField(e, {0.0, -0.2, 0.5}, nullptr), 0.0, 1e-12);
  EXPECT_NEAR(PrimitiveField(e, {0.0, 0.0, 0.8}, nullptr), 0.0, 1e-12);
  EXPECT_LT(PrimitiveField(e, {0.0, 0.0, 0.5}, nullptr), 0.0);
  EXPECT_GT(PrimitiveField(e, {0.2, 0.0, 0.5}, nullptr), 0.0);
  EXPECT_NEAR(PrimitiveField(e, {0.2, 0.0, 0.5}, nullptr), 0.1, 0.02);
}

TEST(MeshPrimitives, MeshesAnEllipsoidIntoAClosedSymmetricSphere) {
  const Primitive e = MakeEllipsoid({0.0, 0.0, 0.3}, 0.1, 0.08, 0.2, 0);
  MeshPrimitivesOptions options;
  options.grid_spacing = 0.01;
  options.target_vertices = 1200;
  options.relax_iterations = 2;
  const SymmetricMesh mesh = MeshPrimitives({e}, options);
  const int nv = static_cast<int>(mesh.vertices.cols());
  const int nf = static_cast<int>(mesh.faces.cols());
  ASSERT_GT(nv, 200);
  EXPECT_LE(nv, options.target_vertices + 50);
  // Genus 0: V - E + F = 2 with E = 3F/2 on a closed triangle mesh.
  EXPECT_EQ(nv - 3 * nf / 2 + nf, 2);
  ASSERT_EQ(mesh.mirror.size(), static_cast<size_t>(nv));
  ASSERT_EQ(mesh.seam.size(), static_cast<size_t>(nv));
  int seam_count = 0;
  for (int v = 0; v < nv; ++v) {
    const Vector3d p = mesh.vertices.col(v);
    EXPECT_EQ(mesh.mirror[mesh.mirror[v]], v);
    EXPECT_EQ(Vector3d(mesh.vertices.col(mesh.mirror[v])), Mirror(p));
    if (mesh.seam[v]) {
      ++seam_count;
      EXPECT_EQ(p.x(), 0.0);
      EXPECT_EQ(mesh.mirror[v], v);
    }
    EXPECT_LT(std::abs(PrimitiveField(e, p, nullptr)), 0.003) << v;
  }
  EXPECT_GT(seam_count, 10);
  // Every face is a distinct triple of distinct vertices.
  std::set<std::vector<int>> faces;
  for (int f = 0; f < nf; ++f) {
    std::vector<int> tri = {
        mesh.faces(0, f), mesh.faces(1, f), mesh.faces(2, f)};
    std::sort(tri.begin(), tri.end());
    EXPECT_TRUE(tri[0] != tri[1] && tri[1] != tri[2]);
    EXPECT_TRUE(faces.insert(tri).second);
  }
}

}  // namespace
}  // namespace soma::internal
