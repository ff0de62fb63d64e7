#include "framework/synth/ghosts.h"

#include <Eigen/Core>
#include <Eigen/QR>

#include <algorithm>
#include <cmath>

namespace soma {
namespace {

/// A random 3x3 correlation matrix with eigenvalues 3 u / sum(u), u ~ U(0,
/// 1)^3, as scipy.stats.random_correlation (Davies & Higham 2000: a Haar
/// random rotation of diag(eigenvalues), then Givens rotations that make the
/// diagonal 1). Returns a factor F with C = F F^T (F = B sqrt(Lambda)).
Eigen::Matrix3d RandomCorrelationFactor(Rng& rng) {
  Eigen::Vector3d eig;
  for (int i = 0; i < 3; ++i) eig(i) = rng.Uniform();
  // Guard the (measure-zero) all-zero draw.
  const double total = std::max(eig.sum(), 1e-12);
  eig *= 3.0 / total;
  // Haar-random orthogonal matrix: QR of a Gaussian matrix with the signs of
  // R's diagonal moved into Q.
  Eigen::Matrix3d gauss;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) gauss(r, c) = rng.Normal();
  }
  const Eigen::HouseholderQR<Eigen::Matrix3d> qr(gauss);
  Eigen::Matrix3d b = qr.householderQ();
  const Eigen::Matrix3d r = qr.matrixQR().triangularView<Eigen::Upper>();
  for (int c = 0; c < 3; ++c) {
    if (r(c, c) < 0) b.col(c) = -b.col(c);
  }
  Eigen::Matrix3d m = b * eig.asDiagonal() * b.transpose();
  // scipy's _to_corr: rotate pairs (i, j) so that m(i, i) becomes 1.
  for (int i = 0; i < 2; ++i) {
    if (m(i, i) == 1.0) continue;
    int j = i + 1;
    if (m(i, i) > 1.0) {
      for (j = i + 1; j < 3; ++j) {
        if (m(j, j) < 1.0) break;
      }
    } else {
      for (j = i + 1; j < 3; ++j) {
        if (m(j, j) > 1.0) break;
      }
    }
    if (j >= 3) j = 2;
    const double aiid = m(i, i) - 1.0;
    const double ajjd = m(j, j) - 1.0;
    const double aij = m(i, j);
    double c = 0.0;
    double s = 1.0;
    if (ajjd != 0.0) {
      const double dd = std::sqrt(std::max(aij * aij - aiid * ajjd, 0.0));
      const double t = (aij + std::copysign(dd, aij)) / ajjd;
      c = 1.0 / std::sqrt(1.0 + t * t);
      s = c == 0.0 ? 1.0 : c * t;
    }
    Eigen::Matrix3d g = Eigen::Matrix3d::Identity();
    g(i, i) = c;
    g(j, j) = c;
    g(j, i) = -s;
    g(i, j) = s;
    m = g.transpose() * m * g;
    b = g.transpose() * b;
  }
  return b * eig.cwiseSqrt().asDiagonal();
}

}  // namespace

void LowerMedianAndStd(std::vector<float>* values,
                       double* median,
                       double* sigma) {
  const int n = static_cast<int>(values->size());
  double sum = 0.0;
  for (const float v : *values) sum += v;
  const double mean = sum / n;
  double ss = 0.0;
  for (const float v : *values) ss += (v - mean) * (v - mean);
  *sigma = n > 1 ? std::sqrt(ss / (n - 1)) : 0.0;
  const size_t mid = (values->size() - 1) / 2;
  std::nth_element(values->begin(), values->begin() + mid, values->end());
  *median = (*values)[mid];
}

void DrawGhosts(const GhostOptions& options,
                int count,
                const GhostCentre& centre,
                Rng& rng,
                std::vector<float>* xyz,
                std::vector<char>* dropped) {
  xyz->resize(3 * static_cast<size_t>(count));
  dropped->assign(count, 0);
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  Eigen::Matrix3d factor = Eigen::Matrix3d::Identity();
  if (options.distribution == GhostDistribution::kSkewedGaussian) {
    for (int c = 0; c < 3; ++c) {
      mean(c) = rng.Uniform(-options.half_extent, options.half_extent);
    }
    factor = RandomCorrelationFactor(rng);
  }
  for (int g = 0; g < count; ++g) {
    Eigen::Vector3d p = Eigen::Vector3d::Zero();
    switch (options.distribution) {
      case GhostDistribution::kSphericalGaussian:
        for (int c = 0; c < 3; ++c) {
          p(c) = centre.median[c] + centre.sigma[c] * rng.Normal();
        }
        break;
      case GhostDistribution::kUniform:
        for (int c = 0; c < 3; ++c) {
          p(c) = rng.Uniform(-options.half_extent, options.half_extent);
        }
        break;
      case GhostDistribution::kSkewedGaussian: {
        Eigen::Vector3d z;
        for (int c = 0; c < 3; ++c) z(c) = rng.Normal();
        p = mean + factor * z;
        break;
      }
    }
    for (int c = 0; c < 3; ++c) (*xyz)[3 * g + c] = static_cast<float>(p(c));
  }
  if (options.up_to) {
    // Draw `count` integers from [0, 3 count); every ghost whose index was
    // drawn is dropped (each survives with probability
    // (1 - 1/(3 count))^count).
    for (int g = 0; g < count; ++g) {
      const int index = static_cast<int>(rng.UniformInt(0, 3 * count - 1));
      if (index < count) (*dropped)[index] = 1;
    }
  }
}

}  // namespace soma
