#include "framework/model/fast_loss.h"

#include "framework/core/error.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>

namespace soma::internal {
namespace {

#define SOMA_FAST_LOSS_INLINE inline __attribute__((always_inline))

/// `x` rounded up to whole 8-double (64-byte) blocks.
int64_t Pad8(int64_t x) { return (x + 7) / 8 * 8; }

/// Carves 64-byte aligned blocks out of a grow-only double vector. Call
/// Reserve() with the total (from a counting pass) before Take().
class Arena {
 public:
  /// Counting pass: returns where the next block would start.
  static int64_t Size(int64_t count) { return Pad8(count); }

  Arena(std::vector<double>& data, int64_t total) {
    const size_t needed = static_cast<size_t>(total + 8);
    if (data.size() < needed) data.resize(needed);
    next_ = data.data();
    while (reinterpret_cast<uintptr_t>(next_) % 64 != 0) ++next_;
  }
  double* Take(int64_t count) {
    double* block = next_;
    next_ += Pad8(count);
    return block;
  }

 private:
  double* next_ = nullptr;
};

// ---------------------------------------------------------------------------
// Exp-domain (scaling) Sinkhorn, forward and backward.
//
// With K = exp(Z - zmax), a^t = exp(u^t + zmax), b^t = exp(v^t) the updates
// are a^t = mu / (K b^{t-1}), b^t = nu / (K^T a^t), and the softmaxes of the
// backward pass are
//   s^t_ij = K_ij a^t_i b^{t-1}_j / mu_i   (row softmax of the u-update),
//   c^t_ij = K_ij a^t_i b^t_j / nu_j       (column softmax of the v-update).
// Every padded lane (rows..rows_p, cols..cols_p) of K, K^T and the vectors
// is zero.

struct ScalingArgs {
  int64_t rows = 0;
  int64_t cols = 0;
  int64_t rows_p = 0;
  int64_t cols_p = 0;
  int iters = 0;
  const double* kernel = nullptr;    // rows x cols_p
  const double* kernel_t = nullptr;  // cols x rows_p
  const double* mu = nullptr;        // rows_p
  const double* nu = nullptr;        // cols_p
  double* a_hist = nullptr;          // iters x rows_p: a^t at (t-1)
  double* b_hist = nullptr;          // (iters+1) x cols_p: b^t at t
  double* acc = nullptr;             // max(rows_p, cols_p)
  // Backward only.
  const double* h = nullptr;  // rows x cols, dloss/dA'
  double* gu = nullptr;       // rows_p
  double* gv = nullptr;       // cols_p
  double* q_hist = nullptr;   // iters x cols_p: b^t gv^t / nu
  double* r_hist = nullptr;   // iters x rows_p: a^t gu^t / mu
  double* m_row = nullptr;    // cols_p
  double* gz = nullptr;       // rows x cols, dloss/dZ (output)
};

/// y[i] = sum_{k < len} m_t[k * ld + i] * x[k] for i < out_p (out_p % 8 ==
/// 0), i.e. y = M x with M stored transposed (`m_t` is `len x ld`). 32
/// outputs at a time (8 for the rest) are accumulated in a local block, in
/// order of k.
SOMA_FAST_LOSS_INLINE void MatVecT(const double* __restrict m_t,
                                   int64_t ld,
                                   int64_t len,
                                   const double* __restrict x,
                                   int64_t out_p,
                                   double* __restrict y) {
  // Four independent 8-wide accumulators per pass: one would serialise on
  // the FMA latency.
  int64_t i0 = 0;
  for (; i0 + 32 <= out_p; i0 += 32) {
    double acc[32] = {};
    const double* col = m_t + i0;
    for (int64_t k = 0; k < len; ++k) {
      const double xk = x[k];
      const double* row = col + k * ld;
      for (int e = 0; e < 32; ++e) acc[e] += row[e] * xk;
    }
    for (int e = 0; e < 32; ++e) y[i0 + e] = acc[e];
  }
  for (; i0 < out_p; i0 += 8) {
    double acc[8] = {};
    const double* col = m_t + i0;
    for (int64_t k = 0; k < len; ++k) {
      const double xk = x[k];
      for (int e = 0; e < 8; ++e) acc[e] += col[k * ld + e] * xk;
    }
    for (int e = 0; e < 8; ++e) y[i0 + e] = acc[e];
  }
}

/// m[j] = sum_{t < iters} a[t * ld_coef] * q[t * ld_vec + j] +
///        r[t * ld_coef] * b[t * ld_vec + j]   for j < ld_vec (% 8 == 0).
SOMA_FAST_LOSS_INLINE void OuterSumRow(const double* __restrict a,
                                       const double* __restrict r,
                                       int64_t ld_coef,
                                       const double* __restrict q,
                                       const double* __restrict b,
                                       int64_t ld_vec,
                                       int iters,
                                       double* __restrict m) {
  // The whole row accumulates at once (ld_vec / 8 independent chains).
  for (int64_t j = 0; j < ld_vec; ++j) m[j] = 0.0;
  for (int t = 0; t < iters; ++t) {
    const double at = a[t * ld_coef];
    const double rt = r[t * ld_coef];
    const double* qt = q + t * ld_vec;
    const double* bt = b + t * ld_vec;
    for (int64_t j = 0; j < ld_vec; ++j) m[j] += at * qt[j] + rt * bt[j];
  }
}

SOMA_FAST_LOSS_INLINE void ScalingForwardBody(const ScalingArgs& p) {
  double* b0 = p.b_hist;
  for (int64_t j = 0; j < p.cols_p; ++j) b0[j] = j < p.cols ? 1.0 : 0.0;
  for (int t = 1; t <= p.iters; ++t) {
    double* a = p.a_hist + (t - 1) * p.rows_p;
    const double* b_prev = p.b_hist + (t - 1) * p.cols_p;
    double* b = p.b_hist + t * p.cols_p;
    MatVecT(p.kernel_t, p.rows_p, p.cols, b_prev, p.rows_p, p.acc);  // K b
    for (int64_t i = 0; i < p.rows; ++i) a[i] = p.mu[i] / p.acc[i];
    for (int64_t i = p.rows; i < p.rows_p; ++i) a[i] = 0.0;
    MatVecT(p.kernel, p.cols_p, p.rows, a, p.cols_p, p.acc);  // K^T a
    for (int64_t j = 0; j < p.cols; ++j) b[j] = p.nu[j] / p.acc[j];
    for (int64_t j = p.cols; j < p.cols_p; ++j) b[j] = 0.0;
  }
}

SOMA_FAST_LOSS_INLINE void ScalingBackwardBody(const ScalingArgs& p) {
  const int64_t rows = p.rows;
  const int64_t cols = p.cols;
  // dloss/du^T and dloss/dv^T from A' = Z + u^T + v^T - norm.
  std::fill(p.gu, p.gu + p.rows_p, 0.0);
  std::fill(p.gv, p.gv + p.cols_p, 0.0);
  for (int64_t i = 0; i < rows; ++i) {
    const double* hr = p.h + i * cols;
    double sum = 0.0;
    for (int64_t j = 0; j < cols; ++j) {
      sum += hr[j];
      p.gv[j] += hr[j];
    }
    p.gu[i] = sum;
  }
  for (int t = p.iters; t >= 1; --t) {
    const double* a = p.a_hist + (t - 1) * p.rows_p;
    const double* b = p.b_hist + t * p.cols_p;
    const double* b_prev = p.b_hist + (t - 1) * p.cols_p;
    double* q = p.q_hist + (t - 1) * p.cols_p;
    double* r = p.r_hist + (t - 1) * p.rows_p;
    // v^t = log nu - LSE_i(Z + u^t): gu_i -= sum_j c_ij gv_j.
    for (int64_t j = 0; j < cols; ++j) q[j] = b[j] * p.gv[j] / p.nu[j];
    for (int64_t j = cols; j < p.cols_p; ++j) q[j] = 0.0;
    MatVecT(p.kernel_t, p.rows_p, cols, q, p.rows_p, p.acc);  // K q
    for (int64_t i = 0; i < rows; ++i) p.gu[i] -= a[i] * p.acc[i];
    // u^t = log mu - LSE_j(Z + v^{t-1}): gv^{t-1}_j = -sum_i s_ij gu_i.
    for (int64_t i = 0; i < rows; ++i) r[i] = a[i] * p.gu[i] / p.mu[i];
    for (int64_t i = rows; i < p.rows_p; ++i) r[i] = 0.0;
    MatVecT(p.kernel, p.cols_p, rows, r, p.cols_p, p.acc);  // K^T r
    for (int64_t j = 0; j < cols; ++j) p.gv[j] = -b_prev[j] * p.acc[j];
    // u^{t-1} only feeds v^{t-1}, handled at step t-1.
    for (int64_t i = 0; i < rows; ++i) p.gu[i] = 0.0;
  }
  // dZ = dA' - K o sum_t (a^t q^t^T + r^t b^{t-1}^T).
  for (int64_t i = 0; i < rows; ++i) {
    OuterSumRow(p.a_hist + i,
                p.r_hist + i,
                p.rows_p,
                p.q_hist,
                p.b_hist,
                p.cols_p,
                p.iters,
                p.m_row);
    const double* kr = p.kernel + i * p.cols_p;
    const double* hr = p.h + i * cols;
    double* gzr = p.gz + i * cols;
    for (int64_t j = 0; j < cols; ++j) gzr[j] = hr[j] - kr[j] * p.m_row[j];
  }
}

void ScalingForwardPortable(const ScalingArgs& p) { ScalingForwardBody(p); }
void ScalingBackwardPortable(const ScalingArgs& p) { ScalingBackwardBody(p); }

// The same code compiled for AVX-512 (only called after a CPUID check).
__attribute__((
    target("avx512f,avx512dq,avx512bw,avx512vl,fma,avx2,"
           "prefer-vector-width=512"))) void
ScalingForwardAvx512(const ScalingArgs& p) {
  ScalingForwardBody(p);
}
__attribute__((
    target("avx512f,avx512dq,avx512bw,avx512vl,fma,avx2,"
           "prefer-vector-width=512"))) void
ScalingBackwardAvx512(const ScalingArgs& p) {
  ScalingBackwardBody(p);
}

// ---------------------------------------------------------------------------
// Log-domain Sinkhorn (couplings spanning > kSinkhornScalingMaxSpan nats or
// non-finite), forward and backward, following LogOptimalTransport literally.

/// Exponents below this are taken as exp = 0 in the log-domain path (e^-600
/// ~ 1e-261; keeps the products that follow out of the slow subnormal range,
/// and changes sums of terms >= 1 by nothing).
constexpr double kMinExponent = -600.0;

/// x[k] = exp(x[k]) for k < count, 0 where x[k] < kMinExponent.
void ExpFlushed(KernelIsa isa, double* x, int64_t count) {
  for (int64_t k = 0; k < count; ++k) {
    if (x[k] < kMinExponent) x[k] = -std::numeric_limits<double>::infinity();
  }
  if (isa == KernelIsa::kAvx512) {
    // The AVX-512 exp clamps -inf to e^-708: zero those lanes afterwards.
    ExpInPlace(isa, x, count);
    for (int64_t k = 0; k < count; ++k) {
      if (x[k] < 1e-300) x[k] = 0.0;
    }
  } else {
    ExpInPlace(isa, x, count);
  }
}

/// log(sum_k exp(x[k])) of `count` values; `x` is overwritten. Like
/// torch.logsumexp, an infinite maximum is not subtracted.
double LogSumExpInPlace(KernelIsa isa, double* x, int64_t count) {
  double m = -std::numeric_limits<double>::infinity();
  for (int64_t k = 0; k < count; ++k) m = std::max(m, x[k]);
  if (std::isinf(m)) m = 0.0;
  for (int64_t k = 0; k < count; ++k) x[k] -= m;
  ExpFlushed(isa, x, count);
  double sum = 0.0;
  for (int64_t k = 0; k < count; ++k) sum += x[k];
  return m + std::log(sum);
}

struct LogDomainArgs {
  int64_t rows = 0;
  int64_t cols = 0;
  int iters = 0;
  const double* z = nullptr;    // rows x cols couplings
  const double* z_t = nullptr;  // cols x rows (transposed)
  const double* log_mu = nullptr;
  const double* log_nu = nullptr;
  double* u_hist = nullptr;  // iters x rows: u^t at (t-1)
  double* v_hist = nullptr;  // (iters+1) x cols: v^t at t
  double* tmp = nullptr;     // max(rows, cols)
  // Backward only.
  const double* h = nullptr;  // rows x cols, dloss/dA'
  double* gu = nullptr;       // rows
  double* gv = nullptr;       // cols
  double* gv_next = nullptr;  // cols
  double* gz = nullptr;       // rows x cols (output)
};

void LogDomainForward(KernelIsa isa, const LogDomainArgs& p) {
  std::fill(p.v_hist, p.v_hist + p.cols, 0.0);
  for (int t = 1; t <= p.iters; ++t) {
    double* u = p.u_hist + (t - 1) * p.rows;
    const double* v_prev = p.v_hist + (t - 1) * p.cols;
    double* v = p.v_hist + t * p.cols;
    for (int64_t i = 0; i < p.rows; ++i) {
      const double* zr = p.z + i * p.cols;
      for (int64_t j = 0; j < p.cols; ++j) p.tmp[j] = zr[j] + v_prev[j];
      u[i] = p.log_mu[i] - LogSumExpInPlace(isa, p.tmp, p.cols);
    }
    for (int64_t j = 0; j < p.cols; ++j) {
      const double* zc = p.z_t + j * p.rows;
      for (int64_t i = 0; i < p.rows; ++i) p.tmp[i] = zc[i] + u[i];
      v[j] = p.log_nu[j] - LogSumExpInPlace(isa, p.tmp, p.rows);
    }
  }
}

void LogDomainBackward(KernelIsa isa, const LogDomainArgs& p) {
  const int64_t rows = p.rows;
  const int64_t cols = p.cols;
  std::fill(p.gv, p.gv + cols, 0.0);
  for (int64_t i = 0; i < rows; ++i) {
    const double* hr = p.h + i * cols;
    double* gzr = p.gz + i * cols;
    double sum = 0.0;
    for (int64_t j = 0; j < cols; ++j) {
      gzr[j] = hr[j];
      sum += hr[j];
      p.gv[j] += hr[j];
    }
    p.gu[i] = sum;
  }
  for (int t = p.iters; t >= 1; --t) {
    const double* u = p.u_hist + (t - 1) * rows;
    const double* v = p.v_hist + t * cols;
    const double* v_prev = p.v_hist + (t - 1) * cols;
    // v-update: c_ij = exp(Z_ij + u_i + v_j - log_nu_j).
    for (int64_t i = 0; i < rows; ++i) {
      const double* zr = p.z + i * cols;
      double* gzr = p.gz + i * cols;
      for (int64_t j = 0; j < cols; ++j)
        p.tmp[j] = zr[j] + u[i] + v[j] - p.log_nu[j];
      ExpFlushed(isa, p.tmp, cols);
      double sum = 0.0;
      for (int64_t j = 0; j < cols; ++j) {
        const double d = p.tmp[j] * p.gv[j];
        gzr[j] -= d;
        sum += d;
      }
      p.gu[i] -= sum;
    }
    // u-update: s_ij = exp(Z_ij + v^{t-1}_j + u_i - log_mu_i).
    std::fill(p.gv_next, p.gv_next + cols, 0.0);
    for (int64_t i = 0; i < rows; ++i) {
      const double* zr = p.z + i * cols;
      double* gzr = p.gz + i * cols;
      const double shift = u[i] - p.log_mu[i];
      for (int64_t j = 0; j < cols; ++j) p.tmp[j] = zr[j] + v_prev[j] + shift;
      ExpFlushed(isa, p.tmp, cols);
      const double gui = p.gu[i];
      for (int64_t j = 0; j < cols; ++j) {
        const double d = p.tmp[j] * gui;
        gzr[j] -= d;
        p.gv_next[j] -= d;
      }
      p.gu[i] = 0.0;  // u^{t-1} only feeds v^{t-1} (step t-1)
    }
    std::copy(p.gv_next, p.gv_next + cols, p.gv);
  }
}

}  // namespace

void BuildFrameTargets(const int64_t* label_ids,
                       int64_t n,
                       int64_t l,
                       bool with_dustbin_row,
                       float* g,
                       float* w) {
  SOMA_CHECK(l > 0) << "num_labels = " << l;
  SOMA_CHECK(n >= 0) << "n = " << n;
  const int64_t cols = l + 1;
  const int64_t rows = with_dustbin_row ? n + 1 : n;
  std::fill(g, g + rows * cols, 0.0f);
  int64_t n_null = 0;
  for (int64_t i = 0; i < n; ++i) {
    const int64_t id = label_ids[i];
    SOMA_CHECK(id >= 0 && id <= l)
        << "label ids must lie in [0, " << l << "], got " << id;
    if (id == l) ++n_null;
    g[i * cols + id] = 1.0f;
  }
  // Each real label on at most one point; the dustbin row takes the rest.
  int64_t not_available = 0;
  for (int64_t j = 0; j < l; ++j) {
    int64_t count = 0;
    for (int64_t i = 0; i < n; ++i) count += label_ids[i] == j ? 1 : 0;
    SOMA_CHECK(count <= 1)
        << "a real label is carried by two points of one frame (label " << j
        << ")";
    if (count == 0) {
      ++not_available;
      if (with_dustbin_row) g[n * cols + j] = 1.0f;
    }
  }
  if (with_dustbin_row) {
    g[n * cols + l] =
        static_cast<float>(l + 1) - static_cast<float>(not_available);
  }
  const float null_weight =
      n_null > 0 ? 1.0f / static_cast<float>(n_null) : 1.0f;
  for (int64_t i = 0; i < rows; ++i) {
    const float weight = (i == n || label_ids[i] == l) ? null_weight : 1.0f;
    std::fill(w + i * cols, w + (i + 1) * cols, weight);
  }
}

double SinkhornLossFrame(const float* scores,
                         int64_t ld_scores,
                         int64_t n,
                         int64_t l,
                         double alpha,
                         int num_iters,
                         const float* g,
                         const float* w,
                         float* log_assignment,
                         float* d_scores,
                         int64_t ld_d,
                         double grad_scale,
                         double* d_alpha,
                         FrameLossScratch& scratch,
                         KernelIsa isa) {
  SOMA_CHECK(n >= 1 && l >= 1)
      << "SinkhornLossFrame(n = " << n << ", l = " << l << ")";
  SOMA_CHECK(num_iters >= 0) << "num_iters = " << num_iters;
  isa = ResolveIsa(isa);
  const int64_t rows = n + 1;
  const int64_t cols = l + 1;
  const int64_t rows_p = Pad8(rows);
  const int64_t cols_p = Pad8(cols);
  const int64_t iters = num_iters;
  const bool backward = d_scores != nullptr;

  // Layout (the exp-domain and log-domain paths share the history blocks).
  const int64_t total =
      3 * Arena::Size(rows * cols) +           // z, h, gz
      Arena::Size(rows * cols_p) +             // kernel
      Arena::Size(cols * rows_p) +             // kernel_t / z_t
      3 * Arena::Size(rows_p) +                // mu, log_mu, gu
      5 * Arena::Size(cols_p) +                // nu, log_nu, gv, gv_next, m_row
      Arena::Size(std::max(rows_p, cols_p)) +  // acc / tmp
      2 * Arena::Size(iters * rows_p) +        // a/u history, r history
      Arena::Size((iters + 1) * cols_p) +      // b/v history
      Arena::Size(iters * cols_p);             // q history
  Arena arena(scratch.data, total);
  double* z = arena.Take(rows * cols);
  double* h = arena.Take(rows * cols);
  double* gz = arena.Take(rows * cols);
  double* kernel = arena.Take(rows * cols_p);
  double* kernel_t = arena.Take(cols * rows_p);
  double* mu = arena.Take(rows_p);
  double* log_mu = arena.Take(rows_p);
  double* gu = arena.Take(rows_p);
  double* nu = arena.Take(cols_p);
  double* log_nu = arena.Take(cols_p);
  double* gv = arena.Take(cols_p);
  double* gv_next = arena.Take(cols_p);
  double* m_row = arena.Take(cols_p);
  double* acc = arena.Take(std::max(rows_p, cols_p));
  double* row_hist = arena.Take(iters * rows_p);
  double* r_hist = arena.Take(iters * rows_p);
  double* col_hist = arena.Take((iters + 1) * cols_p);
  double* q_hist = arena.Take(iters * cols_p);

  // Couplings Z and their span.
  double zmax = alpha;
  double zmin = alpha;
  bool finite = std::isfinite(alpha);
  for (int64_t i = 0; i < rows; ++i) {
    double* zr = z + i * cols;
    if (i < n) {
      const float* sr = scores + i * ld_scores;
      for (int64_t j = 0; j < l; ++j) zr[j] = static_cast<double>(sr[j]);
      zr[l] = alpha;
    } else {
      for (int64_t j = 0; j < cols; ++j) zr[j] = alpha;
    }
    for (int64_t j = 0; j < cols; ++j) {
      zmax = std::max(zmax, zr[j]);
      finite = finite && std::isfinite(zr[j]);
    }
  }
  // The span leaves out the kernel's exact zeros (kSinkhornUnderflowNats).
  const double underflow = zmax - kSinkhornUnderflowNats;
  for (int64_t k = 0; k < rows * cols; ++k) {
    if (z[k] >= underflow) zmin = std::min(zmin, z[k]);
  }
  const double norm = -std::log(static_cast<double>(n + l));
  for (int64_t i = 0; i < rows_p; ++i) log_mu[i] = norm;
  for (int64_t j = 0; j < cols_p; ++j) log_nu[j] = norm;
  log_mu[n] = std::log(static_cast<double>(l)) + norm;
  log_nu[l] = std::log(static_cast<double>(n)) + norm;

  // dloss/dA' = -G' W / sum G'.
  double g_sum = 0.0;
  for (int64_t k = 0; k < rows * cols; ++k) g_sum += static_cast<double>(g[k]);
  const double neg_inv_g_sum = -1.0 / g_sum;
  for (int64_t k = 0; k < rows * cols; ++k) {
    h[k] =
        static_cast<double>(g[k]) * static_cast<double>(w[k]) * neg_inv_g_sum;
  }

  // Forward; u_last / v_last are the final potentials u^T, v^T (none if
  // T = 0). The scaling path stores them in `acc` and `gv_next`, which its
  // backward pass does not use.
  const bool scaling =
      iters > 0 && finite && zmax - zmin <= kSinkhornScalingMaxSpan;
  const double* u_last = nullptr;
  const double* v_last = nullptr;
  ScalingArgs sp;
  LogDomainArgs lp;
  if (scaling) {
    SinkhornScalingKernel(
        isa, z, rows, cols, rows_p, cols_p, zmax, kernel, kernel_t);
    std::fill(mu, mu + rows_p, 0.0);
    std::fill(nu, nu + cols_p, 0.0);
    for (int64_t i = 0; i < rows; ++i) mu[i] = std::exp(log_mu[i]);
    for (int64_t j = 0; j < cols; ++j) nu[j] = std::exp(log_nu[j]);
    sp.rows = rows;
    sp.cols = cols;
    sp.rows_p = rows_p;
    sp.cols_p = cols_p;
    sp.iters = num_iters;
    sp.kernel = kernel;
    sp.kernel_t = kernel_t;
    sp.mu = mu;
    sp.nu = nu;
    sp.a_hist = row_hist;
    sp.b_hist = col_hist;
    sp.acc = acc;
    sp.h = h;
    sp.gu = gu;
    sp.gv = gv;
    sp.q_hist = q_hist;
    sp.r_hist = r_hist;
    sp.m_row = m_row;
    sp.gz = gz;
    if (isa == KernelIsa::kAvx512) {
      ScalingForwardAvx512(sp);
    } else {
      ScalingForwardPortable(sp);
    }
    // u = log a - zmax, v = log b.
    const double* a = row_hist + (iters - 1) * rows_p;
    const double* b = col_hist + iters * cols_p;
    double* u_final = acc;
    double* v_final = gv_next;
    for (int64_t i = 0; i < rows; ++i) u_final[i] = std::log(a[i]) - zmax;
    for (int64_t j = 0; j < cols; ++j) v_final[j] = std::log(b[j]);
    u_last = u_final;
    v_last = v_final;
  } else {
    for (int64_t i = 0; i < rows; ++i) {
      for (int64_t j = 0; j < cols; ++j)
        kernel_t[j * rows + i] = z[i * cols + j];
    }
    // The AVX-512 exp clamps its argument (NaN would vanish): use std::exp
    // for non-finite couplings so that they propagate as in torch.
    const KernelIsa exp_isa = finite ? isa : KernelIsa::kPortable;
    lp.rows = rows;
    lp.cols = cols;
    lp.iters = num_iters;
    lp.z = z;
    lp.z_t = kernel_t;
    lp.log_mu = log_mu;
    lp.log_nu = log_nu;
    lp.u_hist = row_hist;
    lp.v_hist = col_hist;
    lp.tmp = acc;
    lp.h = h;
    lp.gu = gu;
    lp.gv = gv;
    lp.gv_next = gv_next;
    lp.gz = gz;
    LogDomainForward(exp_isa, lp);
    if (iters > 0) {
      u_last = row_hist + (iters - 1) * rows;
      v_last = col_hist + iters * cols;
    }
  }

  // A' = Z + u + v - norm and the loss.
  double loss = 0.0;
  for (int64_t i = 0; i < rows; ++i) {
    const double ui = u_last != nullptr ? u_last[i] : 0.0;
    const double* zr = z + i * cols;
    const double* hr = h + i * cols;
    float* out =
        log_assignment != nullptr ? log_assignment + i * cols : nullptr;
    for (int64_t j = 0; j < cols; ++j) {
      const double vj = v_last != nullptr ? v_last[j] : 0.0;
      const double value = zr[j] + ui + vj - norm;
      loss += hr[j] * value;
      if (out != nullptr) out[j] = static_cast<float>(value);
    }
  }
  if (!backward) return loss;

  // Backward into gz = dloss/dZ.
  if (iters == 0) {
    std::copy(h, h + rows * cols, gz);
  } else if (scaling) {
    if (isa == KernelIsa::kAvx512) {
      ScalingBackwardAvx512(sp);
    } else {
      ScalingBackwardPortable(sp);
    }
  } else {
    LogDomainBackward(finite ? isa : KernelIsa::kPortable, lp);
  }
  double g_alpha = 0.0;
  for (int64_t i = 0; i < n; ++i) {
    const double* gzr = gz + i * cols;
    float* dr = d_scores + i * ld_d;
    for (int64_t j = 0; j < l; ++j)
      dr[j] = static_cast<float>(grad_scale * gzr[j]);
    g_alpha += gzr[l];
  }
  for (int64_t j = 0; j < cols; ++j) g_alpha += gz[n * cols + j];
  if (d_alpha != nullptr) *d_alpha += grad_scale * g_alpha;
  return loss;
}

double LogSoftmaxLossFrame(const float* scores,
                           int64_t ld_scores,
                           int64_t n,
                           int64_t l,
                           bool quirk_probability_loss,
                           const float* g,
                           const float* w,
                           float* log_assignment,
                           float* d_scores,
                           int64_t ld_d,
                           double grad_scale,
                           FrameLossScratch& scratch,
                           KernelIsa isa) {
  SOMA_CHECK(n >= 1 && l >= 1)
      << "LogSoftmaxLossFrame(n = " << n << ", l = " << l << ")";
  isa = ResolveIsa(isa);
  const int64_t cols = l + 1;
  Arena arena(scratch.data, 2 * Arena::Size(cols));
  double* e = arena.Take(cols);
  double* dh = arena.Take(cols);
  double g_sum = 0.0;
  for (int64_t k = 0; k < n * cols; ++k) g_sum += static_cast<double>(g[k]);
  double loss = 0.0;
  for (int64_t i = 0; i < n; ++i) {
    const float* sr = scores + i * ld_scores;
    double m = -std::numeric_limits<double>::infinity();
    bool finite = true;
    for (int64_t j = 0; j < cols; ++j) {
      e[j] = static_cast<double>(sr[j]);
      m = std::max(m, e[j]);
      finite = finite && std::isfinite(e[j]);
    }
    for (int64_t j = 0; j < cols; ++j) e[j] -= m;  // x - max
    float* out =
        log_assignment != nullptr ? log_assignment + i * cols : nullptr;
    // Keep x - max for A' before exponentiating.
    for (int64_t j = 0; j < cols; ++j) dh[j] = e[j];
    ExpInPlace(finite ? isa : KernelIsa::kPortable, e, cols);
    double sum = 0.0;
    for (int64_t j = 0; j < cols; ++j) sum += e[j];
    const double log_sum = std::log(sum);
    const double inv_sum = 1.0 / sum;
    const float* gr = g + i * cols;
    const float* wr = w + i * cols;
    // dh = dloss/dA' (identity) or dloss/dP (quirk), then dloss/dA'.
    double row_grad = 0.0;
    for (int64_t j = 0; j < cols; ++j) {
      const double log_p = dh[j] - log_sum;
      const double p = e[j] * inv_sum;
      if (out != nullptr) out[j] = static_cast<float>(log_p);
      const double hj =
          -(static_cast<double>(gr[j]) * static_cast<double>(wr[j])) / g_sum;
      const double ga = quirk_probability_loss ? hj * p : hj;
      loss += quirk_probability_loss ? hj * p : hj * log_p;
      dh[j] = ga;
      e[j] = p;
      row_grad += ga;
    }
    if (d_scores != nullptr) {
      float* dr = d_scores + i * ld_d;
      for (int64_t j = 0; j < cols; ++j) {
        dr[j] = static_cast<float>(grad_scale * (dh[j] - e[j] * row_grad));
      }
    }
  }
  return loss;
}

}  // namespace soma::internal
