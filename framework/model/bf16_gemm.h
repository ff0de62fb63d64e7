// bf16 matrix products (`train.precision=bf16`): inputs rounded to bfloat16
// (round to nearest even), products accumulated in fp32. Two backends compute
// the same blocks from the same packed operands:
// - Intel AMX (TDPBF16PS on the tile unit): ~2.5 TFLOP/s on one core of the
//   reference Xeon against ~0.14 TFLOP/s for the fp32 AVX-512 micro-kernel;
// - AVX512_BF16 (VDPBF16PS: 16 fp32 sums of two bf16 products per
//   instruction, twice the products of an fp32 FMA), on CPUs without AMX
//   such as AMD Zen4/Zen5.
// The training engine keeps fp32 master weights, BatchNorm, softmax, Sinkhorn
// and the loss; only the per-point convolutions' products (forward, dX, dW)
// go through here.
//
// C (m x n) = [C +] A B [+ bias] with A (m x k) and B (k x n) given by
// element strides, so the transposed operands of the backward pass are read
// in place: A(i, l) = a[i * a_rs + l * a_cs], B(l, j) = b[l * b_rs + j * b_cs].
// B is packed once (VNNI pairs of k, 16-column blocks) and shared by the
// threads; each MatMulBf16 call packs its own rows of A.
#pragma once

#include <cstdint>
#include <vector>

namespace soma::internal {

/// Which instructions compute the bf16 products.
enum class Bf16Backend {
  kNone,    // neither is available
  kAvx512,  // AVX512_BF16 (VDPBF16PS)
  kAmx,     // AMX-BF16 tiles (TDPBF16PS)
};

/// True when the CPU has AMX-BF16 and the kernel granted this process the
/// AMX tile state (arch_prctl ARCH_REQ_XCOMP_PERM; requested once).
bool AmxBf16Available();

/// True when the CPU has AVX512_BF16 (and the OS saves the AVX-512 state).
bool Avx512Bf16Available();

/// The fastest backend this machine has: AMX, else AVX512_BF16, else kNone.
Bf16Backend DefaultBf16Backend();

/// Every backend this machine can run (for tests and benchmarks).
std::vector<Bf16Backend> AvailableBf16Backends();

/// "AMX", "AVX512_BF16" or "none", for log lines.
const char* Bf16BackendName(Bf16Backend backend);

/// B packed for MatMulBf16: k rounded up to 32, n to 32.
struct PackedBf16 {
  std::vector<uint16_t> data;
  int64_t k = 0;
  int64_t n = 0;
  int64_t k_pad = 0;
  int64_t n_pad = 0;
};

/// Sizes `out` for a `k x n` B (zero padding included).
void PrepareBf16B(int64_t k, int64_t n, PackedBf16* out);

/// Packs rows `[k_begin, k_end)` of B (`k_begin` even) into `out` (sized by
/// PrepareBf16B); disjoint ranges may be packed concurrently.
void PackBf16B(const float* b,
               int64_t b_rs,
               int64_t b_cs,
               int64_t k_begin,
               int64_t k_end,
               PackedBf16* out);

/// Per-thread scratch of MatMulBf16, and the backend its products run on.
struct Bf16Scratch {
  std::vector<uint16_t> a;
  std::vector<float> c;
  Bf16Backend backend = DefaultBf16Backend();
};

/// `C[i][j] = (accumulate ? C[i][j] : 0) + bias[j] + sum_l A(i, l) B(l, j)`
/// for `i < m`, `j < b.n` (`bias` may be null), on `scratch.backend` (which
/// must be one of AvailableBf16Backends()).
void MatMulBf16(const float* a,
                int64_t a_rs,
                int64_t a_cs,
                int64_t m,
                const PackedBf16& b,
                const float* bias,
                bool accumulate,
                float* c,
                int64_t ldc,
                Bf16Scratch& scratch);

/// `value` rounded to bfloat16 and back (round to nearest even).
float RoundToBf16(float value);

}  // namespace soma::internal
