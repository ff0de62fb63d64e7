#include "framework/model/fast_kernels.h"

#include "framework/core/error.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <new>
#include <type_traits>

// GCC 12 reports -Wmaybe-uninitialized (and, for the reductions inlined into
// the attention tiles, -Wuninitialized) inside its own AVX-512 intrinsic
// headers (the `_mm512_undefined_*` idiom, GCC bug 105593).
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#pragma GCC diagnostic ignored "-Wuninitialized"
#include <immintrin.h>  // NOLINT(build/include_order)
#pragma GCC diagnostic pop

namespace soma::internal {
namespace {

constexpr int kRowTile = 8;    // rows per micro-kernel tile
constexpr int kPanelTile = 3;  // 16-wide panels per micro-kernel tile
// Rows per cache block of the GEMM (a multiple of both row tiles, 8 and 6).
constexpr int64_t kRowBlock = 96;

bool CpuHasAvx512() {
  static const bool has =
      __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512dq") &&
      __builtin_cpu_supports("avx512bw") && __builtin_cpu_supports("avx512vl");
  return has;
}

// ---------------------------------------------------------------------------
// Portable kernels.

void GemmPortable(const float* x,
                  int64_t ldx,
                  int64_t xks,
                  int64_t rows,
                  const WeightView& w,
                  float* y,
                  int64_t ldy,
                  const GemmEpilogue& ep,
                  int64_t panel_begin,
                  int64_t panel_end) {
  float acc[16];
  for (int64_t p = panel_begin; p < panel_end; ++p) {
    const float* wp = w.data + p * w.panel_stride;
    const int64_t width = std::min<int64_t>(16, w.rows - 16 * p);
    for (int64_t r = 0; r < rows; ++r) {
      const float* xr = x + r * ldx;
      for (int j = 0; j < 16; ++j) {
        acc[j] = w.bias != nullptr ? w.bias[16 * p + j] : 0.0f;
      }
      for (int64_t kk = 0; kk < w.cols; ++kk) {
        const float xv = xr[kk * xks];
        const float* wk = wp + kk * w.k_stride;
        for (int j = 0; j < width; ++j) acc[j] += xv * wk[j];
      }
      float* yr = y + r * ldy + 16 * p;
      const float* rr = ep.residual != nullptr
                            ? ep.residual + r * ep.ld_residual + 16 * p
                            : nullptr;
      for (int64_t j = 0; j < width; ++j) {
        float value = acc[j];
        if (ep.row_scale != nullptr) value *= ep.row_scale[r];
        if (rr != nullptr) value += rr[j];
        if (16 * p + j < ep.relu_columns) value = std::max(value, 0.0f);
        yr[j] = value;
      }
    }
  }
}

void SoftmaxRowsPortable(
    float* s, int64_t ld, int64_t rows, int64_t n, float* inv_sums) {
  for (int64_t r = 0; r < rows; ++r) {
    float* row = s + r * ld;
    float max = -std::numeric_limits<float>::infinity();
    for (int64_t j = 0; j < n; ++j) max = std::max(max, row[j]);
    float sum = 0.0f;
    for (int64_t j = 0; j < n; ++j) {
      row[j] = std::exp(row[j] - max);
      sum += row[j];
    }
    const float inv = 1.0f / sum;
    if (inv_sums != nullptr) {
      inv_sums[r] = inv;
    } else {
      for (int64_t j = 0; j < n; ++j) row[j] *= inv;
    }
  }
}

// ---------------------------------------------------------------------------
// AVX-512 kernels (compiled for AVX-512 regardless of the global flags; only
// called after a CPUID check).

#pragma GCC push_options
#pragma GCC target("avx512f,avx512dq,avx512bw,avx512vl,fma,avx2,bmi2")

inline __mmask16 LaneMask(int64_t valid) {
  if (valid >= 16) return 0xFFFF;
  if (valid <= 0) return 0;
  return static_cast<__mmask16>((1u << valid) - 1u);
}

/// R rows x P panels tile: acc = bias; acc += x * w over k; epilogue; store.
template <int R, int P>
void MicroKernel(const float* x,
                 int64_t ldx,
                 int64_t xks,
                 const WeightView& w,
                 const float* wp,
                 const float* bias,
                 float* y,
                 int64_t ldy,
                 int64_t first_column,
                 const GemmEpilogue& ep) {
  __m512 acc[R][P];
#pragma GCC unroll 4
  for (int p = 0; p < P; ++p) {
    const __m512 b = bias != nullptr ? _mm512_loadu_ps(bias + 16 * int64_t{p})
                                     : _mm512_setzero_ps();
#pragma GCC unroll 8
    for (int r = 0; r < R; ++r) acc[r][p] = b;
  }
  const int64_t k = w.cols;
  const int64_t panel_stride = w.panel_stride;
  const int64_t k_stride = w.k_stride;
  for (int64_t kk = 0; kk < k; ++kk) {
    __m512 wv[P];
#pragma GCC unroll 4
    for (int p = 0; p < P; ++p) {
      wv[p] = _mm512_loadu_ps(wp + p * panel_stride + kk * k_stride);
    }
#pragma GCC unroll 8
    for (int r = 0; r < R; ++r) {
      const __m512 xb = _mm512_set1_ps(x[r * ldx + kk * xks]);
#pragma GCC unroll 4
      for (int p = 0; p < P; ++p) {
        acc[r][p] = _mm512_fmadd_ps(xb, wv[p], acc[r][p]);
      }
    }
  }
  const __m512 zero = _mm512_setzero_ps();
  const __m512i lane =
      _mm512_set_epi32(15, 14, 13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0);
#pragma GCC unroll 4
  for (int p = 0; p < P; ++p) {
    const int64_t column = first_column + 16 * int64_t{p};
    const __mmask16 store = LaneMask(w.rows - column);
    const __mmask16 relu = _mm512_cmplt_epi32_mask(
        _mm512_add_epi32(lane, _mm512_set1_epi32(static_cast<int>(column))),
        _mm512_set1_epi32(
            static_cast<int>(std::min<int64_t>(ep.relu_columns, 1 << 30))));
#pragma GCC unroll 8
    for (int r = 0; r < R; ++r) {
      __m512 value = acc[r][p];
      if (ep.row_scale != nullptr) {
        value = _mm512_mul_ps(value, _mm512_set1_ps(ep.row_scale[r]));
      }
      if (ep.residual != nullptr) {
        value = _mm512_add_ps(
            value,
            _mm512_maskz_loadu_ps(store,
                                  ep.residual + r * ep.ld_residual + column));
      }
      value = _mm512_mask_max_ps(value, relu, value, zero);
      _mm512_mask_storeu_ps(y + r * ldy + column, store, value);
    }
  }
}

using MicroKernelFn = void (*)(const float*,
                               int64_t,
                               int64_t,
                               const WeightView&,
                               const float*,
                               const float*,
                               float*,
                               int64_t,
                               int64_t,
                               const GemmEpilogue&);

template <int R>
constexpr MicroKernelFn KernelFor(int panels) {
  return panels == 1   ? &MicroKernel<R, 1>
         : panels == 2 ? &MicroKernel<R, 2>
         : panels == 3 ? &MicroKernel<R, 3>
                       : &MicroKernel<std::min(R, 6), 4>;
}

MicroKernelFn SelectKernel(int rows, int panels) {
  switch (rows) {
    case 1:
      return KernelFor<1>(panels);
    case 2:
      return KernelFor<2>(panels);
    case 3:
      return KernelFor<3>(panels);
    case 4:
      return KernelFor<4>(panels);
    case 5:
      return KernelFor<5>(panels);
    case 6:
      return KernelFor<6>(panels);
    case 7:
      return KernelFor<7>(panels);
    default:
      return KernelFor<8>(panels);
  }
}

/// The epilogue of the tile starting at row r0.
GemmEpilogue TileEpilogue(const GemmEpilogue& ep, int64_t r0) {
  GemmEpilogue tile = ep;
  if (ep.residual != nullptr) tile.residual = ep.residual + r0 * ep.ld_residual;
  if (ep.row_scale != nullptr) tile.row_scale = ep.row_scale + r0;
  return tile;
}

void GemmAvx512(const float* x,
                int64_t ldx,
                int64_t xks,
                int64_t rows,
                const WeightView& w,
                float* y,
                int64_t ldy,
                const GemmEpilogue& ep,
                int64_t panel_begin,
                int64_t panel_end) {
  // Blocks of kRowBlock rows: a block's rows stay in L1/L2 while every panel
  // group reads them (streaming all rows once per panel group runs at ~65%
  // of the blocked speed once they exceed the L2).
  if (rows > kRowBlock) {
    for (int64_t r0 = 0; r0 < rows; r0 += kRowBlock) {
      GemmAvx512(x + r0 * ldx,
                 ldx,
                 xks,
                 std::min(kRowBlock, rows - r0),
                 w,
                 y + r0 * ldy,
                 ldy,
                 TileEpilogue(ep, r0),
                 panel_begin,
                 panel_end);
    }
    return;
  }
  for (int64_t p0 = panel_begin; p0 < panel_end;) {
    // Tiles of 8 rows x 3 panels, or 6 rows x 4 panels where that avoids a
    // 1- or 2-panel tile (load-bound): 4, 7 = 4 + 3 and 8 = 4 + 4 panels.
    const int64_t remaining = panel_end - p0;
    const int np =
        static_cast<int>(remaining == 4 || remaining == 7 || remaining == 8
                             ? 4
                             : std::min<int64_t>(kPanelTile, remaining));
    const int64_t row_tile = np == 4 ? 6 : kRowTile;
    const float* wp = w.data + p0 * w.panel_stride;
    const float* b = w.bias != nullptr ? w.bias + p0 * 16 : nullptr;
    const MicroKernelFn full = SelectKernel(static_cast<int>(row_tile), np);
    int64_t r0 = 0;
    for (; r0 + row_tile <= rows; r0 += row_tile) {
      full(x + r0 * ldx,
           ldx,
           xks,
           w,
           wp,
           b,
           y + r0 * ldy,
           ldy,
           p0 * 16,
           TileEpilogue(ep, r0));
    }
    if (r0 < rows) {
      SelectKernel(static_cast<int>(rows - r0), np)(x + r0 * ldx,
                                                    ldx,
                                                    xks,
                                                    w,
                                                    wp,
                                                    b,
                                                    y + r0 * ldy,
                                                    ldy,
                                                    p0 * 16,
                                                    TileEpilogue(ep, r0));
    }
    p0 += np;
  }
}

/// `dst[c * ldd + r] = src[r * lds + c]` for a tile of `rows x cols` (both
/// <= 16): 16 rows in registers, transposed with shuffles.
void TransposeTile16(const float* src,
                     int64_t lds,
                     int rows,
                     int cols,
                     float* dst,
                     int64_t ldd) {
  const __mmask16 load = LaneMask(cols);
  const __mmask16 store = LaneMask(rows);
  __m512 r[16];
#pragma GCC unroll 16
  for (int i = 0; i < 16; ++i) {
    r[i] = i < rows ? _mm512_maskz_loadu_ps(load, src + i * lds)
                    : _mm512_setzero_ps();
  }
  __m512 t[16];
#pragma GCC unroll 8
  for (int i = 0; i < 16; i += 2) {
    t[i] = _mm512_unpacklo_ps(r[i], r[i + 1]);
    t[i + 1] = _mm512_unpackhi_ps(r[i], r[i + 1]);
  }
#pragma GCC unroll 4
  for (int i = 0; i < 16; i += 4) {
    r[i] = _mm512_shuffle_ps(t[i], t[i + 2], _MM_SHUFFLE(1, 0, 1, 0));
    r[i + 1] = _mm512_shuffle_ps(t[i], t[i + 2], _MM_SHUFFLE(3, 2, 3, 2));
    r[i + 2] = _mm512_shuffle_ps(t[i + 1], t[i + 3], _MM_SHUFFLE(1, 0, 1, 0));
    r[i + 3] = _mm512_shuffle_ps(t[i + 1], t[i + 3], _MM_SHUFFLE(3, 2, 3, 2));
  }
#pragma GCC unroll 2
  for (int i = 0; i < 16; i += 8) {
#pragma GCC unroll 4
    for (int j = 0; j < 4; ++j) {
      t[i + j] = _mm512_shuffle_f32x4(r[i + j], r[i + j + 4], 0x88);
      t[i + j + 4] = _mm512_shuffle_f32x4(r[i + j], r[i + j + 4], 0xdd);
    }
  }
#pragma GCC unroll 8
  for (int j = 0; j < 8; ++j) {
    r[j] = _mm512_shuffle_f32x4(t[j], t[j + 8], 0x88);
    r[j + 8] = _mm512_shuffle_f32x4(t[j], t[j + 8], 0xdd);
  }
#pragma GCC unroll 16
  for (int c = 0; c < 16; ++c) {
    if (c < cols) _mm512_mask_storeu_ps(dst + c * ldd, store, r[c]);
  }
}

void TransposeAvx512(const float* src,
                     int64_t lds,
                     int64_t rows,
                     int64_t cols,
                     float* dst,
                     int64_t ldd) {
  for (int64_t r0 = 0; r0 < rows; r0 += 16) {
    for (int64_t c0 = 0; c0 < cols; c0 += 16) {
      TransposeTile16(src + r0 * lds + c0,
                      lds,
                      static_cast<int>(std::min<int64_t>(16, rows - r0)),
                      static_cast<int>(std::min<int64_t>(16, cols - c0)),
                      dst + c0 * ldd + r0,
                      ldd);
    }
  }
}

/// exp(x) for float lanes (Cephes polynomial, ~1 ulp; inputs clamped to the
/// finite range, -inf gives ~0).
inline __m512 Exp512(__m512 x) {
  const __m512 log2e = _mm512_set1_ps(1.44269504088896341f);
  const __m512 ln2_hi = _mm512_set1_ps(0.693359375f);
  const __m512 ln2_lo = _mm512_set1_ps(-2.12194440e-4f);
  x = _mm512_min_ps(_mm512_max_ps(x, _mm512_set1_ps(-87.5f)),
                    _mm512_set1_ps(88.5f));
  const __m512 n = _mm512_roundscale_ps(
      _mm512_mul_ps(x, log2e), _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
  __m512 r = _mm512_fnmadd_ps(n, ln2_hi, x);
  r = _mm512_fnmadd_ps(n, ln2_lo, r);
  __m512 p = _mm512_set1_ps(1.9875691500e-4f);
  p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(1.3981999507e-3f));
  p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(8.3334519073e-3f));
  p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(4.1665795894e-2f));
  p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(1.6666665459e-1f));
  p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(5.0000001201e-1f));
  p = _mm512_fmadd_ps(
      p, _mm512_mul_ps(r, r), _mm512_add_ps(r, _mm512_set1_ps(1.0f)));
  return _mm512_scalef_ps(p, n);
}

void SoftmaxRowsAvx512(
    float* s, int64_t ld, int64_t rows, int64_t n, float* inv_sums) {
  for (int64_t r = 0; r < rows; ++r) {
    float* row = s + r * ld;
    __m512 max = _mm512_set1_ps(-std::numeric_limits<float>::infinity());
    for (int64_t j = 0; j < n; j += 16) {
      const __mmask16 mask = LaneMask(n - j);
      max = _mm512_mask_max_ps(
          max, mask, max, _mm512_maskz_loadu_ps(mask, row + j));
    }
    const __m512 row_max = _mm512_set1_ps(_mm512_reduce_max_ps(max));
    __m512 sum = _mm512_setzero_ps();
    for (int64_t j = 0; j < n; j += 16) {
      const __mmask16 mask = LaneMask(n - j);
      const __m512 e =
          Exp512(_mm512_sub_ps(_mm512_maskz_loadu_ps(mask, row + j), row_max));
      sum = _mm512_mask_add_ps(sum, mask, sum, e);
      _mm512_mask_storeu_ps(row + j, mask, e);
    }
    const float inv = 1.0f / _mm512_reduce_add_ps(sum);
    if (inv_sums != nullptr) {
      inv_sums[r] = inv;
      continue;
    }
    const __m512 scale = _mm512_set1_ps(inv);
    for (int64_t j = 0; j < n; j += 16) {
      const __mmask16 mask = LaneMask(n - j);
      _mm512_mask_storeu_ps(
          row + j,
          mask,
          _mm512_mul_ps(_mm512_maskz_loadu_ps(mask, row + j), scale));
    }
  }
}

/// exp(x) for double lanes: x = n ln2 + r, |r| <= ln2/2, degree-11 Taylor
/// polynomial (relative error < 1e-14), scaled by 2^n.
inline __m512d Exp512d(__m512d x) {
  x = _mm512_min_pd(_mm512_max_pd(x, _mm512_set1_pd(-708.0)),
                    _mm512_set1_pd(709.0));
  const __m512d n =
      _mm512_roundscale_pd(_mm512_mul_pd(x, _mm512_set1_pd(1.4426950408889634)),
                           _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
  __m512d r =
      _mm512_fnmadd_pd(n, _mm512_set1_pd(6.93147180369123816490e-01), x);
  r = _mm512_fnmadd_pd(n, _mm512_set1_pd(1.90821492927058770002e-10), r);
  constexpr double kInvFactorial[] = {1.0 / 39916800,
                                      1.0 / 3628800,
                                      1.0 / 362880,
                                      1.0 / 40320,
                                      1.0 / 5040,
                                      1.0 / 720,
                                      1.0 / 120,
                                      1.0 / 24,
                                      1.0 / 6,
                                      1.0 / 2,
                                      1.0,
                                      1.0};
  __m512d p = _mm512_set1_pd(kInvFactorial[0]);
  for (int i = 1; i < 12; ++i)
    p = _mm512_fmadd_pd(p, r, _mm512_set1_pd(kInvFactorial[i]));
  return _mm512_scalef_pd(p, n);
}

void ExpAvx512(float* x, int64_t n) {
  for (int64_t i = 0; i < n; i += 16) {
    const __mmask16 mask = LaneMask(n - i);
    _mm512_mask_storeu_ps(
        x + i, mask, Exp512(_mm512_maskz_loadu_ps(mask, x + i)));
  }
}

void ExpAvx512(double* x, int64_t n) {
  for (int64_t i = 0; i < n; i += 8) {
    const __mmask8 mask =
        static_cast<__mmask8>(LaneMask(std::min<int64_t>(n - i, 8)));
    _mm512_mask_storeu_pd(
        x + i, mask, Exp512d(_mm512_maskz_loadu_pd(mask, x + i)));
  }
}

/// out[0, 8V) = sum_{c < count} m[c * ld + (0, 8V)] * w[c], accumulated in
/// registers.
template <int V>
void AccumulateRows(
    const double* m, int64_t ld, const double* w, int64_t count, double* out) {
  __m512d acc[V];
#pragma GCC unroll 8
  for (int v = 0; v < V; ++v) acc[v] = _mm512_setzero_pd();
  for (int64_t c = 0; c < count; ++c) {
    const __m512d wc = _mm512_set1_pd(w[c]);
    const double* row = m + c * ld;
#pragma GCC unroll 8
    for (int v = 0; v < V; ++v)
      acc[v] =
          _mm512_fmadd_pd(_mm512_load_pd(row + 8 * int64_t{v}), wc, acc[v]);
  }
#pragma GCC unroll 8
  for (int v = 0; v < V; ++v) _mm512_store_pd(out + 8 * int64_t{v}, acc[v]);
}

/// out[0, width) = sum_c m[c * ld + (0, width)] * w[c] (width % 8 == 0).
void WeightedRowSum(const double* m,
                    int64_t ld,
                    const double* w,
                    int64_t count,
                    int64_t width,
                    double* out) {
  for (int64_t x = 0; x < width; x += 64) {
    switch (std::min<int64_t>(8, (width - x) / 8)) {
      case 1:
        AccumulateRows<1>(m + x, ld, w, count, out + x);
        break;
      case 2:
        AccumulateRows<2>(m + x, ld, w, count, out + x);
        break;
      case 3:
        AccumulateRows<3>(m + x, ld, w, count, out + x);
        break;
      case 4:
        AccumulateRows<4>(m + x, ld, w, count, out + x);
        break;
      case 5:
        AccumulateRows<5>(m + x, ld, w, count, out + x);
        break;
      case 6:
        AccumulateRows<6>(m + x, ld, w, count, out + x);
        break;
      case 7:
        AccumulateRows<7>(m + x, ld, w, count, out + x);
        break;
      default:
        AccumulateRows<8>(m + x, ld, w, count, out + x);
        break;
    }
  }
}

/// `iters` scaling iterations (see SinkhornFrame) on zero-padded arrays:
/// `kernel` is rows x cols_p, `kernel_t` cols x rows_p (padding = 0), `a`,
/// `mu`, `acc` have rows_p entries, `b`, `nu` cols_p; padded a/b stay 0.
void SinkhornScalingAvx512(const double* kernel,
                           const double* kernel_t,
                           const double* mu,
                           const double* nu,
                           double* a,
                           double* b,
                           double* acc,
                           int64_t rows,
                           int64_t cols,
                           int64_t rows_p,
                           int64_t cols_p,
                           int iters) {
  for (int it = 0; it < iters; ++it) {
    WeightedRowSum(kernel_t, rows_p, b, cols, rows_p, acc);  // (K b)_i
    for (int64_t i = 0; i < rows_p; i += 8) {
      const __mmask8 valid =
          static_cast<__mmask8>(LaneMask(std::min<int64_t>(rows - i, 8)));
      _mm512_store_pd(
          a + i,
          _mm512_maskz_div_pd(
              valid, _mm512_load_pd(mu + i), _mm512_load_pd(acc + i)));
    }
    WeightedRowSum(kernel, cols_p, a, rows, cols_p, acc);  // (K^T a)_j
    for (int64_t j = 0; j < cols_p; j += 8) {
      const __mmask8 valid =
          static_cast<__mmask8>(LaneMask(std::min<int64_t>(cols - j, 8)));
      _mm512_store_pd(
          b + j,
          _mm512_maskz_div_pd(
              valid, _mm512_load_pd(nu + j), _mm512_load_pd(acc + j)));
    }
  }
}

/// `acc[r][c] = sum_d a[r * lda + d] * bt[d * ldbt + 16 c + lane]` over
/// d < dh: R rows of `a` times the transposed operand's P 16-lane panels,
/// accumulated in registers (the product both attention tiles start with).
template <int R, int P>
inline __attribute__((always_inline)) void RowsTimesPanels(
    const float* a,
    int64_t lda,
    const float* bt,
    int64_t ldbt,
    int64_t dh,
    __m512 (&acc)[R][P]) {
#pragma GCC unroll 8
  for (int r = 0; r < R; ++r) {
#pragma GCC unroll 3
    for (int c = 0; c < P; ++c) acc[r][c] = _mm512_setzero_ps();
  }
  for (int64_t kk = 0; kk < dh; ++kk) {
    __m512 wv[P];
#pragma GCC unroll 3
    for (int c = 0; c < P; ++c)
      wv[c] = _mm512_loadu_ps(bt + kk * ldbt + 16 * c);
#pragma GCC unroll 8
    for (int r = 0; r < R; ++r) {
      const __m512 xb = _mm512_set1_ps(a[r * lda + kk]);
#pragma GCC unroll 3
      for (int c = 0; c < P; ++c) {
        acc[r][c] = _mm512_fmadd_ps(xb, wv[c], acc[r][c]);
      }
    }
  }
}

/// R query rows of one attention head, n <= 16 P keys: the scores
/// `scale * q k^T` accumulated in registers (k read transposed, `kt[d * ldkt
/// + j]`), then each row's softmax in registers, stored to `p`.
template <int R, int P>
void ProbsTile(const float* q,
               int64_t ldq,
               const float* kt,
               int64_t ldkt,
               int64_t n,
               int64_t dh,
               float scale,
               float* p,
               int64_t ldp) {
  __m512 acc[R][P];
  RowsTimesPanels<R, P>(q, ldq, kt, ldkt, dh, acc);
  __mmask16 mask[P];
#pragma GCC unroll 3
  for (int c = 0; c < P; ++c) mask[c] = LaneMask(n - 16 * c);
  const __m512 vscale = _mm512_set1_ps(scale);
#pragma GCC unroll 8
  for (int r = 0; r < R; ++r) {
    __m512 max = _mm512_set1_ps(-std::numeric_limits<float>::infinity());
#pragma GCC unroll 3
    for (int c = 0; c < P; ++c) {
      acc[r][c] = _mm512_mul_ps(acc[r][c], vscale);
      max = _mm512_mask_max_ps(max, mask[c], max, acc[r][c]);
    }
    const __m512 row_max = _mm512_set1_ps(_mm512_reduce_max_ps(max));
    __m512 sum = _mm512_setzero_ps();
#pragma GCC unroll 3
    for (int c = 0; c < P; ++c) {
      acc[r][c] = Exp512(_mm512_sub_ps(acc[r][c], row_max));
      sum = _mm512_mask_add_ps(sum, mask[c], sum, acc[r][c]);
    }
    const __m512 inv = _mm512_set1_ps(1.0f / _mm512_reduce_add_ps(sum));
#pragma GCC unroll 3
    for (int c = 0; c < P; ++c) {
      _mm512_mask_storeu_ps(
          p + r * ldp + 16 * c, mask[c], _mm512_mul_ps(acc[r][c], inv));
    }
  }
}

/// R rows of the softmax backward of one head: `dp = dout v^T` in registers
/// (v read transposed, `vt[d * ldvt + j]`), then `ds = p * (dp - rowsum(dp *
/// p)) * scale`, stored to `ds`.
template <int R, int P>
void ScoresGradTile(const float* dout,
                    int64_t ldo,
                    const float* vt,
                    int64_t ldvt,
                    const float* p,
                    int64_t ldp,
                    int64_t n,
                    int64_t dh,
                    float scale,
                    float* ds,
                    int64_t lds) {
  __m512 acc[R][P];
  RowsTimesPanels<R, P>(dout, ldo, vt, ldvt, dh, acc);
  __mmask16 mask[P];
#pragma GCC unroll 3
  for (int c = 0; c < P; ++c) mask[c] = LaneMask(n - 16 * c);
  const __m512 vscale = _mm512_set1_ps(scale);
#pragma GCC unroll 8
  for (int r = 0; r < R; ++r) {
    __m512 pv[P];
    __m512 dot = _mm512_setzero_ps();
#pragma GCC unroll 3
    for (int c = 0; c < P; ++c) {
      pv[c] = _mm512_maskz_loadu_ps(mask[c], p + r * ldp + 16 * c);
      dot = _mm512_mask3_fmadd_ps(acc[r][c], pv[c], dot, mask[c]);
    }
    const __m512 row_dot = _mm512_set1_ps(_mm512_reduce_add_ps(dot));
#pragma GCC unroll 3
    for (int c = 0; c < P; ++c) {
      const __m512 value = _mm512_mul_ps(
          _mm512_mul_ps(pv[c], _mm512_sub_ps(acc[r][c], row_dot)), vscale);
      _mm512_mask_storeu_ps(ds + r * lds + 16 * c, mask[c], value);
    }
  }
}

/// Rows of one head in tiles of 8 (then the remainder), P = NumPanels(n).
template <int P, typename Tile>
void ForRowTiles(int64_t n, const Tile& tile) {
  int64_t r0 = 0;
  for (; r0 + 8 <= n; r0 += 8) tile(r0, std::integral_constant<int, 8>{});
  switch (n - r0) {
    case 7:
      tile(r0, std::integral_constant<int, 7>{});
      break;
    case 6:
      tile(r0, std::integral_constant<int, 6>{});
      break;
    case 5:
      tile(r0, std::integral_constant<int, 5>{});
      break;
    case 4:
      tile(r0, std::integral_constant<int, 4>{});
      break;
    case 3:
      tile(r0, std::integral_constant<int, 3>{});
      break;
    case 2:
      tile(r0, std::integral_constant<int, 2>{});
      break;
    case 1:
      tile(r0, std::integral_constant<int, 1>{});
      break;
    default:
      break;
  }
}

template <int P>
void AttentionProbsAvx512(const float* q,
                          int64_t ldq,
                          const float* kt,
                          int64_t ldkt,
                          int64_t n,
                          int64_t dh,
                          float scale,
                          float* p,
                          int64_t ldp) {
  ForRowTiles<P>(n, [&](int64_t r0, auto rows) {
    ProbsTile<decltype(rows)::value, P>(
        q + r0 * ldq, ldq, kt, ldkt, n, dh, scale, p + r0 * ldp, ldp);
  });
}

template <int P>
void AttentionScoresGradAvx512(const float* dout,
                               int64_t ldo,
                               const float* vt,
                               int64_t ldvt,
                               const float* p,
                               int64_t ldp,
                               int64_t n,
                               int64_t dh,
                               float scale,
                               float* ds,
                               int64_t lds) {
  ForRowTiles<P>(n, [&](int64_t r0, auto rows) {
    ScoresGradTile<decltype(rows)::value, P>(dout + r0 * ldo,
                                             ldo,
                                             vt,
                                             ldvt,
                                             p + r0 * ldp,
                                             ldp,
                                             n,
                                             dh,
                                             scale,
                                             ds + r0 * lds,
                                             lds);
  });
}

#pragma GCC pop_options

}  // namespace

KernelIsa ResolveIsa(KernelIsa isa) {
  if (isa == KernelIsa::kAuto)
    return CpuHasAvx512() ? KernelIsa::kAvx512 : KernelIsa::kPortable;
  if (isa == KernelIsa::kAvx512) {
    SOMA_CHECK(CpuHasAvx512())
        << "AVX-512 kernels requested on a CPU without AVX-512";
  }
  return isa;
}

void AlignedFloats::Free::operator()(float* p) const { std::free(p); }

void AlignedFloats::Resize(size_t size) {
  if (size <= size_) return;
  const size_t bytes = ((size * sizeof(float) + 63) / 64) * 64;
  void* memory = std::aligned_alloc(64, bytes);
  if (memory == nullptr) throw std::bad_alloc();
  std::memset(memory, 0, bytes);
  data_.reset(static_cast<float*>(memory));
  size_ = size;
}

PackedWeights PackWeights(const float* w,
                          const float* bias,
                          int64_t m,
                          int64_t k) {
  SOMA_CHECK(m > 0 && k > 0) << "PackWeights(" << m << " x " << k << ")";
  PackedWeights packed;
  packed.rows = m;
  packed.cols = k;
  const int64_t panels = NumPanels(m);
  packed.panels.Resize(static_cast<size_t>(panels * k * 16));
  packed.bias.Resize(static_cast<size_t>(panels * 16));
  for (int64_t row = 0; row < m; ++row) {
    float* dst = packed.panels.data() + (row / 16) * k * 16 + row % 16;
    for (int64_t col = 0; col < k; ++col) dst[col * 16] = w[row * k + col];
    if (bias != nullptr) packed.bias.data()[row] = bias[row];
  }
  return packed;
}

void GemmPacked(KernelIsa isa,
                const float* x,
                int64_t ldx,
                int64_t rows,
                const WeightView& w,
                float* y,
                int64_t ldy,
                const GemmEpilogue& epilogue,
                int64_t panel_begin,
                int64_t panel_end) {
  GemmPackedStrided(
      isa, x, ldx, 1, rows, w, y, ldy, epilogue, panel_begin, panel_end);
}

void GemmPackedStrided(KernelIsa isa,
                       const float* x,
                       int64_t ldx,
                       int64_t x_k_stride,
                       int64_t rows,
                       const WeightView& w,
                       float* y,
                       int64_t ldy,
                       const GemmEpilogue& epilogue,
                       int64_t panel_begin,
                       int64_t panel_end) {
  if (rows <= 0 || panel_begin >= panel_end) return;
  if (isa == KernelIsa::kAvx512) {
    GemmAvx512(
        x, ldx, x_k_stride, rows, w, y, ldy, epilogue, panel_begin, panel_end);
  } else {
    GemmPortable(
        x, ldx, x_k_stride, rows, w, y, ldy, epilogue, panel_begin, panel_end);
  }
}

void Transpose(KernelIsa isa,
               const float* src,
               int64_t lds,
               int64_t rows,
               int64_t cols,
               float* dst,
               int64_t ldd) {
  if (isa == KernelIsa::kAvx512) {
    TransposeAvx512(src, lds, rows, cols, dst, ldd);
    return;
  }
  for (int64_t r = 0; r < rows; ++r) {
    for (int64_t c = 0; c < cols; ++c) dst[c * ldd + r] = src[r * lds + c];
  }
}

void Gemm(KernelIsa isa,
          const float* x,
          int64_t ldx,
          int64_t rows,
          const PackedWeights& w,
          float* y,
          int64_t ldy,
          const GemmEpilogue& epilogue) {
  GemmPacked(isa, x, ldx, rows, w.view(), y, ldy, epilogue, 0, w.num_panels());
}

void SoftmaxRows(KernelIsa isa,
                 float* s,
                 int64_t ld,
                 int64_t rows,
                 int64_t n,
                 float* inv_sums) {
  if (isa == KernelIsa::kAvx512) {
    SoftmaxRowsAvx512(s, ld, rows, n, inv_sums);
  } else {
    SoftmaxRowsPortable(s, ld, rows, n, inv_sums);
  }
}

void ExpInPlace(KernelIsa isa, float* x, int64_t n) {
  if (isa == KernelIsa::kAvx512) {
    ExpAvx512(x, n);
  } else {
    for (int64_t i = 0; i < n; ++i) x[i] = std::exp(x[i]);
  }
}

void ExpInPlace(KernelIsa isa, double* x, int64_t n) {
  if (isa == KernelIsa::kAvx512) {
    ExpAvx512(x, n);
  } else {
    for (int64_t i = 0; i < n; ++i) x[i] = std::exp(x[i]);
  }
}

void AttentionProbs(KernelIsa isa,
                    const float* q,
                    int64_t ldq,
                    const float* kt,
                    int64_t ldkt,
                    int64_t n,
                    int64_t dh,
                    float scale,
                    float* p,
                    int64_t ldp) {
  if (isa == KernelIsa::kAvx512 && n <= kMaxFusedKeys) {
    switch (NumPanels(n)) {
      case 1:
        AttentionProbsAvx512<1>(q, ldq, kt, ldkt, n, dh, scale, p, ldp);
        return;
      case 2:
        AttentionProbsAvx512<2>(q, ldq, kt, ldkt, n, dh, scale, p, ldp);
        return;
      default:
        AttentionProbsAvx512<3>(q, ldq, kt, ldkt, n, dh, scale, p, ldp);
        return;
    }
  }
  const std::vector<float> scales(static_cast<size_t>(n), scale);
  GemmEpilogue scaled;
  scaled.row_scale = scales.data();
  GemmPacked(isa,
             q,
             ldq,
             n,
             WeightView{kt, 16, ldkt, nullptr, n, dh},
             p,
             ldp,
             scaled,
             0,
             NumPanels(n));
  SoftmaxRows(isa, p, ldp, n, n);
}

void AttentionScoresGrad(KernelIsa isa,
                         const float* dout,
                         int64_t ldo,
                         const float* vt,
                         int64_t ldvt,
                         const float* p,
                         int64_t ldp,
                         int64_t n,
                         int64_t dh,
                         float scale,
                         float* ds,
                         int64_t lds) {
  if (isa == KernelIsa::kAvx512 && n <= kMaxFusedKeys) {
    switch (NumPanels(n)) {
      case 1:
        AttentionScoresGradAvx512<1>(
            dout, ldo, vt, ldvt, p, ldp, n, dh, scale, ds, lds);
        return;
      case 2:
        AttentionScoresGradAvx512<2>(
            dout, ldo, vt, ldvt, p, ldp, n, dh, scale, ds, lds);
        return;
      default:
        AttentionScoresGradAvx512<3>(
            dout, ldo, vt, ldvt, p, ldp, n, dh, scale, ds, lds);
        return;
    }
  }
  GemmPacked(isa,
             dout,
             ldo,
             n,
             WeightView{vt, 16, ldvt, nullptr, n, dh},
             ds,
             lds,
             {},
             0,
             NumPanels(n));
  for (int64_t r = 0; r < n; ++r) {
    const float* pr = p + r * ldp;
    float* sr = ds + r * lds;
    float dot = 0.0f;
    for (int64_t j = 0; j < n; ++j) dot += sr[j] * pr[j];
    for (int64_t j = 0; j < n; ++j) sr[j] = pr[j] * (sr[j] - dot) * scale;
  }
}

void AttentionHead(KernelIsa isa,
                   const float* q,
                   const float* k,
                   const float* v,
                   int64_t ld_qkv,
                   int64_t n,
                   int64_t dh,
                   float* out,
                   int64_t ld_out,
                   AttentionScratch& scratch) {
  if (n <= 0) return;
  const int64_t key_panels = NumPanels(n);
  const int64_t ld_scores = RoundUp16(n);
  scratch.keys.Resize(static_cast<size_t>(key_panels * dh * 16));
  scratch.scores.Resize(static_cast<size_t>(n * ld_scores));
  scratch.inv_sums.Resize(static_cast<size_t>(n));
  // Keys as the "weights" of S = q k^T: panel p holds keys 16p..16p+15 (the
  // lanes past the last key stay zero).
  float* keys = scratch.keys.data();
  if (n % 16 != 0) {
    float* last = keys + (key_panels - 1) * dh * 16;
    std::memset(last, 0, sizeof(float) * dh * 16);
  }
  for (int64_t j = 0; j < n; ++j) {
    float* dst = keys + (j / 16) * dh * 16 + j % 16;
    const float* src = k + j * ld_qkv;
    for (int64_t d = 0; d < dh; ++d) dst[d * 16] = src[d];
  }
  float* scores = scratch.scores.data();
  GemmPacked(isa,
             q,
             ld_qkv,
             n,
             WeightView{keys, dh * 16, 16, nullptr, n, dh},
             scores,
             ld_scores,
             {},
             0,
             key_panels);
  // Unnormalised softmax; the 1/sum row scale is applied to P v instead.
  SoftmaxRows(isa, scores, ld_scores, n, n, scratch.inv_sums.data());
  // v is read in place as the "weights" of out = P v: panel p = channels
  // 16p..16p+15 of each key row (lanes >= dh are computed but not stored).
  GemmEpilogue normalize;
  normalize.row_scale = scratch.inv_sums.data();
  GemmPacked(isa,
             scores,
             ld_scores,
             n,
             WeightView{v, 16, ld_qkv, nullptr, dh, n},
             out,
             ld_out,
             normalize,
             0,
             NumPanels(dh));
}

void SinkhornScalingKernel(KernelIsa isa,
                           const double* z,
                           int64_t rows,
                           int64_t cols,
                           int64_t rows_p,
                           int64_t cols_p,
                           double zmax,
                           double* kernel,
                           double* kernel_t) {
  const double underflow = zmax - kSinkhornUnderflowNats;
  std::fill(kernel, kernel + rows * cols_p, 0.0);
  for (int64_t i = 0; i < rows; ++i) {
    double* kr = kernel + i * cols_p;
    const double* zr = z + i * cols;
    // -inf for the exact zeros: libm's exp takes a slow path (errno) on an
    // argument that underflows, not on -inf.
    for (int64_t j = 0; j < cols; ++j) {
      kr[j] = zr[j] < underflow ? -std::numeric_limits<double>::infinity()
                                : zr[j] - zmax;
    }
    ExpInPlace(isa, kr, cols);
    // The AVX-512 exp clamps its argument to e^-708: exact zeros.
    for (int64_t j = 0; j < cols; ++j) {
      if (zr[j] < underflow) kr[j] = 0.0;
    }
  }
  std::fill(kernel_t, kernel_t + cols * rows_p, 0.0);
  for (int64_t i = 0; i < rows; ++i) {
    for (int64_t j = 0; j < cols; ++j)
      kernel_t[j * rows_p + i] = kernel[i * cols_p + j];
  }
}

void SinkhornFrame(KernelIsa isa,
                   const float* scores,
                   int64_t ld_scores,
                   int64_t n,
                   int64_t l,
                   double alpha,
                   int num_iters,
                   float* out,
                   std::vector<double>& scratch) {
  const int64_t rows = n + 1;
  const int64_t cols = l + 1;
  // Padded to whole 8-double vectors (64-byte aligned blocks).
  const int64_t rows_p = (rows + 7) / 8 * 8;
  const int64_t cols_p = (cols + 7) / 8 * 8;
  const size_t needed =
      static_cast<size_t>(rows * cols + rows * cols_p + cols * rows_p +
                          3 * rows_p + 3 * cols_p + std::max(rows_p, cols_p) +
                          4 * rows_p + 4 * cols_p) +
      8;
  scratch.resize(needed);
  // Align the working arrays to 64 bytes.
  double* base = scratch.data();
  while (reinterpret_cast<uintptr_t>(base) % 64 != 0) ++base;
  double* kernel = base;                            // rows x cols_p
  double* kernel_t = kernel + rows * cols_p;        // cols x rows_p
  double* a = kernel_t + cols * rows_p;             // rows_p
  double* mu = a + rows_p;                          // rows_p
  double* u = mu + rows_p;                          // rows_p
  double* b = u + rows_p;                           // cols_p
  double* nu = b + cols_p;                          // cols_p
  double* v = nu + cols_p;                          // cols_p
  double* acc = v + cols_p;                         // max(rows_p, cols_p)
  double* log_mu = acc + std::max(rows_p, cols_p);  // rows
  double* log_nu = log_mu + rows_p;                 // cols
  double* z = log_nu + cols_p;                      // rows x cols couplings
  double zmax = alpha;
  bool finite = std::isfinite(alpha);
  for (int64_t i = 0; i < rows; ++i) {
    for (int64_t j = 0; j < cols; ++j) {
      const double value = (i < n && j < l)
                               ? static_cast<double>(scores[i * ld_scores + j])
                               : alpha;
      z[i * cols + j] = value;
      zmax = std::max(zmax, value);
      finite = finite && std::isfinite(value);
    }
  }
  // The span leaves out the kernel's exact zeros (kSinkhornUnderflowNats).
  const double underflow = zmax - kSinkhornUnderflowNats;
  double zmin = alpha;
  for (int64_t k = 0; k < rows * cols; ++k) {
    if (z[k] >= underflow) zmin = std::min(zmin, z[k]);
  }
  const double norm = -std::log(static_cast<double>(n + l));
  for (int64_t i = 0; i < rows; ++i) log_mu[i] = norm;
  for (int64_t j = 0; j < cols; ++j) log_nu[j] = norm;
  log_mu[n] = std::log(static_cast<double>(l)) + norm;
  log_nu[l] = std::log(static_cast<double>(n)) + norm;
  if (num_iters > 0 && finite && zmax - zmin <= kSinkhornScalingMaxSpan) {
    // Scaling form of the same iteration: a = exp(u + zmax), b = exp(v),
    // K = exp(z - zmax); u-update a_i = mu_i / (K b)_i, then v-update
    // b_j = nu_j / (K^T a)_j. K's other entries are >= e^-200, so no
    // underflow.
    SinkhornScalingKernel(
        isa, z, rows, cols, rows_p, cols_p, zmax, kernel, kernel_t);
    std::fill(mu, mu + rows_p, 0.0);
    std::fill(nu, nu + cols_p, 0.0);
    std::fill(a, a + rows_p, 0.0);
    std::fill(b, b + cols_p, 0.0);
    for (int64_t i = 0; i < rows; ++i) mu[i] = std::exp(log_mu[i]);
    for (int64_t j = 0; j < cols; ++j) nu[j] = std::exp(log_nu[j]);
    for (int64_t j = 0; j < cols; ++j) b[j] = 1.0;
    if (isa == KernelIsa::kAvx512) {
      SinkhornScalingAvx512(kernel,
                            kernel_t,
                            mu,
                            nu,
                            a,
                            b,
                            acc,
                            rows,
                            cols,
                            rows_p,
                            cols_p,
                            num_iters);
    } else {
      for (int it = 0; it < num_iters; ++it) {
        for (int64_t i = 0; i < rows; ++i) acc[i] = 0.0;
        for (int64_t j = 0; j < cols; ++j) {
          const double* kc = kernel_t + j * rows_p;
          const double bj = b[j];
          for (int64_t i = 0; i < rows; ++i) acc[i] += kc[i] * bj;
        }
        for (int64_t i = 0; i < rows; ++i) a[i] = mu[i] / acc[i];
        for (int64_t j = 0; j < cols; ++j) acc[j] = 0.0;
        for (int64_t i = 0; i < rows; ++i) {
          const double* kr = kernel + i * cols_p;
          const double ai = a[i];
          for (int64_t j = 0; j < cols; ++j) acc[j] += kr[j] * ai;
        }
        for (int64_t j = 0; j < cols; ++j) b[j] = nu[j] / acc[j];
      }
    }
    for (int64_t i = 0; i < rows; ++i) u[i] = std::log(a[i]) - zmax;
    for (int64_t j = 0; j < cols; ++j) v[j] = std::log(b[j]);
  } else {
    // Log-sum-exp updates (also for non-finite scores, which propagate).
    for (int64_t i = 0; i < rows; ++i) u[i] = 0.0;
    for (int64_t j = 0; j < cols; ++j) v[j] = 0.0;
    for (int it = 0; it < num_iters; ++it) {
      for (int64_t i = 0; i < rows; ++i) {
        const double* zr = z + i * cols;
        double m = -std::numeric_limits<double>::infinity();
        for (int64_t j = 0; j < cols; ++j) m = std::max(m, zr[j] + v[j]);
        double sum = 0.0;
        for (int64_t j = 0; j < cols; ++j) sum += std::exp(zr[j] + v[j] - m);
        u[i] = log_mu[i] - (m + std::log(sum));
      }
      for (int64_t j = 0; j < cols; ++j) {
        double m = -std::numeric_limits<double>::infinity();
        for (int64_t i = 0; i < rows; ++i)
          m = std::max(m, z[i * cols + j] + u[i]);
        double sum = 0.0;
        for (int64_t i = 0; i < rows; ++i)
          sum += std::exp(z[i * cols + j] + u[i] - m);
        v[j] = log_nu[j] - (m + std::log(sum));
      }
    }
  }
  for (int64_t i = 0; i < rows; ++i) {
    for (int64_t j = 0; j < cols; ++j) {
      out[i * cols + j] =
          static_cast<float>(z[i * cols + j] + u[i] + v[j] - norm);
    }
  }
}

void LogSoftmaxFrame(
    const float* scores, int64_t ld_scores, int64_t n, int64_t c, float* out) {
  for (int64_t i = 0; i < n; ++i) {
    const float* row = scores + i * ld_scores;
    double m = -std::numeric_limits<double>::infinity();
    for (int64_t j = 0; j < c; ++j)
      m = std::max(m, static_cast<double>(row[j]));
    double sum = 0.0;
    for (int64_t j = 0; j < c; ++j)
      sum += std::exp(static_cast<double>(row[j]) - m);
    const double lse = m + std::log(sum);
    for (int64_t j = 0; j < c; ++j) {
      out[i * c + j] = static_cast<float>(static_cast<double>(row[j]) - lse);
    }
  }
}

void MedianOffset(const float* points, int64_t n, float offset[3]) {
  float values[3][512];
  std::vector<float> heap[3];
  float* column[3] = {values[0], values[1], values[2]};
  if (n > 512) {
    for (int c = 0; c < 3; ++c) {
      heap[c].resize(static_cast<size_t>(n));
      column[c] = heap[c].data();
    }
  }
  int64_t count = 0;
  for (int64_t i = 0; i < n; ++i) {
    const float* p = points + 3 * i;
    if (p[0] == 0.0f && p[1] == 0.0f && p[2] == 0.0f) continue;
    for (int c = 0; c < 3; ++c) column[c][count] = p[c];
    ++count;
  }
  for (int c = 0; c < 3; ++c) {
    if (count == 0) {
      offset[c] = 0.0f;
      continue;
    }
    const int64_t mid = (count - 1) / 2;  // lower median (torch.median)
    std::nth_element(column[c], column[c] + mid, column[c] + count);
    offset[c] = column[c][mid];
  }
}

}  // namespace soma::internal
