// Seeded random streams with named sub-streams.
//
// One seed in the config drives every random stream. A component asks for
// `rng.Stream("noise/occlusion")`; the sub-stream's seed is a hash of the
// parent seed and the name, so adding a component (a new name) never shifts the
// numbers another component draws. All distributions are implemented here
// (not std::*_distribution, whose output is implementation-defined), so the
// same seed gives the same numbers with any standard library.
#pragma once

#include <cstdint>
#include <string_view>
#include <vector>

namespace soma {

/// 64-bit FNV-1a hash of a byte string (stable across platforms/runs).
uint64_t Fnv1a64(std::string_view bytes, uint64_t seed = 0xcbf29ce484222325ULL);

/// SplitMix64 finaliser: a bijective 64-bit mixer.
uint64_t Mix64(uint64_t x);

/// A xoshiro256** generator with deterministic distributions.
class Rng {
 public:
  explicit Rng(uint64_t seed = 0);

  /// An independent generator whose seed depends only on this generator's
  /// *seed* and `name` (not on how many numbers were drawn so far).
  Rng Stream(std::string_view name) const;
  /// Same, for an integer index (e.g. job, frame or worker number).
  Rng Stream(uint64_t index) const;

  uint64_t seed() const { return seed_; }

  uint64_t NextU64();
  /// Uniform in [0, 1) with 53 random bits.
  double Uniform();
  /// Uniform in [lo, hi).
  double Uniform(double lo, double hi);
  /// Uniform integer in [lo, hi] (inclusive), unbiased (Lemire's method).
  int64_t UniformInt(int64_t lo, int64_t hi);
  /// Standard normal (Marsaglia polar method).
  double Normal();
  double Normal(double mean, double stddev);
  /// True with probability p.
  bool Bernoulli(double p);
  /// A uniformly random permutation of 0..n-1 (Fisher-Yates).
  std::vector<int> Permutation(int n);
  /// k distinct indices from 0..n-1, in random order (partial Fisher-Yates).
  std::vector<int> SampleWithoutReplacement(int n, int k);

  /// Full generator state, for checkpoints (seed + 4 words + normal cache).
  struct State {
    uint64_t seed = 0;
    uint64_t s[4] = {0, 0, 0, 0};
    bool has_spare_normal = false;
    double spare_normal = 0.0;
  };
  State GetState() const;
  void SetState(const State& state);

 private:
  uint64_t seed_;
  uint64_t s_[4];
  bool has_spare_normal_ = false;
  double spare_normal_ = 0.0;
};

}  // namespace soma
