#include "framework/synth/noise.h"

#include "framework/config/compose.h"
#include "framework/config/interpolation.h"
#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/core/random.h"
#include "framework/synth/noise_bank.h"
#include "framework/testing/testing.h"

#include <Eigen/Core>
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <string>
#include <vector>

namespace soma {
namespace {

constexpr int kLabels = 41;
constexpr int kFrames = 10000;

NoisePipeline Build(const std::string& yaml) {
  BuildContext ctx;
  return BuildNoisePipeline(ParseYaml(yaml, "test.yaml"), ctx);
}

/// A fixed body-sized marker cloud: L markers around (0.3, -0.2, 1.0) with
/// per-axis spreads (0.2, 0.15, 0.5) m.
const std::vector<std::array<float, 3>>& CleanMarkers() {
  static const std::vector<std::array<float, 3>> markers = [] {
    std::vector<std::array<float, 3>> out;
    Rng rng(7);
    for (int l = 0; l < kLabels; ++l) {
      out.push_back({static_cast<float>(0.3 + 0.2 * rng.Normal()),
                     static_cast<float>(-0.2 + 0.15 * rng.Normal()),
                     static_cast<float>(1.0 + 0.5 * rng.Normal())});
    }
    return out;
  }();
  return markers;
}

MarkerFrame CleanFrame(const NoisePipeline& pipeline) {
  MarkerFrame frame;
  frame.Reset(kLabels, pipeline.num_ghost_slots());
  for (int l = 0; l < kLabels; ++l) {
    const auto& p = CleanMarkers()[l];
    frame.Set(l, p[0], p[1], p[2], static_cast<int16_t>(l));
  }
  return frame;
}

/// Applies `pipeline` to the clean frame with the stream of frame i.
MarkerFrame Noisy(const NoisePipeline& pipeline, uint64_t i) {
  MarkerFrame frame = CleanFrame(pipeline);
  pipeline.Apply(&frame, Rng(123).Stream(i));
  return frame;
}

std::vector<std::string> Labels(int n) {
  std::vector<std::string> labels;
  for (int l = 0; l < n; ++l) labels.push_back(fmt::format("M{}", l));
  return labels;
}

TEST(MarkerFrame, ResetSetRemove) {
  MarkerFrame frame;
  frame.Reset(3, 2);
  EXPECT_EQ(frame.num_points(), 5);
  EXPECT_EQ(frame.null_label(), 3);
  EXPECT_EQ(frame.NumAvailableMarkers(), 0);
  frame.Set(1, 1.0f, 2.0f, 3.0f, 1);
  EXPECT_TRUE(frame.IsAvailableMarker(1));
  EXPECT_EQ(frame.NumAvailableMarkers(), 1);
  frame.Remove(1);
  EXPECT_FALSE(frame.IsPresent(1));
  EXPECT_EQ(frame.labels[1], 3);
  EXPECT_THROW(frame.Reset(-1, 0), ShapeError);
}

TEST(NoiseModules, OcclusionCountsFollowInclusiveUniform) {
  const NoisePipeline pipeline =
      Build("modules: [{name: occlusion, max_count: 5}]");
  std::map<int, int> counts;
  for (int i = 0; i < kFrames; ++i) {
    const MarkerFrame frame = Noisy(pipeline, i);
    ++counts[kLabels - frame.NumAvailableMarkers()];
  }
  // k ~ U{0..5}: six values, each ~1/6 (binomial std ~0.0037 at 10k).
  ASSERT_EQ(counts.size(), 6u);
  double chi2 = 0.0;
  const double expected = kFrames / 6.0;
  for (int k = 0; k <= 5; ++k) {
    EXPECT_NEAR(counts[k] / static_cast<double>(kFrames), 1.0 / 6.0, 0.015)
        << "k=" << k;
    chi2 += (counts[k] - expected) * (counts[k] - expected) / expected;
  }
  EXPECT_LT(chi2, 20.5);  // chi-square, 5 dof, p = 0.001
}

TEST(NoiseModules, OcclusionExactAndUniformOverMarkers) {
  const NoisePipeline pipeline =
      Build("modules: [{name: occlusion, max_count: 3, exact: true}]");
  std::vector<int> removed(kLabels, 0);
  for (int i = 0; i < kFrames; ++i) {
    const MarkerFrame frame = Noisy(pipeline, i);
    ASSERT_EQ(frame.NumAvailableMarkers(), kLabels - 3);
    for (int l = 0; l < kLabels; ++l) {
      if (!frame.IsPresent(l)) {
        ++removed[l];
        EXPECT_EQ(frame.labels[l], frame.null_label());
      }
    }
  }
  // Each marker is removed with probability 3/41 (~732 of 10k, std ~26).
  for (int l = 0; l < kLabels; ++l) {
    EXPECT_NEAR(removed[l], kFrames * 3.0 / kLabels, 130) << l;
  }
}

TEST(NoiseModules, MoreOcclusionsThanMarkersIsAClearError) {
  const NoisePipeline pipeline =
      Build("modules: [{name: occlusion, max_count: 50}]");
  const std::string message = testing::ErrorMessage<ConfigError>(
      [&] { pipeline.Validate(Labels(kLabels)); });
  EXPECT_NE(message.find("max_count = 50"), std::string::npos) << message;
  EXPECT_NE(message.find("L = 41"), std::string::npos) << message;
  MarkerFrame frame = CleanFrame(pipeline);
  EXPECT_THROW(pipeline.Apply(&frame, Rng(1)), ConfigError);
}

TEST(NoiseModules, SphericalGhostsCentreOnTheMarkerMedian) {
  const NoisePipeline pipeline = Build(
      "modules: [{name: ghosts, distribution: spherical_gaussian, "
      "max_count: 3, exact: true, up_to: false}]");
  EXPECT_EQ(pipeline.num_ghost_slots(), 3);
  // Expected statistics of the clean markers.
  std::array<double, 3> median{};
  std::array<double, 3> stddev{};
  for (int c = 0; c < 3; ++c) {
    std::vector<double> v;
    for (const auto& p : CleanMarkers()) v.push_back(p[c]);
    double mean = 0.0;
    for (double x : v) mean += x / v.size();
    double ss = 0.0;
    for (double x : v) ss += (x - mean) * (x - mean);
    stddev[c] = std::sqrt(ss / (v.size() - 1));
    std::sort(v.begin(), v.end());
    median[c] = v[(v.size() - 1) / 2];
  }
  std::array<double, 3> sum{};
  std::array<double, 3> sum2{};
  int n = 0;
  for (int i = 0; i < kFrames / 2; ++i) {
    const MarkerFrame frame = Noisy(pipeline, i);
    ASSERT_EQ(frame.NumAvailableMarkers(), kLabels);
    for (int g = kLabels; g < frame.num_points(); ++g) {
      ASSERT_TRUE(frame.IsPresent(g));
      EXPECT_EQ(frame.labels[g], frame.null_label());
      for (int c = 0; c < 3; ++c) {
        sum[c] += frame.point(g)[c];
        sum2[c] += frame.point(g)[c] * frame.point(g)[c];
      }
      ++n;
    }
  }
  ASSERT_EQ(n, 3 * kFrames / 2);
  for (int c = 0; c < 3; ++c) {
    const double mean = sum[c] / n;
    const double sd = std::sqrt(sum2[c] / n - mean * mean);
    EXPECT_NEAR(mean, median[c], 4 * stddev[c] / std::sqrt(n)) << c;
    EXPECT_NEAR(sd, stddev[c], 0.03 * stddev[c]) << c;
  }
}

TEST(NoiseModules, UpToRejectionKeepsGhostsAtTheDocumentedRate) {
  const NoisePipeline pipeline = Build(
      "modules: [{name: ghosts, max_count: 3, exact: true, up_to: true}]");
  int survived = 0;
  for (int i = 0; i < kFrames; ++i) {
    const MarkerFrame frame = Noisy(pipeline, i);
    for (int g = kLabels; g < frame.num_points(); ++g)
      survived += frame.IsPresent(g) ? 1 : 0;
  }
  // Each ghost survives with probability (1 - 1/9)^3 = 0.7023.
  EXPECT_NEAR(survived / (3.0 * kFrames), std::pow(8.0 / 9.0, 3), 0.015);
}

TEST(NoiseModules, GhostCountsFollowInclusiveUniformWithoutRejection) {
  const NoisePipeline pipeline =
      Build("modules: [{name: ghosts, max_count: 3, up_to: false}]");
  std::map<int, int> counts;
  for (int i = 0; i < kFrames; ++i) {
    const MarkerFrame frame = Noisy(pipeline, i);
    int present = 0;
    for (int g = kLabels; g < frame.num_points(); ++g)
      present += frame.IsPresent(g) ? 1 : 0;
    ++counts[present];
  }
  ASSERT_EQ(counts.size(), 4u);
  for (int k = 0; k <= 3; ++k) {
    EXPECT_NEAR(counts[k] / static_cast<double>(kFrames), 0.25, 0.02) << k;
  }
}

TEST(NoiseModules, UniformGhostsFillTheBox) {
  const NoisePipeline pipeline = Build(
      "modules: [{name: ghosts, distribution: uniform, max_count: 5, exact: "
      "true, up_to: false}]");
  std::array<double, 3> sum{};
  std::array<double, 3> sum2{};
  int n = 0;
  for (int i = 0; i < 2000; ++i) {
    const MarkerFrame frame = Noisy(pipeline, i);
    for (int g = kLabels; g < frame.num_points(); ++g) {
      for (int c = 0; c < 3; ++c) {
        const double x = frame.point(g)[c];
        ASSERT_GE(x, -2.0);
        ASSERT_LE(x, 2.0);
        sum[c] += x;
        sum2[c] += x * x;
      }
      ++n;
    }
  }
  for (int c = 0; c < 3; ++c) {
    EXPECT_NEAR(sum[c] / n, 0.0, 0.05);
    EXPECT_NEAR(sum2[c] / n, 16.0 / 12.0, 0.06);  // variance of U(-2, 2)
  }
}

TEST(NoiseModules, SkewedGhostsHaveUnitVarianceAndCorrelation) {
  // One frame with many ghosts: their covariance is the frame's random
  // correlation matrix (unit diagonal, off-diagonals in [-1, 1]).
  const NoisePipeline pipeline = Build(
      "modules: [{name: ghosts, distribution: skewed_gaussian, max_count: "
      "1000, exact: true, up_to: false}]");
  double max_offdiag = 0.0;
  for (int i = 0; i < 10; ++i) {
    const MarkerFrame frame = Noisy(pipeline, i);
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    const int n = frame.num_points() - kLabels;
    for (int g = kLabels; g < frame.num_points(); ++g) {
      mean +=
          Eigen::Map<const Eigen::Vector3f>(frame.point(g)).cast<double>() / n;
    }
    for (int c = 0; c < 3; ++c) EXPECT_LE(std::abs(mean(c)), 2.2);
    Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
    for (int g = kLabels; g < frame.num_points(); ++g) {
      const Eigen::Vector3d d =
          Eigen::Map<const Eigen::Vector3f>(frame.point(g)).cast<double>() -
          mean;
      cov += d * d.transpose() / (n - 1);
    }
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(cov(c, c), 1.0, 0.2) << i;
    max_offdiag = std::max({max_offdiag,
                            std::abs(cov(0, 1)),
                            std::abs(cov(0, 2)),
                            std::abs(cov(1, 2))});
  }
  EXPECT_GT(max_offdiag, 0.2);  // correlated, not the identity
}

TEST(NoiseModules, GhostDistributionsMatchTheirGoldenHashes) {
  // Pinned across builds: 200 frames of each ghost distribution (random
  // counts, up-to rejection) hash to the values below (FNV-1a over the
  // points' and labels' bytes). A change of the ghost sampling or of its
  // order of RNG draws shows here; update a value only on purpose.
  const std::map<std::string, uint64_t> expected = {
      {"spherical_gaussian", 15944975628903328528u},
      {"uniform", 725573462893045902u},
      {"skewed_gaussian", 14386860158422195635u},
  };
  for (const auto& [distribution, hash] : expected) {
    const NoisePipeline pipeline = Build(fmt::format(
        "modules: [{{name: ghosts, distribution: {}, max_count: 5}}]",
        distribution));
    uint64_t h = Fnv1a64("");
    for (int i = 0; i < 200; ++i) {
      const MarkerFrame frame = Noisy(pipeline, i);
      h = Fnv1a64(
          std::string_view(reinterpret_cast<const char*>(frame.points.data()),
                           sizeof(float) * frame.points.size()),
          h);
      h = Fnv1a64(
          std::string_view(reinterpret_cast<const char*>(frame.labels.data()),
                           sizeof(int16_t) * frame.labels.size()),
          h);
    }
    EXPECT_EQ(h, hash) << distribution;
  }
}

TEST(NoiseModules, ShiftIsBoundedByM) {
  const NoisePipeline pipeline =
      Build("modules: [{name: shift, fraction: 0.2, max_offset: 0.05}]");
  double max_offset = 0.0;
  for (int i = 0; i < 2000; ++i) {
    const MarkerFrame frame = Noisy(pipeline, i);
    int moved = 0;
    for (int l = 0; l < kLabels; ++l) {
      bool is_moved = false;
      for (int c = 0; c < 3; ++c) {
        const double d = std::abs(frame.point(l)[c] - CleanMarkers()[l][c]);
        ASSERT_LE(d, 0.05 + 1e-6);
        max_offset = std::max(max_offset, d);
        is_moved |= d > 0;
      }
      moved += is_moved ? 1 : 0;
    }
    EXPECT_EQ(moved, 8);  // round(0.2 * 41)
  }
  EXPECT_GT(max_offset, 0.045);
}

TEST(NoiseModules, JitterHasTheConfiguredStd) {
  const NoisePipeline pipeline =
      Build("modules: [{name: jitter, sigma: 0.01}]");
  double sum2 = 0.0;
  int n = 0;
  for (int i = 0; i < 1000; ++i) {
    const MarkerFrame frame = Noisy(pipeline, i);
    for (int l = 0; l < kLabels; ++l) {
      for (int c = 0; c < 3; ++c) {
        const double d = frame.point(l)[c] - CleanMarkers()[l][c];
        sum2 += d * d;
        ++n;
      }
    }
  }
  EXPECT_NEAR(std::sqrt(sum2 / n), 0.01, 0.0003);
}

TEST(NoiseModules, PermutationShufflesPointsWithTheirLabels) {
  const NoisePipeline pipeline = Build(
      "modules: [{name: ghosts, max_count: 3, exact: true, up_to: false}, "
      "{name: permutation}]");
  int fixed = 0;
  for (int i = 0; i < 200; ++i) {
    const MarkerFrame frame = Noisy(pipeline, i);
    std::vector<int> seen(kLabels, 0);
    int ghosts = 0;
    for (int p = 0; p < frame.num_points(); ++p) {
      const int label = frame.labels[p];
      if (label == kLabels) {
        ++ghosts;
        continue;
      }
      ++seen[label];
      fixed += p == label ? 1 : 0;
      for (int c = 0; c < 3; ++c) {
        EXPECT_EQ(frame.point(p)[c], CleanMarkers()[label][c]);
      }
    }
    EXPECT_EQ(ghosts, 3);
    for (int l = 0; l < kLabels; ++l) EXPECT_EQ(seen[l], 1);
  }
  EXPECT_LT(fixed, 200 * 3);  // ~1 fixed point per frame on average
}

TEST(NoisePipeline, ProbabilityZeroNeverAppliesAndHalfAboutHalf) {
  const NoisePipeline never = Build(
      "modules: [{name: occlusion, probability: 0.0, max_count: 2, exact: "
      "true}]");
  const NoisePipeline half = Build(
      "modules: [{name: occlusion, probability: 0.5, max_count: 2, exact: "
      "true}]");
  const NoisePipeline always = Build(
      "modules: [{name: occlusion, probability: 1, max_count: 2, exact: "
      "true}]");
  int applied_half = 0;
  for (int i = 0; i < kFrames; ++i) {
    ASSERT_EQ(Noisy(never, i).NumAvailableMarkers(), kLabels);
    ASSERT_EQ(Noisy(always, i).NumAvailableMarkers(), kLabels - 2);
    applied_half += Noisy(half, i).NumAvailableMarkers() < kLabels ? 1 : 0;
  }
  EXPECT_NEAR(applied_half / static_cast<double>(kFrames), 0.5, 0.02);
}

TEST(NoisePipeline, StagesRunInConfigOrderWithDisjointGhostSlots) {
  const NoisePipeline pipeline = Build(R"(
modules:
  - {name: ghosts, max_count: 2, exact: true, up_to: false}
  - {name: occlusion, max_count: 1, exact: true}
  - {name: ghosts, distribution: uniform, max_count: 3, exact: true, up_to: false}
  - permutation
)");
  EXPECT_EQ(pipeline.stage_names(),
            (std::vector<std::string>{
                "ghosts", "occlusion", "ghosts", "permutation"}));
  EXPECT_EQ(pipeline.num_ghost_slots(), 5);
  EXPECT_EQ(pipeline.Describe(),
            "ghosts(p=1.0) -> occlusion(p=1.0) -> ghosts(p=1.0) -> "
            "permutation(p=1.0)");
  for (int i = 0; i < 100; ++i) {
    const MarkerFrame frame = Noisy(pipeline, i);
    int present = 0;
    for (int p = 0; p < frame.num_points(); ++p)
      present += frame.IsPresent(p) ? 1 : 0;
    EXPECT_EQ(present, kLabels - 1 + 5);
  }
}

TEST(NoisePipeline, JitterOnlyMovesGhostsThatExistBeforeIt) {
  // Order matters: jitter (include_ghosts) before ghosts leaves the ghosts
  // exactly at what the ghost stage drew; after ghosts it moves them.
  const NoisePipeline before = Build(
      "modules: [{name: jitter, sigma: 0.5, include_ghosts: true}, {name: "
      "ghosts, distribution: uniform, max_count: 2, exact: true, up_to: "
      "false}]");
  const NoisePipeline after = Build(
      "modules: [{name: ghosts, distribution: uniform, max_count: 2, exact: "
      "true, up_to: false}, {name: jitter, sigma: 0.5, include_ghosts: "
      "true}]");
  const NoisePipeline ghosts_only = Build(
      "modules: [{name: ghosts, distribution: uniform, max_count: 2, exact: "
      "true, up_to: false}]");
  for (int i = 0; i < 20; ++i) {
    const MarkerFrame a = Noisy(before, i);
    const MarkerFrame b = Noisy(after, i);
    const MarkerFrame g = Noisy(ghosts_only, i);
    for (int s = kLabels; s < kLabels + 2; ++s) {
      for (int c = 0; c < 3; ++c) {
        EXPECT_EQ(a.point(s)[c], g.point(s)[c]);
        EXPECT_NE(b.point(s)[c], g.point(s)[c]);
      }
    }
  }
}

TEST(NoisePipeline, StagesDrawFromIndependentStreams) {
  // Adding a stage in front does not change what a later stage draws.
  const NoisePipeline a = Build("modules: [{name: occlusion, max_count: 5}]");
  const NoisePipeline b = Build(
      "modules: [{name: ghosts, max_count: 3}, {name: occlusion, max_count: "
      "5}]");
  for (int i = 0; i < 200; ++i) {
    const MarkerFrame fa = Noisy(a, i);
    const MarkerFrame fb = Noisy(b, i);
    for (int l = 0; l < kLabels; ++l) {
      EXPECT_EQ(fa.IsPresent(l), fb.IsPresent(l)) << i << " " << l;
    }
  }
}

TEST(NoisePipeline, DeterministicForTheSameStream) {
  const NoisePipeline pipeline = Build(R"(
modules:
  - {name: occlusion, max_count: 5}
  - {name: ghosts, max_count: 3}
  - {name: shift, fraction: 0.1, max_offset: 0.02}
  - {name: jitter, sigma: 0.003}
  - {name: permutation}
)");
  for (int i = 0; i < 50; ++i) {
    const MarkerFrame a = Noisy(pipeline, i);
    const MarkerFrame b = Noisy(pipeline, i);
    EXPECT_EQ(a.points, b.points);
    EXPECT_EQ(a.labels, b.labels);
    // Missing points are null.
    for (int p = 0; p < a.num_points(); ++p) {
      if (!a.IsPresent(p)) {
        EXPECT_EQ(a.labels[p], kLabels);
      }
    }
  }
  EXPECT_NE(Noisy(pipeline, 1).points, Noisy(pipeline, 2).points);
}

TEST(NoisePipeline, EmptyConfigIsNoNoise) {
  EXPECT_EQ(Build("{}").num_stages(), 0);
  EXPECT_EQ(Build("modules: []").num_stages(), 0);
  BuildContext ctx;
  EXPECT_EQ(BuildNoisePipeline(ConfigNode(), ctx).num_stages(), 0);
  const NoisePipeline none = Build("modules: []");
  const MarkerFrame frame = Noisy(none, 0);
  EXPECT_EQ(frame.NumAvailableMarkers(), kLabels);
}

TEST(NoisePipeline, BadInputIsAClearConfigError) {
  std::string message = testing::ErrorMessage<ConfigError>(
      [] { Build("modules: [{name: occlussion}]"); });
  EXPECT_NE(message.find("occlussion"), std::string::npos) << message;
  for (const char* name : {"occlusion",
                           "ghosts",
                           "jitter",
                           "shift",
                           "real_noise",
                           "permutation"}) {
    EXPECT_NE(message.find(name), std::string::npos) << message;
  }
  message = testing::ErrorMessage<ConfigError>(
      [] { Build("modules: [{name: occlusion, probability: 1.5}]"); });
  EXPECT_NE(message.find("modules[0].probability = 1.5"), std::string::npos)
      << message;
  EXPECT_NE(message.find("0 <= probability <= 1"), std::string::npos);
  message = testing::ErrorMessage<ConfigError>(
      [] { Build("modules: [{name: occlusion, probability: -0.1}]"); });
  EXPECT_NE(message.find("probability"), std::string::npos) << message;
  message = testing::ErrorMessage<ConfigError>(
      [] { Build("modules: [{name: occlusion, max_cont: 3}]"); });
  EXPECT_NE(message.find("max_cont"), std::string::npos) << message;
  message = testing::ErrorMessage<ConfigError>(
      [] { Build("modules: [{name: ghosts, distribution: gaussian}]"); });
  EXPECT_NE(message.find("spherical_gaussian"), std::string::npos) << message;
  EXPECT_THROW(Build("modules: [{name: ghosts, max_count: 5000}]"),
               ConfigError);
  EXPECT_THROW(Build("modules: [{name: occlusion, max_count: -1}]"),
               ConfigError);
  EXPECT_THROW(Build("modules: [{name: shift, fraction: 2}]"), ConfigError);
  EXPECT_THROW(Build("modules: [{name: jitter, sigma: -1}]"), ConfigError);
  message = testing::ErrorMessage<ConfigError>(
      [] { Build("modules: [{name: permutation}, {name: jitter}]"); });
  EXPECT_NE(message.find("last"), std::string::npos) << message;
  EXPECT_THROW(Build("modules: {name: jitter}"), ConfigError);
  EXPECT_THROW(Build("modules: [{probability: 1}]"), ConfigError);
  EXPECT_THROW(Build("modulez: []"), ConfigError);
}

TEST(NoisePipeline, ApplyChecksTheFrameSize) {
  const NoisePipeline pipeline = Build("modules: [{name: ghosts}]");
  MarkerFrame frame;
  frame.Reset(kLabels, 0);  // no ghost slots
  EXPECT_THROW(pipeline.Apply(&frame, Rng(1)), ShapeError);
}

TEST(NoisePipeline, ProjectConfigsBuild) {
  const std::filesystem::path dir = testing::SourceDir() / "configs" / "noise";
  const std::map<std::string, int> expected_slots = {
      {"b", 0}, {"b_c", 0}, {"b_g", 3}, {"b_c_g", 3}, {"extreme_ghosts", 60}};
  for (const auto& [name, slots] : expected_slots) {
    SCOPED_TRACE(name);
    const ConfigFile file = LoadConfigFile(dir / (name + ".yaml"));
    BuildContext ctx;
    const NoisePipeline pipeline = BuildNoisePipeline(file.content, ctx);
    EXPECT_EQ(pipeline.num_ghost_slots(), slots);
    EXPECT_EQ(pipeline.stage_names().back(), "permutation");
  }
  const ConfigFile file = LoadConfigFile(dir / "b_c_g.yaml");
  BuildContext ctx;
  EXPECT_EQ(BuildNoisePipeline(file.content, ctx).stage_names(),
            (std::vector<std::string>{"occlusion", "ghosts", "permutation"}));
}

// ---- Real-noise bank.

TEST(NoiseBank, BuildEqualisesAndShufflesPerLabel) {
  // 3 labels; label 0 observed in 4 frames, label 1 in 2, label 2 never.
  const std::vector<std::string> labels = {"A", "B", "C"};
  std::vector<float> observed(4 * 3 * 3, 0.0f);
  std::vector<float> simulated(4 * 3 * 3, 1.0f);
  for (int f = 0; f < 4; ++f) {
    observed[3 * (f * 3 + 0)] = 1.0f + 0.1f * f;  // residual x = 0.1 f
    observed[3 * (f * 3 + 0) + 1] = 1.0f;
    observed[3 * (f * 3 + 0) + 2] = 1.0f;
    if (f < 2) {
      for (int c = 0; c < 3; ++c) observed[3 * (f * 3 + 1) + c] = 2.0f;
    }
  }
  Rng rng(3);
  const NoiseBank bank = BuildNoiseBank(labels, observed, simulated, rng);
  ASSERT_EQ(bank.num_rows, 4);
  bank.Validate();
  std::vector<float> xs;
  for (int k = 0; k < 4; ++k) {
    xs.push_back(bank.row(k)[0]);
    for (int c = 0; c < 3; ++c) EXPECT_FLOAT_EQ(bank.row(k)[3 + c], 1.0f);
    for (int c = 0; c < 3; ++c) EXPECT_EQ(bank.row(k)[6 + c], 0.0f);
  }
  std::sort(xs.begin(), xs.end());
  for (int k = 0; k < 4; ++k) EXPECT_NEAR(xs[k], 0.1f * k, 1e-6);
  EXPECT_THROW(BuildNoiseBank(labels, observed, std::vector<float>(3), rng),
               ShapeError);
}

TEST(NoiseBank, FileRoundTripAndRealNoiseModule) {
  const std::filesystem::path dir = testing::CreateTestDir();
  NoiseBank bank;
  bank.labels = Labels(kLabels);
  bank.num_rows = 5;
  Rng rng(1);
  for (int i = 0; i < 5 * kLabels * 3; ++i) {
    bank.residuals.push_back(static_cast<float>(0.01 * rng.Normal()));
  }
  const std::filesystem::path path = dir / "bank.h5";
  WriteNoiseBank(bank, path);
  const NoiseBank read = ReadNoiseBank(path);
  EXPECT_EQ(read.labels, bank.labels);
  EXPECT_EQ(read.num_rows, 5);
  EXPECT_EQ(read.residuals, bank.residuals);

  const NoisePipeline pipeline = Build(fmt::format(
      "modules: [{{name: real_noise, path: '{}'}}]", path.string()));
  pipeline.Validate(Labels(kLabels));
  EXPECT_THROW(pipeline.Validate(Labels(kLabels - 1)), ConfigError);
  for (int i = 0; i < 20; ++i) {
    const MarkerFrame frame = Noisy(pipeline, i);
    // Every marker moved by one bank row's residual for its label.
    bool matched_row = false;
    for (int k = 0; k < 5 && !matched_row; ++k) {
      bool all = true;
      for (int l = 0; l < kLabels && all; ++l) {
        for (int c = 0; c < 3; ++c) {
          all &= std::abs(frame.point(l)[c] - CleanMarkers()[l][c] -
                          bank.row(k)[3 * l + c]) < 1e-6;
        }
      }
      matched_row = all;
    }
    EXPECT_TRUE(matched_row) << i;
  }

  // Bad files.
  EXPECT_THROW(ReadNoiseBank(dir / "missing.h5"), IoError);
  { std::ofstream(dir / "text.h5") << "not hdf5"; }
  EXPECT_THROW(ReadNoiseBank(dir / "text.h5"), IoError);
  std::filesystem::copy_file(path, dir / "truncated.h5");
  std::filesystem::resize_file(dir / "truncated.h5",
                               std::filesystem::file_size(path) / 2);
  EXPECT_THROW(ReadNoiseBank(dir / "truncated.h5"), IoError);
}

}  // namespace
}  // namespace soma
