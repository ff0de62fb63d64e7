// The built-in noise modules (REFERENCE.md 3.4-3.5; Noise-in Bias-out C.2)
// and their registration.
#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/registry/registry.h"
#include "framework/synth/noise.h"
#include "framework/synth/noise_bank.h"

#include <Eigen/Core>
#include <Eigen/QR>
#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <memory>
#include <string>
#include <vector>

namespace soma {
namespace {

/// Largest ghost count a module accepts (slots per frame).
constexpr int kMaxGhostCount = 1000;

// ---- occlusion.

/// REFERENCE.md 3.5 step 3: k ~ U{0..max_count} (inclusive; `exact`: k =
/// max_count) distinct markers chosen uniformly among **all** L superset
/// markers are removed (some may already be absent from the frame's layout,
/// so fewer markers can disappear).
struct OcclusionOptions {
  int max_count = 5;   // k upper bound (inclusive)
  bool exact = false;  // always exactly max_count
};

class OcclusionModule : public NoiseModule {
 public:
  explicit OcclusionModule(const OcclusionOptions& options)
      : options_(options) {}

  void Validate(const std::vector<std::string>& labels) const override {
    CheckCount(static_cast<int>(labels.size()));
  }

  void Apply(MarkerFrame* frame, int, Rng& rng) const override {
    const int num_labels = frame->num_labels;
    CheckCount(num_labels);
    const int k = options_.exact
                      ? options_.max_count
                      : static_cast<int>(rng.UniformInt(0, options_.max_count));
    if (k == 0) return;
    // Partial Fisher-Yates over the marker slots 0..L-1 (pre-permutation,
    // slot = label id).
    thread_local std::vector<int> pool;
    pool.resize(num_labels);
    for (int i = 0; i < num_labels; ++i) pool[i] = i;
    for (int i = 0; i < k; ++i) {
      const int j = static_cast<int>(rng.UniformInt(i, num_labels - 1));
      std::swap(pool[i], pool[j]);
      frame->Remove(pool[i]);
    }
  }

 private:
  void CheckCount(int num_labels) const {
    if (options_.max_count > num_labels) {
      throw ConfigError(fmt::format(
          "Invalid configuration. noise module 'occlusion': max_count = {}. "
          "Violated constraint: max_count <= number of markers L = {} (cannot "
          "occlude more markers than the layout has)",
          options_.max_count,
          num_labels));
    }
  }

  OcclusionOptions options_;
};

std::unique_ptr<NoiseModule> MakeOcclusion(const ConfigNode& node,
                                           BuildContext&) {
  ConfigReader reader(node);
  OcclusionOptions options;
  reader.Read("max_count", &options.max_count);
  reader.Read("exact", &options.exact);
  reader.Check("max_count", options.max_count >= 0, "max_count >= 0");
  reader.Finish();
  return std::make_unique<OcclusionModule>(options);
}

// ---- ghosts.

enum class GhostDistribution { kSphericalGaussian, kUniform, kSkewedGaussian };

/// REFERENCE.md 3.5 step 4.
struct GhostOptions {
  GhostDistribution distribution = GhostDistribution::kSphericalGaussian;
  int max_count = 3;         // G ~ U{0..max_count}; also the slots used
  bool exact = false;        // always G = max_count
  bool up_to = true;         // "up-to" rejection (use_upto_num_ghost)
  double half_extent = 2.0;  // uniform box / skewed mean U(-h, h), metres
};

/// Median (lower median for even counts, as torch.median) of `values`
/// (reordered in place).
float LowerMedian(std::vector<float>& values) {
  const size_t mid = (values.size() - 1) / 2;
  std::nth_element(values.begin(), values.begin() + mid, values.end());
  return values[mid];
}

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

class GhostsModule : public NoiseModule {
 public:
  explicit GhostsModule(const GhostOptions& options) : options_(options) {}

  int num_ghost_slots() const override { return options_.max_count; }

  void Apply(MarkerFrame* frame, int ghost_begin, Rng& rng) const override {
    const int count =
        options_.exact
            ? options_.max_count
            : static_cast<int>(rng.UniformInt(0, options_.max_count));
    if (count == 0) return;
    std::array<double, 3> mean = {0.0, 0.0, 0.0};
    std::array<double, 3> sigma = {0.0, 0.0, 0.0};
    Eigen::Matrix3d factor = Eigen::Matrix3d::Identity();
    switch (options_.distribution) {
      case GhostDistribution::kSphericalGaussian:
        if (!MarkerStatistics(*frame, &mean, &sigma)) return;
        break;
      case GhostDistribution::kUniform:
        break;
      case GhostDistribution::kSkewedGaussian:
        for (double& m : mean) {
          m = rng.Uniform(-options_.half_extent, options_.half_extent);
        }
        factor = RandomCorrelationFactor(rng);
        break;
    }
    for (int g = 0; g < count; ++g) {
      Eigen::Vector3d p = Eigen::Vector3d::Zero();
      switch (options_.distribution) {
        case GhostDistribution::kSphericalGaussian:
          for (int c = 0; c < 3; ++c) p(c) = mean[c] + sigma[c] * rng.Normal();
          break;
        case GhostDistribution::kUniform:
          for (int c = 0; c < 3; ++c) {
            p(c) = rng.Uniform(-options_.half_extent, options_.half_extent);
          }
          break;
        case GhostDistribution::kSkewedGaussian: {
          Eigen::Vector3d z;
          for (int c = 0; c < 3; ++c) z(c) = rng.Normal();
          p = Eigen::Vector3d(mean[0], mean[1], mean[2]) + factor * z;
          break;
        }
      }
      frame->Set(ghost_begin + g,
                 static_cast<float>(p(0)),
                 static_cast<float>(p(1)),
                 static_cast<float>(p(2)),
                 frame->null_label());
    }
    if (options_.up_to) {
      // Draw `count` integers from [0, 3 count); every ghost whose index was
      // drawn is dropped (each survives with probability
      // (1 - 1/(3 count))^count).
      for (int g = 0; g < count; ++g) {
        const int index = static_cast<int>(rng.UniformInt(0, 3 * count - 1));
        if (index < count) frame->Remove(ghost_begin + index);
      }
    }
  }

 private:
  /// Per-coordinate lower median and unbiased std of the available markers;
  /// false if fewer than 2 (the std is undefined: no ghosts).
  static bool MarkerStatistics(const MarkerFrame& frame,
                               std::array<double, 3>* median,
                               std::array<double, 3>* sigma) {
    thread_local std::vector<float> values;
    for (int c = 0; c < 3; ++c) {
      values.clear();
      for (int i = 0; i < frame.num_points(); ++i) {
        if (frame.IsAvailableMarker(i)) values.push_back(frame.point(i)[c]);
      }
      const int n = static_cast<int>(values.size());
      if (n < 2) return false;
      double sum = 0.0;
      for (const float v : values) sum += v;
      const double mean = sum / n;
      double ss = 0.0;
      for (const float v : values) ss += (v - mean) * (v - mean);
      (*sigma)[c] = std::sqrt(ss / (n - 1));
      (*median)[c] = LowerMedian(values);
    }
    return true;
  }

  GhostOptions options_;
};

std::unique_ptr<NoiseModule> MakeGhosts(const ConfigNode& node, BuildContext&) {
  ConfigReader reader(node);
  GhostOptions options;
  std::string distribution = "spherical_gaussian";
  reader.Read("distribution", &distribution);
  reader.Read("max_count", &options.max_count);
  reader.Read("exact", &options.exact);
  reader.Read("up_to", &options.up_to);
  reader.Read("half_extent", &options.half_extent);
  reader.Check("distribution",
               distribution == "spherical_gaussian" ||
                   distribution == "uniform" ||
                   distribution == "skewed_gaussian",
               "distribution is spherical_gaussian, uniform or "
               "skewed_gaussian");
  reader.Check("max_count",
               options.max_count >= 0 && options.max_count <= kMaxGhostCount,
               fmt::format("0 <= max_count <= {}", kMaxGhostCount));
  reader.Check("half_extent", options.half_extent > 0, "half_extent > 0");
  reader.Finish();
  options.distribution = distribution == "uniform" ? GhostDistribution::kUniform
                         : distribution == "skewed_gaussian"
                             ? GhostDistribution::kSkewedGaussian
                             : GhostDistribution::kSphericalGaussian;
  return std::make_unique<GhostsModule>(options);
}

// ---- jitter.

/// Gaussian noise N(0, sigma^2) per coordinate on every available marker.
class JitterModule : public NoiseModule {
 public:
  JitterModule(double sigma, bool include_ghosts)
      : sigma_(sigma), include_ghosts_(include_ghosts) {}

  void Apply(MarkerFrame* frame, int, Rng& rng) const override {
    for (int i = 0; i < frame->num_points(); ++i) {
      const bool eligible =
          include_ghosts_ ? frame->IsPresent(i) : frame->IsAvailableMarker(i);
      if (!eligible) continue;
      float* p = frame->point(i);
      for (int c = 0; c < 3; ++c) {
        p[c] += static_cast<float>(sigma_ * rng.Normal());
      }
    }
  }

 private:
  double sigma_;
  bool include_ghosts_;
};

std::unique_ptr<NoiseModule> MakeJitter(const ConfigNode& node, BuildContext&) {
  ConfigReader reader(node);
  double sigma = 0.005;
  bool include_ghosts = false;
  reader.Read("sigma", &sigma);
  reader.Read("include_ghosts", &include_ghosts);
  reader.Check("sigma", sigma >= 0, "sigma >= 0 (metres)");
  reader.Finish();
  return std::make_unique<JitterModule>(sigma, include_ghosts);
}

// ---- shift (Noise-in Bias-out C.2).

/// round(fraction * available) distinct available markers, each moved by an
/// offset U(-max_offset, max_offset) per coordinate.
class ShiftModule : public NoiseModule {
 public:
  ShiftModule(double fraction, double max_offset)
      : fraction_(fraction), max_offset_(max_offset) {}

  void Apply(MarkerFrame* frame, int, Rng& rng) const override {
    thread_local std::vector<int> available;
    available.clear();
    for (int i = 0; i < frame->num_points(); ++i) {
      if (frame->IsAvailableMarker(i)) available.push_back(i);
    }
    const int n = static_cast<int>(available.size());
    const int count = std::min(
        n, static_cast<int>(std::lround(fraction_ * static_cast<double>(n))));
    for (int k = 0; k < count; ++k) {
      const int j = static_cast<int>(rng.UniformInt(k, n - 1));
      std::swap(available[k], available[j]);
      float* p = frame->point(available[k]);
      for (int c = 0; c < 3; ++c) {
        p[c] += static_cast<float>(rng.Uniform(-max_offset_, max_offset_));
      }
    }
  }

 private:
  double fraction_;
  double max_offset_;
};

std::unique_ptr<NoiseModule> MakeShift(const ConfigNode& node, BuildContext&) {
  ConfigReader reader(node);
  double fraction = 0.1;
  double max_offset = 0.03;
  reader.Read("fraction", &fraction);
  reader.Read("max_offset", &max_offset);
  reader.Check(
      "fraction", fraction >= 0 && fraction <= 1, "0 <= fraction <= 1");
  reader.Check("max_offset", max_offset >= 0, "max_offset >= 0 (metres)");
  reader.Finish();
  return std::make_unique<ShiftModule>(fraction, max_offset);
}

// ---- real_noise (REFERENCE.md 3.4).

/// Adds row i ~ U{0..K-1} of a per-label residual bank (K x L x 3) to every
/// available marker (label l gets bank[i, l]).
class RealNoiseModule : public NoiseModule {
 public:
  RealNoiseModule(NoiseBank bank, std::string path)
      : bank_(std::move(bank)), path_(std::move(path)) {}

  void Validate(const std::vector<std::string>& labels) const override {
    if (labels != bank_.labels) {
      throw ConfigError(fmt::format(
          "Invalid configuration. noise module 'real_noise': the bank {} has "
          "labels [{}] but the superset has [{}]; build the bank for this "
          "superset",
          path_,
          fmt::join(bank_.labels, ", "),
          fmt::join(labels, ", ")));
    }
  }

  void Apply(MarkerFrame* frame, int, Rng& rng) const override {
    if (frame->num_labels != bank_.num_labels()) {
      throw ConfigError(fmt::format(
          "noise module 'real_noise': the bank {} has {} labels, the frame {}",
          path_,
          bank_.num_labels(),
          frame->num_labels));
    }
    if (bank_.num_rows == 0) return;
    const int64_t row = rng.UniformInt(0, bank_.num_rows - 1);
    const float* residuals = bank_.row(row);
    for (int i = 0; i < frame->num_points(); ++i) {
      if (!frame->IsAvailableMarker(i)) continue;
      const float* r = residuals + 3 * frame->labels[i];
      float* p = frame->point(i);
      for (int c = 0; c < 3; ++c) p[c] += r[c];
    }
  }

 private:
  NoiseBank bank_;
  std::string path_;
};

std::unique_ptr<NoiseModule> MakeRealNoise(const ConfigNode& node,
                                           BuildContext&) {
  ConfigReader reader(node);
  std::string path;
  reader.Require("path", &path);
  reader.Finish();
  return std::make_unique<RealNoiseModule>(ReadNoiseBank(path), path);
}

// ---- permutation.

/// One uniformly random permutation of the N points and their labels
/// (REFERENCE.md 3.5 step 6). Must be the last stage.
class PermutationModule : public NoiseModule {
 public:
  void Apply(MarkerFrame* frame, int, Rng& rng) const override {
    const int n = frame->num_points();
    for (int i = n - 1; i > 0; --i) {
      const int j = static_cast<int>(rng.UniformInt(0, i));
      if (j == i) continue;
      std::swap(frame->labels[i], frame->labels[j]);
      float* a = frame->point(i);
      float* b = frame->point(j);
      for (int c = 0; c < 3; ++c) std::swap(a[c], b[c]);
    }
  }
};

std::unique_ptr<NoiseModule> MakePermutation(const ConfigNode& node,
                                             BuildContext&) {
  ConfigReader reader(node);
  reader.Finish();
  return std::make_unique<PermutationModule>();
}

}  // namespace

void RegisterNoiseModules() {
  Registry<NoiseModule>& registry = GetRegistry<NoiseModule>();
  registry.Register("occlusion", MakeOcclusion);
  registry.Register("ghosts", MakeGhosts);
  registry.Register("jitter", MakeJitter);
  registry.Register("shift", MakeShift);
  registry.Register("real_noise", MakeRealNoise);
  registry.Register("permutation", MakePermutation);
}

}  // namespace soma
