#include "framework/core/random.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <set>
#include <vector>

namespace soma {
namespace {

TEST(Rng, SameSeedSameSequence) {
  Rng a(42), b(42);
  for (int i = 0; i < 100; ++i) EXPECT_EQ(a.NextU64(), b.NextU64());
}

TEST(Rng, DifferentSeedsDiffer) {
  Rng a(1), b(2);
  int equal = 0;
  for (int i = 0; i < 100; ++i) equal += a.NextU64() == b.NextU64();
  EXPECT_EQ(equal, 0);
}

TEST(Rng, KnownFirstValuesAreStable) {
  // Golden values, pinned across builds and machines: every dataset, noise
  // draw and corruption depends on the generator, its named sub-streams and
  // its distributions, so "the same config and seed give byte-identical
  // data" holds only while these numbers hold. Change one only on purpose,
  // in the commit that changes the generator, and say so.
  Rng rng(0);
  EXPECT_EQ(rng.NextU64(), 1905207664160064169u);
  EXPECT_EQ(rng.NextU64(), 7642312046547803776u);
  EXPECT_EQ(Rng(0).Stream("noise/occlusion").NextU64(), 17209545034751847080u);
  EXPECT_EQ(Rng(42).Stream("synth").Stream(3).NextU64(), 3557457909057026912u);
  // Doubles compared bit for bit.
  Rng draws(7);
  EXPECT_EQ(std::bit_cast<uint64_t>(draws.Uniform()), 4606165688711853090u);
  EXPECT_EQ(std::bit_cast<uint64_t>(draws.Normal()), 4603721014294413876u);
  EXPECT_EQ(draws.UniformInt(0, 1000), 177);
  EXPECT_EQ(draws.Permutation(6), std::vector<int>({1, 5, 0, 4, 2, 3}));
}

TEST(Rng, StreamDependsOnNameNotOnDrawCount) {
  Rng root(7);
  Rng before = root.Stream("noise/occlusion");
  for (int i = 0; i < 10; ++i) root.NextU64();
  Rng after = root.Stream("noise/occlusion");
  EXPECT_EQ(before.NextU64(), after.NextU64());
  // Adding another named stream does not shift this one.
  Rng other = Rng(7).Stream("noise/ghost");
  EXPECT_NE(Rng(7).Stream("noise/occlusion").NextU64(), other.NextU64());
}

TEST(Rng, IndexedStreamsDiffer) {
  Rng root(3);
  EXPECT_NE(root.Stream(uint64_t{0}).NextU64(),
            root.Stream(uint64_t{1}).NextU64());
}

TEST(Rng, UniformMomentsAndRange) {
  Rng rng(11);
  const int n = 200000;
  double sum = 0, sum_sq = 0;
  for (int i = 0; i < n; ++i) {
    const double u = rng.Uniform();
    ASSERT_GE(u, 0.0);
    ASSERT_LT(u, 1.0);
    sum += u;
    sum_sq += u * u;
  }
  const double mean = sum / n;
  EXPECT_NEAR(mean, 0.5, 0.005);
  EXPECT_NEAR(sum_sq / n - mean * mean, 1.0 / 12.0, 0.002);
}

TEST(Rng, NormalMoments) {
  Rng rng(5);
  const int n = 200000;
  double sum = 0, sum_sq = 0;
  for (int i = 0; i < n; ++i) {
    const double x = rng.Normal(2.0, 3.0);
    sum += x;
    sum_sq += x * x;
  }
  const double mean = sum / n;
  EXPECT_NEAR(mean, 2.0, 0.03);
  EXPECT_NEAR(std::sqrt(sum_sq / n - mean * mean), 3.0, 0.03);
}

TEST(Rng, UniformIntIsInclusiveAndUnbiased) {
  Rng rng(9);
  std::vector<int> counts(6, 0);
  const int n = 60000;
  for (int i = 0; i < n; ++i) {
    const int64_t k = rng.UniformInt(0, 5);
    ASSERT_GE(k, 0);
    ASSERT_LE(k, 5);
    ++counts[k];
  }
  for (int c : counts) EXPECT_NEAR(c, n / 6.0, 5 * std::sqrt(n / 6.0));
}

TEST(Rng, PermutationIsAPermutation) {
  Rng rng(1);
  std::vector<int> perm = rng.Permutation(50);
  std::sort(perm.begin(), perm.end());
  for (int i = 0; i < 50; ++i) EXPECT_EQ(perm[i], i);
}

TEST(Rng, SampleWithoutReplacementIsDistinct) {
  Rng rng(2);
  const std::vector<int> sample = rng.SampleWithoutReplacement(41, 5);
  EXPECT_EQ(sample.size(), 5u);
  EXPECT_EQ(std::set<int>(sample.begin(), sample.end()).size(), 5u);
  for (int k : sample) {
    EXPECT_GE(k, 0);
    EXPECT_LT(k, 41);
  }
}

TEST(Rng, StateRoundTripContinuesTheSequence) {
  Rng rng(123);
  rng.Normal();  // leaves a cached spare normal
  const Rng::State state = rng.GetState();
  const double expected_a = rng.Normal();
  const uint64_t expected_b = rng.NextU64();
  Rng restored(0);
  restored.SetState(state);
  EXPECT_EQ(restored.Normal(), expected_a);
  EXPECT_EQ(restored.NextU64(), expected_b);
}

}  // namespace
}  // namespace soma
