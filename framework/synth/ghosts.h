// Ghost points (REFERENCE.md 3.5 step 4): the sampling of the `ghosts` noise
// module, also used by the real-data corruption protocol (corruption.h),
// which draws spherical Gaussian ghosts around statistics of its own.
//
// One frame's ghosts: for the skewed Gaussian, first a mean ~ U(-h, h)^3 and
// a random correlation; then per ghost its three coordinates (spherical:
// median_c + sigma_c * N(0, 1); uniform: U(-h, h); skewed: mean + F z); then,
// with up-to rejection, `count` draws r ~ U{0..3 count - 1}, each dropping
// ghost r when r < count.
#pragma once

#include "framework/core/random.h"

#include <array>
#include <vector>

namespace soma {

enum class GhostDistribution { kSphericalGaussian, kUniform, kSkewedGaussian };

/// REFERENCE.md 3.5 step 4.
struct GhostOptions {
  GhostDistribution distribution = GhostDistribution::kSphericalGaussian;
  int max_count = 3;         // G ~ U{0..max_count}; also the slots used
  bool exact = false;        // always G = max_count
  bool up_to = true;         // "up-to" rejection (use_upto_num_ghost)
  double half_extent = 2.0;  // uniform box / skewed mean U(-h, h), metres
};

/// The centre and spread of spherical Gaussian ghosts, per axis.
struct GhostCentre {
  std::array<double, 3> median = {0.0, 0.0, 0.0};  // metres
  std::array<double, 3> sigma = {0.0, 0.0, 0.0};   // metres
};

/// Lower median (as torch.median) and unbiased standard deviation (0 for a
/// single value) of `values` (at least one; reordered in place). The sum
/// runs in the given order.
void LowerMedianAndStd(std::vector<float>* values,
                       double* median,
                       double* sigma);

/// The ghosts of one frame: `count` points (3 floats each, metres) into
/// `xyz` and, per ghost, whether up-to rejection dropped it (all kept
/// without `options.up_to`) into `dropped`. `centre` is used by the
/// spherical Gaussian only. Draws from `rng` in the order above.
void DrawGhosts(const GhostOptions& options,
                int count,
                const GhostCentre& centre,
                Rng& rng,
                std::vector<float>* xyz,
                std::vector<char>* dropped);

}  // namespace soma
