// The fast training engine's kernels alone, at the paper-size shapes (44
// points, 256 frames = 11,264 rows, d_model 125, 5 heads of 25): where a
// step's time goes when it is not in the kernels themselves. CPU time of the
// calling thread (one thread), so that a loaded machine disturbs it less than
// wall time.
//
//   soma_bench_train_fast_kernels_benchmark --benchmark_repetitions=5
//
// - Gemm/M/K: y = x W^T + b in blocks of 96 rows, as LinearOp::Forward calls
//   it; `sets` > 1 rotates over that many inputs and outputs (12 MB each at
//   K = 250), so they come from L3/DRAM as in a step.
// - WeightGrad/M/K/chunk: dW = dy^T x in row chunks, as LinearOp::Backward.
// - GemmBf16/M/K/backend: the forward product of Gemm with
//   train.precision=bf16 (MatMulBf16 on 64-row ranges, as LinearOp::Forward
//   calls it, the rounding of x to bf16 included), backend 1 = AVX512_BF16,
//   2 = AMX (skipped where the CPU lacks it).
// - WeightGradBf16/M/K/backend: dW = dy^T x as LinearOp::Backward computes
//   it with train.precision=bf16 (x packed, then dy read transposed in
//   blocks of 32 output rows; one thread).
// - AttentionProbs (fused) against Gemm + SoftmaxRows (the path it replaced)
//   and AttentionScoresGrad (fused dP = dO V^T + softmax backward), per head.
#include "framework/model/bf16_gemm.h"
#include "framework/model/fast_kernels.h"

#include <benchmark/benchmark.h>

#include <algorithm>
#include <random>
#include <vector>

namespace soma {
namespace {

using internal::AlignedFloats;
using internal::KernelIsa;
using internal::NumPanels;
using internal::RoundUp16;
using internal::WeightView;

constexpr int64_t kRows = 256 * 44;
constexpr int64_t kPoints = 44;
constexpr int64_t kHeadDim = 25;

KernelIsa Isa() { return internal::ResolveIsa(KernelIsa::kAuto); }

void Fill(AlignedFloats& buffer, size_t size, uint32_t seed) {
  buffer.Resize(size);
  std::mt19937 rng(seed);
  std::normal_distribution<float> normal;
  for (size_t i = 0; i < size; ++i) buffer.data()[i] = normal(rng);
}

/// The GFLOP/s counter of a product over all kRows rows: m outputs, k inputs.
void SetGemmRate(benchmark::State& state, int64_t m, int64_t k) {
  state.counters["GFLOP/s"] =
      benchmark::Counter(2.0 * kRows * m * k * state.iterations() / 1e9,
                         benchmark::Counter::kIsRate);
}

void BM_Gemm(benchmark::State& state) {
  const int64_t m = state.range(0), k = state.range(1);
  const int sets = static_cast<int>(state.range(2));
  const int64_t ldx = RoundUp16(k) + 16, ldy = RoundUp16(m) + 16;
  std::vector<AlignedFloats> xs(sets), ys(sets);
  for (int s = 0; s < sets; ++s) {
    Fill(xs[s], static_cast<size_t>(kRows * ldx + 16), s + 1);
    ys[s].Resize(static_cast<size_t>(kRows * ldy + 16));
  }
  AlignedFloats wt, bias;
  Fill(wt, static_cast<size_t>(k * RoundUp16(m) + 16), 99);
  Fill(bias, static_cast<size_t>(RoundUp16(m)), 98);
  const WeightView w{wt.data(), 16, RoundUp16(m), bias.data(), m, k};
  int s = 0;
  for (auto _ : state) {
    for (int64_t r0 = 0; r0 < kRows; r0 += 96) {
      internal::GemmPacked(Isa(),
                           xs[s].data() + r0 * ldx,
                           ldx,
                           std::min<int64_t>(96, kRows - r0),
                           w,
                           ys[s].data() + r0 * ldy,
                           ldy,
                           {},
                           0,
                           NumPanels(m));
    }
    benchmark::DoNotOptimize(ys[s].data());
    s = (s + 1) % sets;
  }
  SetGemmRate(state, m, k);
}

void BM_WeightGrad(benchmark::State& state) {
  const int64_t m = state.range(0), k = state.range(1);
  const int64_t chunk = state.range(2);
  const int64_t ldy = RoundUp16(m) + 16, ldx = RoundUp16(k) + 16;
  const int64_t kp = RoundUp16(k);
  AlignedFloats dy, x, dw;
  Fill(dy, static_cast<size_t>(kRows * ldy + 16), 1);
  Fill(x, static_cast<size_t>(kRows * ldx + 16), 2);
  dw.Resize(static_cast<size_t>(m * kp + 16));
  for (auto _ : state) {
    for (int64_t b0 = 0; b0 < kRows; b0 += chunk) {
      internal::GemmEpilogue ep;
      if (b0 > 0) {
        ep.residual = dw.data();
        ep.ld_residual = kp;
      }
      internal::GemmPackedStrided(Isa(),
                                  dy.data() + b0 * ldy,
                                  1,
                                  ldy,
                                  m,
                                  WeightView{x.data() + b0 * ldx,
                                             16,
                                             ldx,
                                             nullptr,
                                             k,
                                             std::min(chunk, kRows - b0)},
                                  dw.data(),
                                  kp,
                                  ep,
                                  0,
                                  NumPanels(k));
    }
    benchmark::DoNotOptimize(dw.data());
  }
  SetGemmRate(state, m, k);
}

/// Whether `backend` runs here; skips the benchmark with the reason if not.
bool Bf16BackendOrSkip(benchmark::State& state, internal::Bf16Backend backend) {
  const std::vector<internal::Bf16Backend> available =
      internal::AvailableBf16Backends();
  if (std::find(available.begin(), available.end(), backend) !=
      available.end()) {
    return true;
  }
  state.SkipWithError("this bf16 backend is not available on this CPU");
  return false;
}

void BM_GemmBf16(benchmark::State& state) {
  const int64_t m = state.range(0), k = state.range(1);
  const auto backend = static_cast<internal::Bf16Backend>(state.range(2));
  if (!Bf16BackendOrSkip(state, backend)) return;
  const int64_t ldx = RoundUp16(k) + 16, ldy = RoundUp16(m) + 16;
  AlignedFloats x, y, w, bias;
  Fill(x, static_cast<size_t>(kRows * ldx + 16), 1);
  y.Resize(static_cast<size_t>(kRows * ldy + 16));
  Fill(w, static_cast<size_t>(m * k), 99);  // W (m x k); B(l, j) = W[j][l]
  Fill(bias, static_cast<size_t>(RoundUp16(m)), 98);
  internal::PackedBf16 packed;
  internal::PrepareBf16B(k, m, &packed);
  internal::PackBf16B(w.data(), 1, k, 0, k, &packed);
  internal::Bf16Scratch scratch;
  scratch.backend = backend;
  for (auto _ : state) {
    for (int64_t r0 = 0; r0 < kRows; r0 += 64) {
      internal::MatMulBf16(x.data() + r0 * ldx,
                           ldx,
                           1,
                           std::min<int64_t>(64, kRows - r0),
                           packed,
                           bias.data(),
                           false,
                           y.data() + r0 * ldy,
                           ldy,
                           scratch);
    }
    benchmark::DoNotOptimize(y.data());
  }
  state.SetLabel(internal::Bf16BackendName(backend));
  SetGemmRate(state, m, k);
}

void BM_WeightGradBf16(benchmark::State& state) {
  const int64_t m = state.range(0), k = state.range(1);
  const auto backend = static_cast<internal::Bf16Backend>(state.range(2));
  if (!Bf16BackendOrSkip(state, backend)) return;
  const int64_t ldy = RoundUp16(m) + 16, ldx = RoundUp16(k) + 16;
  const int64_t kp = RoundUp16(k);
  AlignedFloats dy, x, dw;
  Fill(dy, static_cast<size_t>(kRows * ldy + 16), 1);
  Fill(x, static_cast<size_t>(kRows * ldx + 16), 2);
  dw.Resize(static_cast<size_t>(m * kp + 16));
  internal::PackedBf16 packed;
  internal::Bf16Scratch scratch;
  scratch.backend = backend;
  for (auto _ : state) {
    internal::PrepareBf16B(kRows, k, &packed);
    internal::PackBf16B(x.data(), ldx, 1, 0, kRows, &packed);
    for (int64_t m0 = 0; m0 < m; m0 += 32) {
      internal::MatMulBf16(dy.data() + m0,
                           1,
                           ldy,
                           std::min<int64_t>(32, m - m0),
                           packed,
                           nullptr,
                           false,
                           dw.data() + m0 * kp,
                           kp,
                           scratch);
    }
    benchmark::DoNotOptimize(dw.data());
  }
  state.SetLabel(internal::Bf16BackendName(backend));
  SetGemmRate(state, m, k);
}

/// One head's operands: q (n x dh, stride 3 * 144 as in [q | k | v]), k and v
/// transposed (dh x 48), probabilities and scores' gradient (n x 48).
struct Head {
  Head() {
    Fill(q, static_cast<size_t>(kPoints * kLdq + 16), 1);
    Fill(kt, static_cast<size_t>(kHeadDim * kNp + 16), 2);
    Fill(p, static_cast<size_t>(kPoints * kNp + 16), 3);
    ds.Resize(static_cast<size_t>(kPoints * kNp + 16));
  }
  static constexpr int64_t kLdq = 3 * 144;
  static constexpr int64_t kNp = 48;
  static constexpr float kScale = 0.2f;
  AlignedFloats q, kt, p, ds;
};

void BM_AttentionProbsFused(benchmark::State& state) {
  Head head;
  for (auto _ : state) {
    internal::AttentionProbs(Isa(),
                             head.q.data(),
                             Head::kLdq,
                             head.kt.data(),
                             Head::kNp,
                             kPoints,
                             kHeadDim,
                             Head::kScale,
                             head.p.data(),
                             Head::kNp);
    benchmark::DoNotOptimize(head.p.data());
  }
}

void BM_AttentionProbsGemmThenSoftmax(benchmark::State& state) {
  Head head;
  const std::vector<float> scales(static_cast<size_t>(kPoints), Head::kScale);
  internal::GemmEpilogue scaled;
  scaled.row_scale = scales.data();
  for (auto _ : state) {
    internal::GemmPacked(
        Isa(),
        head.q.data(),
        Head::kLdq,
        kPoints,
        WeightView{head.kt.data(), 16, Head::kNp, nullptr, kPoints, kHeadDim},
        head.p.data(),
        Head::kNp,
        scaled,
        0,
        NumPanels(kPoints));
    internal::SoftmaxRows(Isa(), head.p.data(), Head::kNp, kPoints, kPoints);
    benchmark::DoNotOptimize(head.p.data());
  }
}

void BM_AttentionScoresGradFused(benchmark::State& state) {
  Head head;
  for (auto _ : state) {
    internal::AttentionScoresGrad(Isa(),
                                  head.q.data(),
                                  Head::kLdq,
                                  head.kt.data(),
                                  Head::kNp,
                                  head.p.data(),
                                  Head::kNp,
                                  kPoints,
                                  kHeadDim,
                                  Head::kScale,
                                  head.ds.data(),
                                  Head::kNp);
    benchmark::DoNotOptimize(head.ds.data());
  }
}

/// The path AttentionScoresGrad replaced (commit 7a89151's
/// SoftmaxBackwardRows after a GEMM), kept here for the comparison.
__attribute__((target_clones("avx512f", "default"))) void SoftmaxBackwardRows(
    const float* __restrict p,
    int64_t ldp,
    int64_t n,
    float scale,
    float* __restrict ds,
    int64_t lds) {
  for (int64_t r = 0; r < n; ++r) {
    const float* pr = p + r * ldp;
    float* sr = ds + r * lds;
    float part[16] = {};
    int64_t j = 0;
    for (; j + 16 <= n; j += 16) {
      for (int e = 0; e < 16; ++e) part[e] += sr[j + e] * pr[j + e];
    }
    float dot = 0.0f;
    for (; j < n; ++j) dot += sr[j] * pr[j];
    for (int e = 0; e < 16; ++e) dot += part[e];
    for (j = 0; j < n; ++j) sr[j] = pr[j] * (sr[j] - dot) * scale;
  }
}

void BM_AttentionScoresGradGemmThenSoftmaxBackward(benchmark::State& state) {
  Head head;
  for (auto _ : state) {
    internal::GemmPacked(
        Isa(),
        head.q.data(),
        Head::kLdq,
        kPoints,
        WeightView{head.kt.data(), 16, Head::kNp, nullptr, kPoints, kHeadDim},
        head.ds.data(),
        Head::kNp,
        {},
        0,
        NumPanels(kPoints));
    SoftmaxBackwardRows(head.p.data(),
                        Head::kNp,
                        kPoints,
                        Head::kScale,
                        head.ds.data(),
                        Head::kNp);
    benchmark::DoNotOptimize(head.ds.data());
  }
}

// Forward shapes of a paper-size step: post1/post2 (250 x 250, 125 x 250),
// qkv (375 x 125), merge (125 x 125).
BENCHMARK(BM_Gemm)
    ->Args({250, 250, 1})
    ->Args({250, 250, 8})
    ->Args({375, 125, 1})
    ->Args({375, 125, 8})
    ->Args({125, 125, 8})
    ->Unit(benchmark::kMillisecond);
BENCHMARK(BM_WeightGrad)
    ->Args({250, 250, 256})
    ->Args({250, 250, 64})
    ->Args({375, 125, 256})
    ->Args({125, 250, 256})
    ->Unit(benchmark::kMillisecond);
BENCHMARK(BM_GemmBf16)
    ->Args({250, 250, 1})
    ->Args({375, 125, 1})
    ->Args({125, 125, 1})
    ->Args({250, 250, 2})
    ->Unit(benchmark::kMillisecond);
BENCHMARK(BM_WeightGradBf16)
    ->Args({250, 250, 1})
    ->Args({375, 125, 1})
    ->Args({125, 250, 1})
    ->Args({250, 250, 2})
    ->Unit(benchmark::kMillisecond);
BENCHMARK(BM_AttentionProbsFused);
BENCHMARK(BM_AttentionProbsGemmThenSoftmax);
BENCHMARK(BM_AttentionScoresGradFused);
BENCHMARK(BM_AttentionScoresGradGemmThenSoftmaxBackward);

}  // namespace
}  // namespace soma
