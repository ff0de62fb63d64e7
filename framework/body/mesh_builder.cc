#include "framework/body/mesh_builder.h"

#include "framework/body/body_model.h"
#include "framework/core/error.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <iterator>
#include <limits>
#include <unordered_map>
#include <utility>

namespace soma {
namespace internal {

using Eigen::Vector3d;

double PrimitiveField(const Primitive& prim,
                      const Vector3d& p,
                      PrimitiveCoords* coords) {
  const Vector3d q = p - prim.a;
  const double s = q.dot(prim.d);
  double tc = 0.0;
  double w = s;
  if (prim.length > 1e-9) {
    tc = std::clamp(s / prim.length, 0.0, 1.0);
    w = s - tc * prim.length;
  }
  const Section sec = prim.SectionAt(tc);
  const double x1 = q.dot(prim.e1) - sec.c1;
  const double x2 = q.dot(prim.e2) - sec.c2;
  const double r3 = w < 0.0 ? prim.cap0 : prim.cap1;
  const double u1 = x1 / sec.r1;
  const double u2 = x2 / sec.r2;
  const double u3 = w / r3;
  if (coords != nullptr) *coords = {tc, u1, u2, u3};
  const double k0 = std::sqrt(u1 * u1 + u2 * u2 + u3 * u3);
  const double v1 = u1 / sec.r1;
  const double v2 = u2 / sec.r2;
  const double v3 = u3 / r3;
  const double k1 = std::sqrt(v1 * v1 + v2 * v2 + v3 * v3);
  if (k1 < 1e-12) return -std::min({sec.r1, sec.r2, r3});
  return k0 * (k0 - 1.0) / k1;
}

Vector3d PrimitivePoint(const Primitive& prim, const PrimitiveCoords& coords) {
  const Section sec = prim.SectionAt(coords.t);
  const double r3 = coords.nw < 0.0 ? prim.cap0 : prim.cap1;
  return prim.a + (coords.t * prim.length + coords.nw * r3) * prim.d +
         (sec.c1 + coords.n1 * sec.r1) * prim.e1 +
         (sec.c2 + coords.n2 * sec.r2) * prim.e2;
}

Primitive MakeSweep(const Vector3d& a,
                    const Vector3d& b,
                    std::vector<Section> sections,
                    double cap0_ratio,
                    double cap1_ratio,
                    int owner,
                    const Vector3d& hint1,
                    const Vector3d& hint2) {
  Primitive prim;
  prim.a = a;
  prim.b = b;
  prim.sections = std::move(sections);
  prim.hint1 = hint1;
  prim.hint2 = hint2;
  prim.owner = owner;
  const Section& s0 = prim.sections.front();
  const Section& s1 = prim.sections.back();
  prim.cap0 = cap0_ratio * std::min(s0.r1, s0.r2);
  prim.cap1 = cap1_ratio * std::min(s1.r1, s1.r2);
  prim.Finalize();
  return prim;
}

Primitive MakeEllipsoid(
    const Vector3d& centre, double rx, double ry, double rz, int owner) {
  Primitive prim;
  prim.a = centre;
  prim.b = centre;
  prim.axis_if_degenerate = Vector3d::UnitZ();
  prim.hint1 = Vector3d::UnitX();
  prim.hint2 = Vector3d::UnitY();
  prim.sections = {{0.0, rx, ry, 0.0, 0.0}, {1.0, rx, ry, 0.0, 0.0}};
  prim.cap0 = rz;
  prim.cap1 = rz;
  prim.owner = owner;
  prim.Finalize();
  return prim;
}

namespace {

// ---------------------------------------------------------------------------
// The implicit surface on a grid over x >= 0 (the body is mirror symmetric).

class FieldGrid {
 public:
  FieldGrid(const std::vector<Primitive>& prims, double spacing, double blend)
      : h_(spacing), blend_(blend) {
    Vector3d lo = Vector3d::Constant(std::numeric_limits<double>::max());
    Vector3d hi = -lo;
    for (const Primitive& prim : prims) {
      Vector3d a, b;
      prim.Bounds(&a, &b);
      lo = lo.cwiseMin(a);
      hi = hi.cwiseMax(b);
    }
    const double margin = 3.0 * h_;
    y0_ = lo.y() - margin;
    z0_ = -margin;  // soles at z = 0
    nx_ = static_cast<int>(std::ceil((hi.x() + margin) / h_)) + 1;
    ny_ = static_cast<int>(std::ceil((hi.y() + margin - y0_) / h_)) + 1;
    nz_ = static_cast<int>(std::ceil((hi.z() + margin - z0_) / h_)) + 1;
    const size_t n = static_cast<size_t>(nx_) * ny_ * nz_;
    std::vector<double> acc(n, 0.0);
    for (const Primitive& prim : prims) {
      Vector3d a, b;
      prim.Bounds(&a, &b);
      a -= Vector3d::Constant(kBand);
      b += Vector3d::Constant(kBand);
      const int i0 = std::max(0, static_cast<int>(std::floor(a.x() / h_)));
      const int i1 = std::min(nx_ - 1, static_cast<int>(std::ceil(b.x() / h_)));
      const int j0 =
          std::max(0, static_cast<int>(std::floor((a.y() - y0_) / h_)));
      const int j1 =
          std::min(ny_ - 1, static_cast<int>(std::ceil((b.y() - y0_) / h_)));
      const int k0 =
          std::max(0, static_cast<int>(std::floor((a.z() - z0_) / h_)));
      const int k1 =
          std::min(nz_ - 1, static_cast<int>(std::ceil((b.z() - z0_) / h_)));
      for (int k = k0; k <= k1; ++k) {
        for (int j = j0; j <= j1; ++j) {
          for (int i = i0; i <= i1; ++i) {
            const double f = PrimitiveField(prim, Node(i, j, k), nullptr);
            if (f < kBand)
              acc[Index(i, j, k)] += std::exp(-std::max(f, -kDeep) / blend_);
          }
        }
      }
    }
    values_.resize(n);
    for (int k = 0; k < nz_; ++k) {
      const double z = z0_ + k * h_;
      for (int j = 0; j < ny_; ++j) {
        for (int i = 0; i < nx_; ++i) {
          const size_t idx = Index(i, j, k);
          const double body =
              acc[idx] > 0.0 ? -blend_ * std::log(acc[idx]) : kBand;
          values_[idx] = FloorClip(body, z);
        }
      }
    }
  }

  /// Smooth intersection with the half-space z >= 0 (flat soles).
  static double FloorClip(double body, double z) {
    const double a = body;
    const double b = -z;
    const double m = std::max(a, b);
    return m + kSoleBlend * std::log1p(std::exp(-std::abs(a - b) / kSoleBlend));
  }

  int nx() const { return nx_; }
  int ny() const { return ny_; }
  int nz() const { return nz_; }
  double spacing() const { return h_; }
  size_t Index(int i, int j, int k) const {
    return (static_cast<size_t>(k) * ny_ + j) * nx_ + i;
  }
  Vector3d Node(int i, int j, int k) const {
    return {i * h_, y0_ + j * h_, z0_ + k * h_};
  }
  double Value(int i, int j, int k) const { return values_[Index(i, j, k)]; }

  /// Trilinear value and gradient at p (x < 0 by mirror symmetry).
  double Sample(const Vector3d& p, Vector3d* gradient) const {
    const bool mirrored = p.x() < 0.0;
    const double gx = (mirrored ? -p.x() : p.x()) / h_;
    const double gy = (p.y() - y0_) / h_;
    const double gz = (p.z() - z0_) / h_;
    const int i = std::clamp(static_cast<int>(std::floor(gx)), 0, nx_ - 2);
    const int j = std::clamp(static_cast<int>(std::floor(gy)), 0, ny_ - 2);
    const int k = std::clamp(static_cast<int>(std::floor(gz)), 0, nz_ - 2);
    const double u = std::clamp(gx - i, 0.0, 1.0);
    const double v = std::clamp(gy - j, 0.0, 1.0);
    const double w = std::clamp(gz - k, 0.0, 1.0);
    double c[2][2][2];
    for (int dk = 0; dk < 2; ++dk) {
      for (int dj = 0; dj < 2; ++dj) {
        for (int di = 0; di < 2; ++di)
          c[dk][dj][di] = Value(i + di, j + dj, k + dk);
      }
    }
    const auto lerp = [](double a, double b, double t) {
      return a + t * (b - a);
    };
    const double c00 = lerp(c[0][0][0], c[0][0][1], u);
    const double c01 = lerp(c[0][1][0], c[0][1][1], u);
    const double c10 = lerp(c[1][0][0], c[1][0][1], u);
    const double c11 = lerp(c[1][1][0], c[1][1][1], u);
    const double c0 = lerp(c00, c01, v);
    const double c1 = lerp(c10, c11, v);
    if (gradient != nullptr) {
      const double dx0 =
          lerp(c[0][0][1] - c[0][0][0], c[0][1][1] - c[0][1][0], v);
      const double dx1 =
          lerp(c[1][0][1] - c[1][0][0], c[1][1][1] - c[1][1][0], v);
      const double dx = lerp(dx0, dx1, w) / h_;
      const double dy = lerp(c01 - c00, c11 - c10, w) / h_;
      const double dz = (c1 - c0) / h_;
      *gradient = Vector3d(mirrored ? -dx : dx, dy, dz);
    }
    return lerp(c0, c1, w);
  }

  /// Newton steps onto the zero level set; `on_seam` keeps x = 0.
  void Project(Vector3d* p, bool on_seam) const {
    for (int iter = 0; iter < 4; ++iter) {
      Vector3d g;
      const double f = Sample(*p, &g);
      if (on_seam) g.x() = 0.0;
      const double g2 = g.squaredNorm();
      if (g2 < 1e-12) return;
      Vector3d step = (f / g2) * g;
      const double len = step.norm();
      if (len > h_) step *= h_ / len;
      *p -= step;
      if (std::abs(f) < 1e-7) return;
    }
  }

 private:
  static constexpr double kBand = 0.06;  // primitives farther away are ignored
  static constexpr double kDeep = 0.3;   // clamp of deep-inside values
  static constexpr double kSoleBlend = 0.003;

  double h_;
  double blend_;
  double y0_ = 0.0;
  double z0_ = 0.0;
  int nx_ = 0;
  int ny_ = 0;
  int nz_ = 0;
  std::vector<double> values_;
};

// ---------------------------------------------------------------------------
// Marching tetrahedra (Kuhn decomposition of each cube into 6 tetrahedra
// around its main diagonal; consistent across cubes, so the result is a
// closed 2-manifold wherever the surface stays inside the grid).

struct HalfMesh {
  std::vector<Vector3d> vertices;
  std::vector<char> seam;  // on x = 0 (the boundary of the half mesh)
  std::vector<std::array<int, 3>> faces;
};

HalfMesh MarchingTetrahedra(const FieldGrid& grid) {
  HalfMesh mesh;
  std::unordered_map<uint64_t, int> edge_vertex;
  edge_vertex.reserve(1 << 17);
  const int nx = grid.nx();
  const int ny = grid.ny();
  const int nz = grid.nz();
  static constexpr int kTets[6][4] = {{0, 1, 3, 7},
                                      {0, 1, 5, 7},
                                      {0, 2, 3, 7},
                                      {0, 2, 6, 7},
                                      {0, 4, 5, 7},
                                      {0, 4, 6, 7}};
  auto corner_node = [](int i, int j, int k, int c, int* ci, int* cj, int* ck) {
    *ci = i + (c & 1);
    *cj = j + ((c >> 1) & 1);
    *ck = k + ((c >> 2) & 1);
  };
  auto edge_point = [&](int i, int j, int k, int ca, int cb) -> int {
    // ca is a bit-subset of cb (Kuhn chains are monotone).
    int ai, aj, ak, bi, bj, bk;
    corner_node(i, j, k, ca, &ai, &aj, &ak);
    corner_node(i, j, k, cb, &bi, &bj, &bk);
    const uint64_t key =
        static_cast<uint64_t>(grid.Index(ai, aj, ak)) * 8 + (ca ^ cb);
    const auto it = edge_vertex.find(key);
    if (it != edge_vertex.end()) return it->second;
    const double fa = grid.Value(ai, aj, ak);
    const double fb = grid.Value(bi, bj, bk);
    const double t = std::clamp(fa / (fa - fb), 0.02, 0.98);
    const Vector3d pa = grid.Node(ai, aj, ak);
    const Vector3d pb = grid.Node(bi, bj, bk);
    const int id = static_cast<int>(mesh.vertices.size());
    mesh.vertices.push_back(pa + t * (pb - pa));
    mesh.seam.push_back(ai == 0 && bi == 0 ? 1 : 0);
    edge_vertex.emplace(key, id);
    return id;
  };
  auto add_triangle = [&](int v0, int v1, int v2, const Vector3d& outward) {
    const Vector3d n = (mesh.vertices[v1] - mesh.vertices[v0])
                           .cross(mesh.vertices[v2] - mesh.vertices[v0]);
    if (n.dot(outward) >= 0.0) {
      mesh.faces.push_back({v0, v1, v2});
    } else {
      mesh.faces.push_back({v0, v2, v1});
    }
  };
  for (int k = 0; k + 1 < nz; ++k) {
    for (int j = 0; j + 1 < ny; ++j) {
      for (int i = 0; i + 1 < nx; ++i) {
        double f[8];
        int inside_count = 0;
        for (int c = 0; c < 8; ++c) {
          f[c] =
              grid.Value(i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1));
          if (f[c] < 0.0) ++inside_count;
        }
        if (inside_count == 0 || inside_count == 8) continue;
        for (const auto& tet : kTets) {
          int in[4], out[4];
          int n_in = 0, n_out = 0;
          for (const int c : tet) {
            if (f[c] < 0.0) {
              in[n_in++] = c;
            } else {
              out[n_out++] = c;
            }
          }
          if (n_in == 0 || n_out == 0) continue;
          Vector3d in_centre = Vector3d::Zero();
          Vector3d out_centre = Vector3d::Zero();
          for (int q = 0; q < n_in; ++q) {
            in_centre += grid.Node(
                i + (in[q] & 1), j + ((in[q] >> 1) & 1), k + (in[q] >> 2));
          }
          for (int q = 0; q < n_out; ++q) {
            out_centre += grid.Node(
                i + (out[q] & 1), j + ((out[q] >> 1) & 1), k + (out[q] >> 2));
          }
          const Vector3d outward = out_centre / n_out - in_centre / n_in;
          auto ep = [&](int c0, int c1) {
            return c0 < c1 ? edge_point(i, j, k, c0, c1)
                           : edge_point(i, j, k, c1, c0);
          };
          if (n_in == 1 || n_out == 1) {
            const int apex = n_in == 1 ? in[0] : out[0];
            const int* others = n_in == 1 ? out : in;
            add_triangle(ep(apex, others[0]),
                         ep(apex, others[1]),
                         ep(apex, others[2]),
                         outward);
          } else {
            // Quad: in {a, b}, out {c, d}; cycle ac, ad, bd, bc.
            const int ac = ep(in[0], out[0]);
            const int ad = ep(in[0], out[1]);
            const int bd = ep(in[1], out[1]);
            const int bc = ep(in[1], out[0]);
            add_triangle(ac, ad, bd, outward);
            add_triangle(ac, bd, bc, outward);
          }
        }
      }
    }
  }
  return mesh;
}

// ---------------------------------------------------------------------------
// Shortest-edge-first collapse decimation of the half mesh. Seam vertices
// (x = 0) only collapse along the seam; an interior vertex collapses into a
// seam vertex; no interior edge may join two seam vertices (the mirrored mesh
// would be non-manifold there). The link condition keeps the mesh a
// manifold, the normal test prevents fold-overs.

double TriangleQuality(const Vector3d& a,
                       const Vector3d& b,
                       const Vector3d& c) {
  const double area2 = (b - a).cross(c - a).norm();  // 2 * area
  const double sum_sq =
      (b - a).squaredNorm() + (c - b).squaredNorm() + (a - c).squaredNorm();
  if (sum_sq <= 0.0) return 0.0;
  return 2.0 * std::sqrt(3.0) * area2 / sum_sq;  // 1 for equilateral
}

class Decimator {
 public:
  /// Largest allowed angle between a new face and the surface normal: 70 deg.
  static constexpr double kMinNormalCosine = 0.34;

  Decimator(HalfMesh* mesh, const FieldGrid* grid) : mesh_(mesh), grid_(grid) {
    const int nv = static_cast<int>(mesh_->vertices.size());
    vertex_alive_.assign(nv, 1);
    face_alive_.assign(mesh_->faces.size(), 1);
    stamp_.assign(nv, 0);
    vertex_faces_.resize(nv);
    for (size_t f = 0; f < mesh_->faces.size(); ++f) {
      for (const int v : mesh_->faces[f])
        vertex_faces_[v].push_back(static_cast<int>(f));
    }
    alive_ = nv;
    alive_seam_ = 0;
    for (const char s : mesh_->seam) alive_seam_ += s;
  }

  void Run(int target_full_vertices) {
    // Edges rejected once may become collapsible after their neighbourhood
    // changed: re-seed the queue with every live edge a few times.
    for (int round = 0; round < 6 && FullCount() > target_full_vertices;
         ++round) {
      // Each undirected edge once (seam edges have a single face).
      for (size_t f = 0; f < mesh_->faces.size(); ++f) {
        if (!face_alive_[f]) continue;
        const auto& tri = mesh_->faces[f];
        for (int e = 0; e < 3; ++e) {
          const int a = tri[e];
          const int b = tri[(e + 1) % 3];
          if (a < b || (mesh_->seam[a] && mesh_->seam[b])) {
            Push(std::min(a, b), std::max(a, b));
          }
        }
      }
      int collapses = 0;
      Entry entry;
      while (FullCount() > target_full_vertices && queue_.Pop(&entry)) {
        if (!vertex_alive_[entry.a] || !vertex_alive_[entry.b]) continue;
        if (stamp_[entry.a] != entry.stamp_a ||
            stamp_[entry.b] != entry.stamp_b) {
          continue;
        }
        collapses += TryCollapse(entry.a, entry.b) ? 1 : 0;
      }
      queue_.Clear();
      if (collapses == 0) break;
    }
  }

  /// Removes dead vertices and faces.
  void Compact() {
    std::vector<int> remap(mesh_->vertices.size(), -1);
    HalfMesh out;
    for (size_t v = 0; v < mesh_->vertices.size(); ++v) {
      if (!vertex_alive_[v]) continue;
      remap[v] = static_cast<int>(out.vertices.size());
      out.vertices.push_back(mesh_->vertices[v]);
      out.seam.push_back(mesh_->seam[v]);
    }
    for (size_t f = 0; f < mesh_->faces.size(); ++f) {
      if (!face_alive_[f]) continue;
      const auto& tri = mesh_->faces[f];
      out.faces.push_back({remap[tri[0]], remap[tri[1]], remap[tri[2]]});
    }
    *mesh_ = std::move(out);
  }

 private:
  struct Entry {
    int a = 0, b = 0;
    int stamp_a = 0, stamp_b = 0;
  };

  /// Shortest-edge-first order up to kBucketWidth: a bucket queue (O(1)
  /// push/pop, cache friendly) instead of a binary heap over ~10^5 edges.
  /// LIFO within a bucket, so the order is deterministic.
  class EdgeQueue {
   public:
    static constexpr double kBucketWidth = 2.5e-4;  // metres
    static constexpr int kNumBuckets = 800;         // edges up to 20 cm

    void Push(double length, const Entry& entry) {
      const int bucket =
          std::min(kNumBuckets - 1, static_cast<int>(length / kBucketWidth));
      buckets_[bucket].push_back(entry);
      first_ = std::min(first_, bucket);
    }
    bool Pop(Entry* entry) {
      while (first_ < kNumBuckets && buckets_[first_].empty()) ++first_;
      if (first_ == kNumBuckets) return false;
      *entry = buckets_[first_].back();
      buckets_[first_].pop_back();
      return true;
    }
    void Clear() {
      for (auto& bucket : buckets_) bucket.clear();
      first_ = kNumBuckets;
    }

   private:
    std::vector<std::vector<Entry>> buckets_ =
        std::vector<std::vector<Entry>>(kNumBuckets);
    int first_ = kNumBuckets;
  };

  int FullCount() const { return 2 * alive_ - alive_seam_; }

  void Push(int a, int b) {
    queue_.Push((mesh_->vertices[a] - mesh_->vertices[b]).norm(),
                {a, b, stamp_[a], stamp_[b]});
  }

  void Neighbours(int v, std::vector<int>* out) const {
    out->clear();
    for (const int f : vertex_faces_[v]) {
      for (const int u : mesh_->faces[f]) {
        if (u != v) out->push_back(u);
      }
    }
    std::sort(out->begin(), out->end());
    out->erase(std::unique(out->begin(), out->end()), out->end());
  }

  static bool Contains(const std::array<int, 3>& tri, int v) {
    return tri[0] == v || tri[1] == v || tri[2] == v;
  }

  bool TryCollapse(int a, int b) {
    auto& seam = mesh_->seam;
    if (!seam[a] && seam[b]) std::swap(a, b);  // keep the seam vertex
    const bool both_seam = seam[a] && seam[b];
    shared_.clear();
    for (const int f : vertex_faces_[a]) {
      if (Contains(mesh_->faces[f], b)) shared_.push_back(f);
    }
    if (both_seam ? shared_.size() != 1 : shared_.size() != 2) return false;
    opposite_.clear();
    for (const int f : shared_) {
      for (const int u : mesh_->faces[f]) {
        if (u != a && u != b) opposite_.push_back(u);
      }
    }
    std::sort(opposite_.begin(), opposite_.end());
    Neighbours(a, &na_);
    Neighbours(b, &nb_);
    common_.clear();
    std::set_intersection(na_.begin(),
                          na_.end(),
                          nb_.begin(),
                          nb_.end(),
                          std::back_inserter(common_));
    if (common_ != opposite_) return false;  // link condition
    if (seam[a] && !seam[b]) {
      for (const int c : nb_) {
        if (c != a && seam[c] &&
            !std::binary_search(common_.begin(), common_.end(), c)) {
          return false;  // would create an interior seam-to-seam edge
        }
      }
    }
    const size_t remaining =
        vertex_faces_[a].size() + vertex_faces_[b].size() - 2 * shared_.size();
    if (remaining < (seam[a] ? 2u : 3u)) return false;

    Vector3d p;
    if (both_seam) {
      p = 0.5 * (mesh_->vertices[a] + mesh_->vertices[b]);
      p.x() = 0.0;
      grid_->Project(&p, true);
      p.x() = 0.0;
    } else if (seam[a]) {
      p = mesh_->vertices[a];
    } else {
      p = 0.5 * (mesh_->vertices[a] + mesh_->vertices[b]);
      grid_->Project(&p, false);
    }
    // Geometric checks on every surviving face around a and b.
    for (const int v : {a, b}) {
      for (const int f : vertex_faces_[v]) {
        if (std::find(shared_.begin(), shared_.end(), f) != shared_.end())
          continue;
        const auto& tri = mesh_->faces[f];
        Vector3d before[3], after[3];
        for (int q = 0; q < 3; ++q) {
          before[q] = mesh_->vertices[tri[q]];
          after[q] = (tri[q] == a || tri[q] == b) ? p : before[q];
        }
        const Vector3d n0 =
            (before[1] - before[0]).cross(before[2] - before[0]);
        const Vector3d n1 = (after[1] - after[0]).cross(after[2] - after[0]);
        const double l0 = n0.norm();
        const double l1 = n1.norm();
        if (l1 < 1e-14) return false;
        if (l0 > 1e-14 && n0.dot(n1) < 0.0) return false;  // flipped
        // The new face must face the way the surface does (the MT faces
        // themselves are noisy, so compare with the field gradient).
        Vector3d gradient;
        grid_->Sample((after[0] + after[1] + after[2]) / 3.0, &gradient);
        if (n1.dot(gradient) < kMinNormalCosine * l1 * gradient.norm())
          return false;
        const double q1 = TriangleQuality(after[0], after[1], after[2]);
        if (q1 < 0.1 && q1 < TriangleQuality(before[0], before[1], before[2])) {
          return false;
        }
      }
    }
    // Apply: b disappears into a.
    for (const int f : shared_) {
      face_alive_[f] = 0;
      for (const int u : mesh_->faces[f]) {
        auto& list = vertex_faces_[u];
        list.erase(std::remove(list.begin(), list.end(), f), list.end());
      }
    }
    for (const int f : vertex_faces_[b]) {
      for (int& u : mesh_->faces[f]) {
        if (u == b) u = a;
      }
      vertex_faces_[a].push_back(f);
    }
    vertex_faces_[b].clear();
    vertex_alive_[b] = 0;
    --alive_;
    if (seam[b]) --alive_seam_;
    mesh_->vertices[a] = p;
    ++stamp_[a];
    Neighbours(a, &na_);
    for (const int u : na_) Push(std::min(a, u), std::max(a, u));
    return true;
  }

  HalfMesh* mesh_;
  const FieldGrid* grid_;
  std::vector<char> vertex_alive_;
  std::vector<char> face_alive_;
  std::vector<int> stamp_;
  std::vector<std::vector<int>> vertex_faces_;
  EdgeQueue queue_;
  int alive_ = 0;
  int alive_seam_ = 0;
  // Scratch.
  std::vector<int> shared_, opposite_, na_, nb_, common_;
};

/// Edge flips that raise the worse quality of the two triangles around an
/// interior edge (a local Delaunay-like improvement that removes the slivers
/// decimation could not collapse). Seam edges are never flipped and no
/// interior seam-to-seam edge is created.
void ImproveByFlips(const FieldGrid& grid, HalfMesh* mesh) {
  auto key = [](int a, int b) {
    return (static_cast<uint64_t>(std::min(a, b)) << 32) |
           static_cast<uint32_t>(std::max(a, b));
  };
  auto& faces = mesh->faces;
  const auto& pos = mesh->vertices;
  for (int pass = 0; pass < 8; ++pass) {
    std::unordered_map<uint64_t, std::array<int, 2>> edge_faces;
    edge_faces.reserve(faces.size() * 2);
    for (size_t f = 0; f < faces.size(); ++f) {
      for (int e = 0; e < 3; ++e) {
        auto [it, inserted] =
            edge_faces.try_emplace(key(faces[f][e], faces[f][(e + 1) % 3]),
                                   std::array<int, 2>{static_cast<int>(f), -1});
        if (!inserted) it->second[1] = static_cast<int>(f);
      }
    }
    // Deterministic order: by edge key.
    std::vector<uint64_t> keys;
    keys.reserve(edge_faces.size());
    for (const auto& [k, fs] : edge_faces) keys.push_back(k);
    std::sort(keys.begin(), keys.end());
    std::vector<char> touched(faces.size(), 0);
    int flips = 0;
    for (const uint64_t k : keys) {
      const auto& fs = edge_faces[k];
      if (fs[1] < 0 || touched[fs[0]] || touched[fs[1]]) continue;
      const int u = static_cast<int>(k >> 32);
      const int w = static_cast<int>(k & 0xffffffffu);
      // Orient: f1 has the directed edge a -> b.
      int f1 = fs[0], f2 = fs[1];
      int a = -1, b = -1, c = -1, d = -1;
      for (int e = 0; e < 3; ++e) {
        const int p = faces[f1][e], q = faces[f1][(e + 1) % 3];
        if ((p == u && q == w) || (p == w && q == u)) {
          a = p;
          b = q;
          c = faces[f1][(e + 2) % 3];
        }
      }
      for (const int v : faces[f2]) {
        if (v != a && v != b) d = v;
      }
      if (c == d || (mesh->seam[c] && mesh->seam[d])) continue;
      if (edge_faces.count(key(c, d)))
        continue;  // the flipped edge exists already
      const double before = std::min(TriangleQuality(pos[a], pos[b], pos[c]),
                                     TriangleQuality(pos[b], pos[a], pos[d]));
      const double after = std::min(TriangleQuality(pos[a], pos[d], pos[c]),
                                    TriangleQuality(pos[d], pos[b], pos[c]));
      if (after < before + 0.05) continue;
      bool facing = true;
      for (const auto& tri :
           {std::array<int, 3>{a, d, c}, std::array<int, 3>{d, b, c}}) {
        const Vector3d n =
            (pos[tri[1]] - pos[tri[0]]).cross(pos[tri[2]] - pos[tri[0]]);
        Vector3d g;
        grid.Sample((pos[tri[0]] + pos[tri[1]] + pos[tri[2]]) / 3.0, &g);
        if (n.dot(g) < 0.5 * n.norm() * g.norm()) facing = false;
      }
      if (!facing) continue;
      faces[f1] = {a, d, c};
      faces[f2] = {d, b, c};
      touched[f1] = touched[f2] = 1;
      ++flips;
    }
    if (flips == 0) break;
  }
}

// ---------------------------------------------------------------------------
// Full mesh: mirror the half mesh, relax tangentially, keep exact symmetry.

SymmetricMesh MirrorHalfMesh(const HalfMesh& half) {
  const int nh = static_cast<int>(half.vertices.size());
  std::vector<int> mirror_index(nh);
  int next = nh;
  for (int v = 0; v < nh; ++v) mirror_index[v] = half.seam[v] ? v : next++;
  SymmetricMesh full;
  full.vertices.resize(3, next);
  full.mirror.resize(next);
  full.seam.assign(next, 0);
  for (int v = 0; v < nh; ++v) {
    full.vertices.col(v) = half.vertices[v];
    full.vertices.col(mirror_index[v]) = Mirror(half.vertices[v]);
    full.mirror[v] = mirror_index[v];
    full.mirror[mirror_index[v]] = v;
    full.seam[v] = half.seam[v];
    if (half.seam[v]) full.vertices(0, v) = 0.0;
  }
  const int nf = static_cast<int>(half.faces.size());
  full.faces.resize(3, 2 * nf);
  for (int f = 0; f < nf; ++f) {
    const auto& tri = half.faces[f];
    full.faces.col(f) << tri[0], tri[1], tri[2];
    full.faces.col(nf + f) << mirror_index[tri[0]], mirror_index[tri[2]],
        mirror_index[tri[1]];
  }
  return full;
}

void RelaxMesh(const FieldGrid& grid, int iterations, SymmetricMesh* mesh) {
  const int nv = static_cast<int>(mesh->vertices.cols());
  const auto neighbours = VertexNeighbours(nv, mesh->faces);
  const double min_x = 0.02 * grid.spacing();
  for (int iter = 0; iter < iterations; ++iter) {
    const Eigen::Matrix3Xd normals = VertexNormals(mesh->vertices, mesh->faces);
    Eigen::Matrix3Xd next = mesh->vertices;
    for (int v = 0; v < nv; ++v) {
      // Primary copies (the half mesh: seam vertices and their x > 0
      // partners have mirror[v] >= v); the others are their mirror images.
      if (mesh->mirror[v] < v) continue;
      const bool seam = mesh->seam[v] != 0;
      Vector3d centre = Vector3d::Zero();
      for (const int u : neighbours[v]) centre += mesh->vertices.col(u);
      centre /= static_cast<double>(neighbours[v].size());
      Vector3d delta = centre - mesh->vertices.col(v);
      const Vector3d n = normals.col(v);
      delta -= delta.dot(n) * n;
      Vector3d p = mesh->vertices.col(v) + 0.5 * delta;
      if (seam) p.x() = 0.0;
      grid.Project(&p, seam);
      p.x() =
          seam ? 0.0 : std::max(p.x(), min_x);  // never cross the mirror plane
      next.col(v) = p;
      next.col(mesh->mirror[v]) = Mirror(p);
      if (seam) next(0, v) = 0.0;
    }
    mesh->vertices = next;
  }
}

/// Every undirected edge in exactly two faces with opposite orientation.
void CheckClosedManifold(const Eigen::Matrix3Xi& faces) {
  std::unordered_map<uint64_t, int> directed;
  directed.reserve(faces.cols() * 3);
  for (Eigen::Index f = 0; f < faces.cols(); ++f) {
    for (int e = 0; e < 3; ++e) {
      const uint64_t a = static_cast<uint32_t>(faces(e, f));
      const uint64_t b = static_cast<uint32_t>(faces((e + 1) % 3, f));
      SOMA_CHECK(a != b) << "degenerate face " << f;
      const int count = ++directed[(a << 32) | b];
      SOMA_CHECK_EQ(count, 1)
          << "directed edge used twice (non-manifold or flipped face)";
    }
  }
  for (const auto& [key, count] : directed) {
    const uint64_t reverse = (key << 32) | (key >> 32);
    SOMA_CHECK(directed.count(reverse) == 1)
        << "open edge (hole) in the procedural mesh";
  }
}

}  // namespace

SymmetricMesh MeshPrimitives(const std::vector<Primitive>& prims,
                             const MeshPrimitivesOptions& options) {
  const FieldGrid grid(prims, options.grid_spacing, options.blend_radius);
  HalfMesh half = MarchingTetrahedra(grid);
  {
    Decimator decimator(&half, &grid);
    decimator.Run(options.target_vertices);
    decimator.Compact();
  }
  ImproveByFlips(grid, &half);
  SymmetricMesh mesh = MirrorHalfMesh(half);
  RelaxMesh(grid, options.relax_iterations, &mesh);
  CheckClosedManifold(mesh.faces);
  return mesh;
}

}  // namespace internal
}  // namespace soma
