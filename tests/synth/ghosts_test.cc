#include "framework/synth/ghosts.h"

#include "framework/core/random.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

namespace soma {
namespace {

TEST(Ghosts, LowerMedianAndUnbiasedStd) {
  std::vector<float> values = {3.0f, 1.0f, 10.0f, 2.0f};
  double median = 0.0;
  double sigma = 0.0;
  LowerMedianAndStd(&values, &median, &sigma);
  EXPECT_EQ(median, 2.0);  // the lower of 2 and 3, as torch.median
  EXPECT_DOUBLE_EQ(sigma, std::sqrt(50.0 / 3.0));  // mean 4, ss 1+9+36+4

  std::vector<float> odd = {0.5f, -1.5f, 4.0f};
  LowerMedianAndStd(&odd, &median, &sigma);
  EXPECT_EQ(median, 0.5);
  EXPECT_DOUBLE_EQ(sigma, std::sqrt((0.25 + 6.25 + 9.0) / 2.0));  // mean 1

  std::vector<float> single = {7.0f};
  LowerMedianAndStd(&single, &median, &sigma);
  EXPECT_EQ(median, 7.0);
  EXPECT_EQ(sigma, 0.0);
}

TEST(Ghosts, SphericalGhostsAreMedianPlusSigmaTimesNormalInDrawOrder) {
  GhostOptions options;
  options.up_to = false;
  GhostCentre centre;
  centre.median = {1.0, 2.0, 3.0};
  centre.sigma = {0.5, 0.0, 2.0};
  Rng rng(5);
  Rng reference(5);
  std::vector<float> xyz;
  std::vector<char> dropped;
  DrawGhosts(options, 4, centre, rng, &xyz, &dropped);
  ASSERT_EQ(xyz.size(), 12u);
  ASSERT_EQ(dropped, std::vector<char>(4, 0));
  for (int g = 0; g < 4; ++g) {
    for (int c = 0; c < 3; ++c) {
      const double expected =
          centre.median[c] + centre.sigma[c] * reference.Normal();
      EXPECT_EQ(xyz[3 * g + c], static_cast<float>(expected)) << g << c;
    }
    EXPECT_EQ(xyz[3 * g + 1], 2.0f);  // sigma 0: exactly the median
  }
  EXPECT_EQ(rng.Uniform(), reference.Uniform());  // nothing else was drawn
}

TEST(Ghosts, UpToRejectionDropsTheDrawnIndicesBelowTheCount) {
  GhostOptions options;
  options.distribution = GhostDistribution::kUniform;
  options.half_extent = 1.0;
  const int count = 3;
  int dropped_total = 0;
  const int frames = 20000;
  for (int i = 0; i < frames; ++i) {
    Rng rng = Rng(9).Stream(i);
    Rng reference = Rng(9).Stream(i);
    std::vector<float> xyz;
    std::vector<char> dropped;
    DrawGhosts(options, count, GhostCentre(), rng, &xyz, &dropped);
    std::vector<char> expected(count, 0);
    for (int k = 0; k < 3 * count; ++k) reference.Uniform(-1.0, 1.0);
    for (int g = 0; g < count; ++g) {
      const int64_t r = reference.UniformInt(0, 3 * count - 1);
      if (r < count) expected[r] = 1;
    }
    ASSERT_EQ(dropped, expected) << i;
    for (const float x : xyz) {
      ASSERT_GE(x, -1.0f);
      ASSERT_LE(x, 1.0f);
    }
    for (const char d : dropped) dropped_total += d;
  }
  // Each ghost survives with probability (1 - 1/(3 count))^count.
  const double kept = 1.0 - dropped_total / static_cast<double>(count * frames);
  EXPECT_NEAR(kept, std::pow(1.0 - 1.0 / (3.0 * count), count), 0.01);
}

}  // namespace
}  // namespace soma
