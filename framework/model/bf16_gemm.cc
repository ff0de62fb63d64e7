#include "framework/model/bf16_gemm.h"

#include "framework/core/error.h"

#include <algorithm>
#include <cstring>
#include <sys/syscall.h>
#include <unistd.h>

#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#include <immintrin.h>  // NOLINT(build/include_order)
#pragma GCC diagnostic pop

namespace soma::internal {
namespace {

constexpr int64_t kTile = 16;      // rows (and fp32 columns) of a tile
constexpr int64_t kTileK = 32;     // bf16 values of k per tile row
constexpr int64_t kRowBlock = 32;  // A rows per block (two tiles)
constexpr int64_t kChunkK = 1024;  // k per pass over B (a multiple of 32)
constexpr long kArchReqXcompPerm = 0x1023;
constexpr long kXfeatureXtiledata = 18;

inline uint16_t ToBf16(float value) {
  uint32_t bits;
  std::memcpy(&bits, &value, sizeof(bits));
  if ((bits & 0x7fffffffu) > 0x7f800000u) return 0x7fc0;  // NaN
  bits += 0x7fffu + ((bits >> 16) & 1u);
  return static_cast<uint16_t>(bits >> 16);
}

/// The AMX tile configuration (64-byte LDTILECFG operand).
struct alignas(64) TileConfig {
  uint8_t palette = 1;
  uint8_t start_row = 0;
  uint8_t reserved[14] = {};
  uint16_t colsb[16] = {};
  uint8_t rows[16] = {};
};

bool RequestAmx() {
  if (!__builtin_cpu_supports("avx512f")) return false;
  // CPUID.(EAX=7, ECX=0):EDX bit 22 = AMX-BF16, bit 24 = AMX-TILE.
  unsigned int eax = 7, ebx = 0, ecx = 0, edx = 0;
  __asm__ volatile("cpuid" : "+a"(eax), "=b"(ebx), "+c"(ecx), "=d"(edx));
  const bool has = ((edx >> 22) & 1u) != 0 && ((edx >> 24) & 1u) != 0;
  if (!has) return false;
  return syscall(SYS_arch_prctl, kArchReqXcompPerm, kXfeatureXtiledata) == 0;
}

/// A 32 x 32 block of C from a 32-row block of A (`k_pad` bf16 per row)
/// and column blocks `jb`, `jb + 1` of B; written to `out` (32 x 32 floats).
__attribute__((target("amx-tile,amx-bf16"))) void AmxBlock(const uint16_t* a,
                                                           int64_t k_pad,
                                                           const uint16_t* b,
                                                           int64_t kp_count,
                                                           int64_t jb,
                                                           float* out) {
  _tile_zero(0);
  _tile_zero(1);
  _tile_zero(2);
  _tile_zero(3);
  const uint16_t* b0 = b + jb * kp_count * 32;
  const uint16_t* b1 = b0 + kp_count * 32;
  const int64_t a_stride = k_pad * 2;
  for (int64_t k0 = 0; k0 < k_pad; k0 += kTileK) {
    _tile_loadd(4, a + k0, a_stride);
    _tile_loadd(5, a + kTile * k_pad + k0, a_stride);
    _tile_loadd(6, b0 + (k0 / 2) * 32, 64);
    _tile_loadd(7, b1 + (k0 / 2) * 32, 64);
    _tile_dpbf16ps(0, 4, 6);
    _tile_dpbf16ps(1, 4, 7);
    _tile_dpbf16ps(2, 5, 6);
    _tile_dpbf16ps(3, 5, 7);
  }
  _tile_stored(0, out, 128);
  _tile_stored(1, out + 16, 128);
  _tile_stored(2, out + 16 * 32, 128);
  _tile_stored(3, out + 16 * 32 + 16, 128);
}

/// The two 16-column halves of a 32-column block of C with `cols` valid
/// columns: their lane masks and `bias` (zero when null) loaded under them.
struct BlockColumns {
  __mmask16 mask0;
  __mmask16 mask1;
  __m512 bias0;
  __m512 bias1;
};

__attribute__((target("avx512f"), always_inline)) inline BlockColumns
LoadBlockColumns(int64_t cols, const float* bias) {
  BlockColumns out;
  out.mask0 = static_cast<__mmask16>(
      cols >= 16 ? 0xFFFF : (1u << std::max<int64_t>(cols, 0)) - 1u);
  out.mask1 = static_cast<__mmask16>(
      cols >= 32 ? 0xFFFF : (cols > 16 ? (1u << (cols - 16)) - 1u : 0u));
  out.bias0 = bias != nullptr ? _mm512_maskz_loadu_ps(out.mask0, bias)
                              : _mm512_setzero_ps();
  out.bias1 = bias != nullptr ? _mm512_maskz_loadu_ps(out.mask1, bias + 16)
                              : _mm512_setzero_ps();
  return out;
}

/// The block of AmxBlock with AVX512_BF16, stored as StoreBlock stores it:
/// `dst[r][j] (+)= sum + bias[j]` for `r < rows`, `j < cols`. Per group of 8
/// rows of A, 16 accumulators (8 rows x the two 16-column blocks of B); each
/// step broadcasts one k pair of a row of A (a 32-bit bf16 pair) against the
/// pair-interleaved columns of B, the layout the tiles read. Row groups at or
/// past `rows` are not computed (their A rows are zero padding). A is packed
/// by rows (`interleaved` false: row r's k values contiguous) or, for an A
/// read transposed, in B's own layout (two 16-row blocks of k pairs).
__attribute__((target("avx512f,avx512bf16"))) void DpBlock(const uint16_t* a,
                                                           bool interleaved,
                                                           int64_t k_pad,
                                                           const uint16_t* b,
                                                           int64_t kp_count,
                                                           int64_t jb,
                                                           int64_t rows,
                                                           int64_t cols,
                                                           const float* bias,
                                                           bool accumulate,
                                                           float* dst,
                                                           int64_t ld) {
  constexpr int kRows = 8;
  const uint16_t* b0 = b + jb * kp_count * 32;
  const uint16_t* b1 = b0 + kp_count * 32;
  const int64_t pairs = k_pad / 2;
  const BlockColumns columns = LoadBlockColumns(cols, bias);
  const int64_t pair_stride = interleaved ? 32 : 2;
  for (int64_t r0 = 0; r0 < rows; r0 += kRows) {
    __m512 acc0[kRows];
    __m512 acc1[kRows];
    const uint16_t* ar[kRows];
#pragma GCC unroll 8
    for (int r = 0; r < kRows; ++r) {
      acc0[r] = columns.bias0;
      acc1[r] = columns.bias1;
      const int64_t row = r0 + r;
      ar[r] = interleaved ? a + (row / kTile) * pairs * 32 + 2 * (row % kTile)
                          : a + row * k_pad;
    }
    for (int64_t p = 0; p < pairs; ++p) {
      const __m512i w0 = _mm512_loadu_si512(b0 + p * 32);
      const __m512i w1 = _mm512_loadu_si512(b1 + p * 32);
      const int64_t offset = p * pair_stride;
#pragma GCC unroll 8
      for (int r = 0; r < kRows; ++r) {
        uint32_t pair;
        std::memcpy(&pair, ar[r] + offset, sizeof(pair));
        const __m512i x = _mm512_set1_epi32(static_cast<int>(pair));
        acc0[r] = _mm512_dpbf16_ps(acc0[r],
                                   reinterpret_cast<const __m512bh&>(x),
                                   reinterpret_cast<const __m512bh&>(w0));
        acc1[r] = _mm512_dpbf16_ps(acc1[r],
                                   reinterpret_cast<const __m512bh&>(x),
                                   reinterpret_cast<const __m512bh&>(w1));
      }
    }
    const int group = static_cast<int>(std::min<int64_t>(kRows, rows - r0));
#pragma GCC unroll 8
    for (int r = 0; r < kRows; ++r) {
      if (r >= group) break;
      float* d = dst + (r0 + r) * ld;
      __m512 v0 = acc0[r];
      __m512 v1 = acc1[r];
      if (accumulate) {
        v0 = _mm512_add_ps(v0, _mm512_maskz_loadu_ps(columns.mask0, d));
        v1 = _mm512_add_ps(v1, _mm512_maskz_loadu_ps(columns.mask1, d + 16));
      }
      _mm512_mask_storeu_ps(d, columns.mask0, v0);
      _mm512_mask_storeu_ps(d + 16, columns.mask1, v1);
    }
  }
}

bool CpuHasAvx512Bf16() {
  if (!__builtin_cpu_supports("avx512f")) return false;
  // CPUID.(EAX=7, ECX=0):EAX = the highest sub-leaf;
  // CPUID.(EAX=7, ECX=1):EAX bit 5 = AVX512_BF16.
  unsigned int eax = 7, ebx = 0, ecx = 0, edx = 0;
  __asm__ volatile("cpuid" : "+a"(eax), "=b"(ebx), "+c"(ecx), "=d"(edx));
  if (eax < 1) return false;
  eax = 7;
  ecx = 1;
  __asm__ volatile("cpuid" : "+a"(eax), "=b"(ebx), "+c"(ecx), "=d"(edx));
  return ((eax >> 5) & 1u) != 0;
}

__attribute__((target("amx-tile"))) void LoadTileConfig() {
  TileConfig config;
  for (int t = 0; t < 8; ++t) {
    config.rows[t] = kTile;
    config.colsb[t] = 64;
  }
  // GCC does not model LDTILECFG as reading the whole 64 bytes and would
  // drop the stores above without this barrier.
  __asm__ volatile("" : : "r"(&config) : "memory");
  _tile_loadconfig(&config);
}

__attribute__((target("amx-tile"))) void ReleaseTiles() { _tile_release(); }

/// Rows [i0, i0 + 32) of A as bf16, `k_pad` per row, zero padded.
__attribute__((target("avx512f,avx512bf16,avx512vl,avx512bw"))) void
PackRowsOfA(const float* a,
            int64_t a_rs,
            int64_t a_cs,
            int64_t m,
            int64_t k,
            int64_t k_pad,
            int64_t i0,
            uint16_t* out) {
  const int64_t rows = std::min(kRowBlock, m - i0);
  // Rows past m, and the padding of k, are zero.
  for (int64_t r = 0; r < kRowBlock; ++r) {
    uint16_t* dst = out + r * k_pad;
    std::fill(dst + (r < rows ? k : 0), dst + k_pad, uint16_t{0});
  }
  if (a_rs == 1 && a_cs != 1) {
    // A stored transposed (the dW product reads dY^T): A(i, l) at
    // a[l * a_cs + i]. Blocks of 64 values of l, whose 64 source rows stay
    // in L1 while the block's rows of A gather 16 values at a time.
    const __m512i index = _mm512_mullo_epi32(
        _mm512_set_epi32(15, 14, 13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0),
        _mm512_set1_epi32(static_cast<int>(a_cs)));
    constexpr int64_t kBlockL = 64;
    const bool gather = a_cs <= (int64_t{1} << 26);
    for (int64_t l0 = 0; l0 < k; l0 += kBlockL) {
      const int64_t l1 = std::min(k, l0 + kBlockL);
      for (int64_t r = 0; r < rows; ++r) {
        uint16_t* dst = out + r * k_pad;
        const float* src = a + i0 + r;
        int64_t l = l0;
        if (gather) {
          for (; l + 16 <= l1; l += 16) {
            const __m512 v = _mm512_i32gather_ps(index, src + l * a_cs, 4);
            const __m256bh h = _mm512_cvtneps_pbh(v);
            std::memcpy(dst + l, &h, 32);
          }
        }
        for (; l < l1; ++l) dst[l] = ToBf16(src[l * a_cs]);
      }
    }
    return;
  }
  for (int64_t r = 0; r < rows; ++r) {
    uint16_t* dst = out + r * k_pad;
    const float* src = a + (i0 + r) * a_rs;
    int64_t l = 0;
    if (a_cs == 1) {
      for (; l + 16 <= k; l += 16) {
        const __m256bh v = _mm512_cvtneps_pbh(_mm512_loadu_ps(src + l));
        std::memcpy(dst + l, &v, 32);
      }
    }
    for (; l < k; ++l) dst[l] = ToBf16(src[l * a_cs]);
  }
}

/// `dst[r][j] (+)= src[r][j] (+ bias[j])` for a `rows x cols` (<= 32 x 32)
/// block; `src` has row stride 32.
__attribute__((target("avx512f"))) void StoreBlock(const float* src,
                                                   int64_t rows,
                                                   int64_t cols,
                                                   const float* bias,
                                                   bool accumulate,
                                                   float* dst,
                                                   int64_t ld) {
  const BlockColumns columns = LoadBlockColumns(cols, bias);
  for (int64_t r = 0; r < rows; ++r) {
    const float* s = src + r * 32;
    float* d = dst + r * ld;
    __m512 v0 = _mm512_add_ps(_mm512_loadu_ps(s), columns.bias0);
    __m512 v1 = _mm512_add_ps(_mm512_loadu_ps(s + 16), columns.bias1);
    if (accumulate) {
      v0 = _mm512_add_ps(v0, _mm512_maskz_loadu_ps(columns.mask0, d));
      v1 = _mm512_add_ps(v1, _mm512_maskz_loadu_ps(columns.mask1, d + 16));
    }
    _mm512_mask_storeu_ps(d, columns.mask0, v0);
    _mm512_mask_storeu_ps(d + 16, columns.mask1, v1);
  }
}

}  // namespace

bool AmxBf16Available() {
  static const bool available = RequestAmx();
  return available;
}

bool Avx512Bf16Available() {
  static const bool available = CpuHasAvx512Bf16();
  return available;
}

Bf16Backend DefaultBf16Backend() {
  if (AmxBf16Available()) return Bf16Backend::kAmx;
  if (Avx512Bf16Available()) return Bf16Backend::kAvx512;
  return Bf16Backend::kNone;
}

std::vector<Bf16Backend> AvailableBf16Backends() {
  std::vector<Bf16Backend> out;
  if (AmxBf16Available()) out.push_back(Bf16Backend::kAmx);
  if (Avx512Bf16Available()) out.push_back(Bf16Backend::kAvx512);
  return out;
}

const char* Bf16BackendName(Bf16Backend backend) {
  switch (backend) {
    case Bf16Backend::kAmx:
      return "AMX";
    case Bf16Backend::kAvx512:
      return "AVX512_BF16";
    case Bf16Backend::kNone:
      break;
  }
  return "none";
}

float RoundToBf16(float value) {
  const uint32_t bits = static_cast<uint32_t>(ToBf16(value)) << 16;
  float out;
  std::memcpy(&out, &bits, sizeof(out));
  return out;
}

void PrepareBf16B(int64_t k, int64_t n, PackedBf16* out) {
  out->k = k;
  out->n = n;
  out->k_pad = std::max<int64_t>(kTileK, (k + kTileK - 1) / kTileK * kTileK);
  out->n_pad = std::max<int64_t>(32, (n + 31) / 32 * 32);
  const size_t size = static_cast<size_t>(out->k_pad * out->n_pad);
  if (out->data.size() < size) out->data.resize(size);
  // Padding rows of k are written by PackBf16B's last range; padding columns
  // by every range.
}

namespace {

/// Pairs of rows of B with contiguous columns (`b_cs == 1`): 16 columns of
/// two rows converted and interleaved per step.
__attribute__((target("avx512f,avx512bf16,avx512bw,avx512vl"))) void
PackPairsContiguous(const float* r0,
                    const float* r1,
                    int64_t n,
                    int64_t blocks,
                    uint16_t* dst0,
                    int64_t block_stride) {
  const __m512i interleave = _mm512_set_epi16(31,
                                              15,
                                              30,
                                              14,
                                              29,
                                              13,
                                              28,
                                              12,
                                              27,
                                              11,
                                              26,
                                              10,
                                              25,
                                              9,
                                              24,
                                              8,
                                              23,
                                              7,
                                              22,
                                              6,
                                              21,
                                              5,
                                              20,
                                              4,
                                              19,
                                              3,
                                              18,
                                              2,
                                              17,
                                              1,
                                              16,
                                              0);
  for (int64_t jb = 0; jb < blocks; ++jb) {
    const int64_t j0 = jb * kTile;
    const __mmask16 mask = static_cast<__mmask16>(
        n - j0 >= 16 ? 0xFFFF : (n > j0 ? (1u << (n - j0)) - 1u : 0u));
    const __m512 v0 = r0 != nullptr ? _mm512_maskz_loadu_ps(mask, r0 + j0)
                                    : _mm512_setzero_ps();
    const __m512 v1 = r1 != nullptr ? _mm512_maskz_loadu_ps(mask, r1 + j0)
                                    : _mm512_setzero_ps();
    const __m512bh packed = _mm512_cvtne2ps_pbh(v1, v0);  // [v0 | v1]
    const __m512i pairs = _mm512_permutexvar_epi16(
        interleave, reinterpret_cast<const __m512i&>(packed));
    _mm512_storeu_si512(dst0 + jb * block_stride, pairs);
  }
}

/// A read transposed (`A(i, l) = a[l * a_cs + i]`, rows `i < rows` of a
/// 32-row block) in B's packed layout: two blocks of 16 rows, each `k_pad / 2`
/// k pairs of 16 interleaved rows; k and rows past the data are zero.
void PackPairsOfA(const float* a,
                  int64_t a_cs,
                  int64_t rows,
                  int64_t k,
                  int64_t k_pad,
                  uint16_t* out) {
  const int64_t pairs = k_pad / 2;
  for (int64_t l = 0; l < k_pad; l += 2) {
    PackPairsContiguous(l < k ? a + l * a_cs : nullptr,
                        l + 1 < k ? a + (l + 1) * a_cs : nullptr,
                        rows,
                        kRowBlock / kTile,
                        out + (l / 2) * 32,
                        pairs * 32);
  }
}

}  // namespace

void PackBf16B(const float* b,
               int64_t b_rs,
               int64_t b_cs,
               int64_t k_begin,
               int64_t k_end,
               PackedBf16* out) {
  SOMA_CHECK(k_begin % 2 == 0) << "PackBf16B: k_begin must be even";
  const int64_t kp_count = out->k_pad / 2;
  const int64_t blocks = out->n_pad / kTile;
  // The last range also zeroes the padding rows of k.
  const int64_t k_stop = k_end >= out->k ? out->k_pad : k_end;
  for (int64_t l = k_begin; l < k_stop; l += 2) {
    const int64_t kp = l / 2;
    const float* r0 = l < out->k ? b + l * b_rs : nullptr;
    const float* r1 = l + 1 < out->k ? b + (l + 1) * b_rs : nullptr;
    if (b_cs == 1) {
      PackPairsContiguous(
          r0, r1, out->n, blocks, out->data.data() + kp * 32, kp_count * 32);
      continue;
    }
    for (int64_t jb = 0; jb < blocks; ++jb) {
      uint16_t* dst = out->data.data() + (jb * kp_count + kp) * 32;
      for (int64_t jj = 0; jj < kTile; ++jj) {
        const int64_t j = jb * kTile + jj;
        const bool valid = j < out->n;
        dst[2 * jj] = valid && r0 != nullptr ? ToBf16(r0[j * b_cs]) : 0;
        dst[2 * jj + 1] = valid && r1 != nullptr ? ToBf16(r1[j * b_cs]) : 0;
      }
    }
  }
}

void MatMulBf16(const float* a,
                int64_t a_rs,
                int64_t a_cs,
                int64_t m,
                const PackedBf16& b,
                const float* bias,
                bool accumulate,
                float* c,
                int64_t ldc,
                Bf16Scratch& scratch) {
  const Bf16Backend backend = scratch.backend;
  SOMA_CHECK((backend == Bf16Backend::kAmx && AmxBf16Available()) ||
             (backend == Bf16Backend::kAvx512 && Avx512Bf16Available()))
      << "MatMulBf16: the bf16 backend " << Bf16BackendName(backend)
      << " is not available on this CPU";
  if (m <= 0 || b.n <= 0) return;
  const bool amx = backend == Bf16Backend::kAmx;
  // A read transposed (dW = dY^T X): AVX512_BF16 takes it pair-interleaved,
  // packed without a transpose; the tiles need it by rows.
  const bool interleaved = !amx && a_rs == 1 && a_cs != 1;
  const int64_t kp_count = b.k_pad / 2;
  // Chunks of k: the chunk of B (all column blocks) stays in L2 while every
  // row block of A uses it; partial sums go through C.
  const int64_t chunk = std::min(kChunkK, b.k_pad);
  scratch.a.resize(static_cast<size_t>(kRowBlock * chunk));
  scratch.c.resize(32 * 32);
  if (amx) LoadTileConfig();
  for (int64_t k0 = 0; k0 < std::max<int64_t>(b.k, 1); k0 += chunk) {
    const int64_t kc = std::min(chunk, b.k - k0);
    const int64_t kc_pad =
        std::max<int64_t>(kTileK, (kc + kTileK - 1) / kTileK * kTileK);
    const bool first = k0 == 0;
    for (int64_t i0 = 0; i0 < m; i0 += kRowBlock) {
      const int64_t rows = std::min(kRowBlock, m - i0);
      if (interleaved) {
        PackPairsOfA(a + k0 * a_cs + i0,
                     a_cs,
                     rows,
                     std::max<int64_t>(kc, 0),
                     kc_pad,
                     scratch.a.data());
      } else {
        PackRowsOfA(a + k0 * a_cs,
                    a_rs,
                    a_cs,
                    m,
                    std::max<int64_t>(kc, 0),
                    kc_pad,
                    i0,
                    scratch.a.data());
      }
      for (int64_t jb = 0; jb < b.n_pad / kTile; jb += 2) {
        const int64_t j0 = jb * kTile;
        const int64_t cols = std::min<int64_t>(32, b.n - j0);
        const float* block_bias =
            first && bias != nullptr ? bias + j0 : nullptr;
        const bool block_accumulate = accumulate || !first;
        if (!amx) {
          DpBlock(scratch.a.data(),
                  interleaved,
                  kc_pad,
                  b.data.data() + (k0 / 2) * 32,
                  kp_count,
                  jb,
                  rows,
                  cols,
                  block_bias,
                  block_accumulate,
                  c + i0 * ldc + j0,
                  ldc);
          continue;
        }
        AmxBlock(scratch.a.data(),
                 kc_pad,
                 b.data.data() + (k0 / 2) * 32,
                 kp_count,
                 jb,
                 scratch.c.data());
        StoreBlock(scratch.c.data(),
                   rows,
                   cols,
                   block_bias,
                   block_accumulate,
                   c + i0 * ldc + j0,
                   ldc);
      }
    }
  }
  if (amx) ReleaseTiles();
}

}  // namespace soma::internal
