// The built-in noise modules (REFERENCE.md 3.4-3.5; Noise-in Bias-out C.2)
// and their registration.
#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/registry/registry.h"
#include "framework/synth/ghosts.h"
#include "framework/synth/noise.h"
#include "framework/synth/noise_bank.h"

#include <fmt/format.h>

#include <algorithm>
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
    GhostCentre centre;
    if (options_.distribution == GhostDistribution::kSphericalGaussian &&
        !MarkerStatistics(*frame, &centre)) {
      return;
    }
    thread_local std::vector<float> xyz;
    thread_local std::vector<char> dropped;
    DrawGhosts(options_, count, centre, rng, &xyz, &dropped);
    for (int g = 0; g < count; ++g) {
      frame->Set(ghost_begin + g,
                 xyz[3 * g],
                 xyz[3 * g + 1],
                 xyz[3 * g + 2],
                 frame->null_label());
    }
    for (int g = 0; g < count; ++g) {
      if (dropped[g]) frame->Remove(ghost_begin + g);
    }
  }

 private:
  /// Per-coordinate lower median and unbiased std of the available markers;
  /// false if fewer than 2 (the std is undefined: no ghosts).
  static bool MarkerStatistics(const MarkerFrame& frame, GhostCentre* centre) {
    thread_local std::vector<float> values;
    for (int c = 0; c < 3; ++c) {
      values.clear();
      for (int i = 0; i < frame.num_points(); ++i) {
        if (frame.IsAvailableMarker(i)) values.push_back(frame.point(i)[c]);
      }
      if (values.size() < 2) return false;
      LowerMedianAndStd(&values, &centre->median[c], &centre->sigma[c]);
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
