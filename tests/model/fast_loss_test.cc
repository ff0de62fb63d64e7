// The torch-free per-frame loss kernels (fast_loss.h) against the torch
// reference: BuildAugmentedTargets, LogOptimalTransport / log_softmax +
// ComputeLabelingLoss and their autograd gradients (float64), on random
// frames that exercise both the exp-domain and the log-domain Sinkhorn path;
// plus finite differences, strides, gradient scaling and scratch reuse.
#include "framework/model/fast_loss.h"

#include "framework/core/error.h"
#include "framework/model/loss.h"
#include "framework/model/normalization.h"

#include <gtest/gtest.h>
#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <iostream>
#include <limits>
#include <string>
#include <utility>
#include <vector>

namespace soma {
namespace {

using internal::BuildFrameTargets;
using internal::FrameLossScratch;
using internal::KernelIsa;
using internal::LogSoftmaxLossFrame;
using internal::SinkhornLossFrame;

constexpr double kValueTol = 1e-5;  // loss and A', relative
constexpr double kGradTol = 1e-4;   // gradients, relative (norm-wise)
// Elementwise gradient check: |a - b| <= kGradTol * (|b| + floor), floor =
// kGradFloor * max|b|.
constexpr double kGradFloor = 1e-3;

/// Random label ids of one frame: `num_real` distinct real labels on random
/// points, the other points null (l).
std::vector<int64_t> RandomLabelIds(int64_t n, int64_t l, int64_t num_real) {
  std::vector<int64_t> ids(static_cast<size_t>(n), l);
  const torch::Tensor labels = torch::randperm(l, torch::kLong);
  const torch::Tensor points = torch::randperm(n, torch::kLong);
  for (int64_t k = 0; k < num_real; ++k) {
    ids[points[k].item<int64_t>()] = labels[k].item<int64_t>();
  }
  return ids;
}

/// A random number of real labels in [0, min(n, l)].
int64_t RandomNumReal(int64_t n, int64_t l) {
  const int64_t most = std::min(n, l);
  return torch::randint(0, most + 1, {1}, torch::kLong).item<int64_t>();
}

torch::Tensor IdsTensor(const std::vector<int64_t>& ids) {
  return torch::tensor(ids, torch::kLong).view({1, -1});
}

/// Reference values of one frame from torch (float64, autograd).
struct TorchReference {
  double loss = 0.0;
  torch::Tensor log_assignment;  // rows x (l+1), double
  torch::Tensor d_scores;        // like the scores, double
  double d_alpha = 0.0;
};

TorchReference TorchSinkhorn(const torch::Tensor& scores,  // n x l float
                             float alpha,
                             int num_iters,
                             const std::vector<int64_t>& ids) {
  const int64_t l = scores.size(1);
  torch::Tensor s =
      scores.to(torch::kDouble).unsqueeze(0).clone().requires_grad_(true);
  torch::Tensor bin = torch::tensor(static_cast<double>(alpha), torch::kDouble)
                          .requires_grad_(true);
  const torch::Tensor a = LogOptimalTransport(s, bin, num_iters);
  const AugmentedTargets targets = BuildAugmentedTargets(IdsTensor(ids), l);
  const torch::Tensor loss = ComputeLabelingLoss(a, targets);
  loss.backward();
  TorchReference ref;
  ref.loss = loss.item<double>();
  ref.log_assignment = a.detach()[0];
  ref.d_scores = s.grad()[0];
  ref.d_alpha = bin.grad().item<double>();
  return ref;
}

TorchReference TorchLogSoftmax(const torch::Tensor& scores,  // n x (l+1)
                               bool quirk,
                               const std::vector<int64_t>& ids) {
  const int64_t l = scores.size(1) - 1;
  torch::Tensor s =
      scores.to(torch::kDouble).unsqueeze(0).clone().requires_grad_(true);
  const torch::Tensor a = torch::log_softmax(s, -1);
  const AugmentedTargets targets = BuildAugmentedTargets(IdsTensor(ids), l);
  LabelingLossOptions options;
  options.quirk_probability_loss = quirk;
  const torch::Tensor loss = ComputeLabelingLoss(a, targets, options);
  loss.backward();
  TorchReference ref;
  ref.loss = loss.item<double>();
  ref.log_assignment = a.detach()[0];
  ref.d_scores = s.grad()[0];
  return ref;
}

/// `rows x cols` floats with row stride `ld`; the padding holds NaN so that
/// reads past a row show up.
std::vector<float> Strided(const torch::Tensor& m, int64_t ld) {
  const int64_t rows = m.size(0);
  const int64_t cols = m.size(1);
  std::vector<float> out(static_cast<size_t>(rows * ld),
                         std::numeric_limits<float>::quiet_NaN());
  const torch::Tensor c = m.to(torch::kFloat).contiguous();
  const float* src = c.data_ptr<float>();
  for (int64_t i = 0; i < rows; ++i) {
    std::copy(src + i * cols, src + (i + 1) * cols, out.data() + i * ld);
  }
  return out;
}

/// The `rows x cols` block of a strided float buffer as a double tensor.
torch::Tensor FromStrided(const std::vector<float>& data,
                          int64_t rows,
                          int64_t cols,
                          int64_t ld) {
  torch::Tensor out = torch::empty({rows, cols}, torch::kDouble);
  for (int64_t i = 0; i < rows; ++i) {
    for (int64_t j = 0; j < cols; ++j) {
      out[i][j] = static_cast<double>(data[static_cast<size_t>(i * ld + j)]);
    }
  }
  return out;
}

/// Worst errors seen over a sweep (printed for the record).
struct MaxErrors {
  double loss = 0.0;
  double log_assignment = 0.0;
  double d_scores = 0.0;  // norm-wise
  double d_alpha = 0.0;
  void Print(const char* name) const {
    std::cout << "[" << name << "] max relative errors: loss " << loss
              << ", A' " << log_assignment << ", dS (norm-wise) " << d_scores
              << ", dalpha " << d_alpha << "\n";
  }
};

double RelativeError(double a, double b, double scale) {
  return std::abs(a - b) / std::max(std::abs(b), scale);
}

/// max|a - b| / max|b| (norm-wise); also EXPECTs the elementwise bound.
double CheckGradient(const torch::Tensor& actual,
                     const torch::Tensor& expected,
                     const std::string& context) {
  const double max_ref = expected.abs().max().item<double>();
  const torch::Tensor diff = (actual - expected).abs();
  const double norm_rel = diff.max().item<double>() / std::max(max_ref, 1e-300);
  EXPECT_LE(norm_rel, kGradTol) << context;
  const torch::Tensor bound =
      kGradTol * (expected.abs() + kGradFloor * max_ref) + 1e-300;
  EXPECT_TRUE(diff.le(bound).all().item<bool>())
      << context << ": worst elementwise ratio "
      << (diff / bound).max().item<double>();
  return norm_rel;
}

// ---------------------------------------------------------------------------
// Targets.

void ExpectTargetsMatch(const std::vector<int64_t>& ids, int64_t l) {
  const int64_t n = static_cast<int64_t>(ids.size());
  const AugmentedTargets ref = BuildAugmentedTargets(IdsTensor(ids), l);
  std::vector<float> g(static_cast<size_t>((n + 1) * (l + 1)), -7.0f);
  std::vector<float> w(g.size(), -7.0f);
  BuildFrameTargets(
      ids.data(), n, l, /*with_dustbin_row=*/true, g.data(), w.data());
  const torch::Tensor gt =
      torch::from_blob(g.data(), {1, n + 1, l + 1}, torch::kFloat);
  const torch::Tensor wt =
      torch::from_blob(w.data(), {1, n + 1, l + 1}, torch::kFloat);
  EXPECT_TRUE(torch::equal(gt, ref.assignment)) << "n=" << n << " l=" << l;
  EXPECT_TRUE(torch::equal(wt, ref.weights)) << "n=" << n << " l=" << l;
  // Without the dustbin row: exactly the point rows, nothing written past.
  std::vector<float> gp(g.size(), -7.0f);
  std::vector<float> wp(g.size(), -7.0f);
  BuildFrameTargets(
      ids.data(), n, l, /*with_dustbin_row=*/false, gp.data(), wp.data());
  const size_t point_entries = static_cast<size_t>(n * (l + 1));
  for (size_t k = 0; k < g.size(); ++k) {
    if (k < point_entries) {
      ASSERT_EQ(gp[k], g[k]) << k;
      ASSERT_EQ(wp[k], w[k]) << k;
    } else {
      ASSERT_EQ(gp[k], -7.0f) << k;
      ASSERT_EQ(wp[k], -7.0f) << k;
    }
  }
}

TEST(FastLoss, BuildFrameTargetsMatchesTorch) {
  torch::manual_seed(11);
  const std::vector<std::pair<int64_t, int64_t>> shapes = {
      {0, 4}, {1, 1}, {3, 3}, {5, 3}, {5, 41}, {44, 41}, {70, 41}, {100, 53}};
  for (const auto& [n, l] : shapes) {
    for (int rep = 0; rep < 4; ++rep) {
      ExpectTargetsMatch(RandomLabelIds(n, l, RandomNumReal(n, l)), l);
    }
    // Every point real (n_null == 0, possible when n <= l) and every point
    // null (ghosts / zero points only, every label missing).
    if (n <= l) ExpectTargetsMatch(RandomLabelIds(n, l, n), l);
    ExpectTargetsMatch(RandomLabelIds(n, l, 0), l);
    // All labels present (no missing label: dustbin row 0 except corner).
    if (n >= l) ExpectTargetsMatch(RandomLabelIds(n, l, l), l);
  }
}

TEST(FastLoss, BuildFrameTargetsRejectsBadIds) {
  std::vector<float> g(6 * 5);
  std::vector<float> w(6 * 5);
  const std::vector<int64_t> duplicate = {2, 4, 2, 4, 1};
  EXPECT_THROW(
      BuildFrameTargets(duplicate.data(), 5, 4, true, g.data(), w.data()),
      InternalError);
  const std::vector<int64_t> too_large = {2, 5, 0, 4, 1};
  EXPECT_THROW(
      BuildFrameTargets(too_large.data(), 5, 4, true, g.data(), w.data()),
      InternalError);
  const std::vector<int64_t> negative = {2, -1, 0, 4, 1};
  EXPECT_THROW(
      BuildFrameTargets(negative.data(), 5, 4, false, g.data(), w.data()),
      InternalError);
  const std::vector<int64_t> fine = {2, 4, 0, 4, 1};
  EXPECT_NO_THROW(
      BuildFrameTargets(fine.data(), 5, 4, true, g.data(), w.data()));
}

// ---------------------------------------------------------------------------
// Sinkhorn.

TEST(FastLoss, SinkhornMatchesTorchAutograd) {
  torch::manual_seed(3);
  MaxErrors worst_exp;
  MaxErrors worst_log;
  int frames_exp = 0;
  int frames_log = 0;
  FrameLossScratch scratch;  // shared across sizes on purpose
  for (const KernelIsa isa : {KernelIsa::kPortable, KernelIsa::kAuto}) {
    for (const int64_t n : {5, 44, 70}) {
      for (const int64_t l : {3, 41}) {
        for (const int iters : {0, 1, 35}) {
          // 1 and 20: exp-domain (span < 200 nats); 300: log-domain.
          for (const double scale : {1.0, 20.0, 300.0}) {
            const torch::Tensor scores =
                (torch::randn({n, l}) * scale).to(torch::kFloat);
            const float alpha =
                static_cast<float>(scale * torch::randn({}).item<double>());
            const std::vector<int64_t> ids =
                RandomLabelIds(n, l, RandomNumReal(n, l));
            const double span =
                std::max<double>(scores.max().item<float>(), alpha) -
                std::min<double>(scores.min().item<float>(), alpha);
            const bool scaling = span <= internal::kSinkhornScalingMaxSpan;
            ASSERT_EQ(scaling, scale < 100.0) << "span " << span;
            const std::string context =
                "n=" + std::to_string(n) + " l=" + std::to_string(l) +
                " T=" + std::to_string(iters) +
                " scale=" + std::to_string(scale) +
                " isa=" + std::to_string(static_cast<int>(isa));
            const TorchReference ref = TorchSinkhorn(scores, alpha, iters, ids);

            const int64_t ld_s = l + 3;
            const int64_t ld_d = l + 5;
            const std::vector<float> s = Strided(scores, ld_s);
            std::vector<float> g(static_cast<size_t>((n + 1) * (l + 1)));
            std::vector<float> w(g.size());
            BuildFrameTargets(ids.data(), n, l, true, g.data(), w.data());
            std::vector<float> a(g.size());
            std::vector<float> d(static_cast<size_t>(n * ld_d), 1234.0f);
            double d_alpha = 0.0;
            const double loss = SinkhornLossFrame(s.data(),
                                                  ld_s,
                                                  n,
                                                  l,
                                                  alpha,
                                                  iters,
                                                  g.data(),
                                                  w.data(),
                                                  a.data(),
                                                  d.data(),
                                                  ld_d,
                                                  1.0,
                                                  &d_alpha,
                                                  scratch,
                                                  isa);
            MaxErrors& worst = scaling ? worst_exp : worst_log;
            (scaling ? frames_exp : frames_log) += iters > 0 ? 1 : 0;

            const double loss_err = RelativeError(loss, ref.loss, 1e-12);
            EXPECT_LE(loss_err, kValueTol) << context;
            worst.loss = std::max(worst.loss, loss_err);

            const torch::Tensor at =
                torch::from_blob(a.data(), {n + 1, l + 1}, torch::kFloat)
                    .to(torch::kDouble);
            const double a_err = ((at - ref.log_assignment).abs() /
                                  ref.log_assignment.abs().clamp_min(1.0))
                                     .max()
                                     .item<double>();
            EXPECT_LE(a_err, kValueTol) << context;
            worst.log_assignment = std::max(worst.log_assignment, a_err);

            const torch::Tensor dt = FromStrided(d, n, l, ld_d);
            worst.d_scores = std::max(worst.d_scores,
                                      CheckGradient(dt, ref.d_scores, context));
            for (int64_t i = 0; i < n; ++i) {
              for (int64_t j = l; j < ld_d; ++j) {
                ASSERT_EQ(d[static_cast<size_t>(i * ld_d + j)], 1234.0f)
                    << "padding written, " << context;
              }
            }
            const double grad_scale = std::max(
                std::abs(ref.d_alpha), ref.d_scores.abs().max().item<double>());
            const double alpha_err =
                std::abs(d_alpha - ref.d_alpha) / grad_scale;
            EXPECT_LE(alpha_err, kGradTol)
                << context << ": " << d_alpha << " vs " << ref.d_alpha;
            worst.d_alpha = std::max(worst.d_alpha, alpha_err);
          }
        }
      }
    }
  }
  // Both paths ran with iterations.
  EXPECT_GT(frames_exp, 0);
  EXPECT_GT(frames_log, 0);
  worst_exp.Print("Sinkhorn exp-domain");
  worst_log.Print("Sinkhorn log-domain");
}

TEST(FastLoss, SinkhornWithPaddedLabelSlotsMatchesTorchAutograd) {
  // A layout-conditioned labeller's padded slots score kPaddedSlotScore =
  // -1e4 (label_encoder.h): those couplings are exact zeros of the kernel
  // and left out of the span (kSinkhornUnderflowNats), so this frame runs
  // the exp-domain path; torch's log-domain iteration is the reference.
  torch::manual_seed(11);
  FrameLossScratch scratch;
  for (const KernelIsa isa : {KernelIsa::kPortable, KernelIsa::kAuto}) {
    for (const int iters : {1, 35}) {
      const int64_t n = 12;
      const int64_t l = 9;
      torch::Tensor scores = torch::randn({n, l}).to(torch::kFloat) * 3.0;
      scores.select(1, 0).fill_(-1e4f);
      scores.select(1, l - 1).fill_(-1e4f);
      const float alpha = 0.7f;
      // Real labels 1..l-2 on the first points, the rest null.
      std::vector<int64_t> ids(static_cast<size_t>(n), l);
      for (int64_t j = 1; j < l - 1; ++j) ids[static_cast<size_t>(j)] = j;
      const std::string context = "T=" + std::to_string(iters) + " isa=" +
                                  std::to_string(static_cast<int>(isa));
      const TorchReference ref = TorchSinkhorn(scores, alpha, iters, ids);
      const std::vector<float> s = Strided(scores, l);
      std::vector<float> g(static_cast<size_t>((n + 1) * (l + 1)));
      std::vector<float> w(g.size());
      BuildFrameTargets(ids.data(), n, l, true, g.data(), w.data());
      std::vector<float> a(g.size());
      std::vector<float> d(static_cast<size_t>(n * l));
      double d_alpha = 0.0;
      const double loss = SinkhornLossFrame(s.data(),
                                            l,
                                            n,
                                            l,
                                            alpha,
                                            iters,
                                            g.data(),
                                            w.data(),
                                            a.data(),
                                            d.data(),
                                            l,
                                            1.0,
                                            &d_alpha,
                                            scratch,
                                            isa);
      EXPECT_LE(RelativeError(loss, ref.loss, 1e-12), kValueTol) << context;
      const torch::Tensor at =
          torch::from_blob(a.data(), {n + 1, l + 1}, torch::kFloat)
              .to(torch::kDouble);
      EXPECT_LE(((at - ref.log_assignment).abs() /
                 ref.log_assignment.abs().clamp_min(1.0))
                    .max()
                    .item<double>(),
                kValueTol)
          << context;
      CheckGradient(FromStrided(d, n, l, l), ref.d_scores, context);
      const double grad_scale = std::max(
          std::abs(ref.d_alpha), ref.d_scores.abs().max().item<double>());
      EXPECT_LE(std::abs(d_alpha - ref.d_alpha) / grad_scale, kGradTol)
          << context;
    }
  }
}

TEST(FastLoss, SinkhornFiniteDifferences) {
  torch::manual_seed(5);
  const int64_t n = 5;
  const int64_t l = 3;
  const int iters = 35;
  const std::vector<int64_t> ids = {2, 3, 0, 3, 3};
  std::vector<float> g(static_cast<size_t>((n + 1) * (l + 1)));
  std::vector<float> w(g.size());
  BuildFrameTargets(ids.data(), n, l, true, g.data(), w.data());
  FrameLossScratch scratch;
  for (const double scale : {1.0, 300.0}) {
    const torch::Tensor scores =
        (torch::randn({n, l}) * scale).to(torch::kFloat).contiguous();
    std::vector<float> s(scores.data_ptr<float>(),
                         scores.data_ptr<float>() + n * l);
    const double alpha = 0.5 * scale;
    std::vector<float> d(static_cast<size_t>(n * l));
    double d_alpha = 0.0;
    SinkhornLossFrame(s.data(),
                      l,
                      n,
                      l,
                      alpha,
                      iters,
                      g.data(),
                      w.data(),
                      nullptr,
                      d.data(),
                      l,
                      1.0,
                      &d_alpha,
                      scratch);
    auto loss_at = [&](const std::vector<float>& x, double al) {
      return SinkhornLossFrame(x.data(),
                               l,
                               n,
                               l,
                               al,
                               iters,
                               g.data(),
                               w.data(),
                               nullptr,
                               nullptr,
                               l,
                               1.0,
                               nullptr,
                               scratch);
    };
    const double eps = 1e-3 * scale;
    const double fd_alpha =
        (loss_at(s, alpha + eps) - loss_at(s, alpha - eps)) / (2 * eps);
    double max_grad = std::abs(d_alpha);
    for (const float v : d) max_grad = std::max(max_grad, std::abs(1.0 * v));
    constexpr double kFdTol = 1e-3;
    EXPECT_NEAR(d_alpha, fd_alpha, kFdTol * max_grad) << "scale " << scale;
    for (int64_t k = 0; k < n * l; ++k) {
      std::vector<float> plus = s;
      std::vector<float> minus = s;
      plus[k] += static_cast<float>(eps);
      minus[k] -= static_cast<float>(eps);
      const double step = static_cast<double>(plus[k]) - minus[k];
      const double fd = (loss_at(plus, alpha) - loss_at(minus, alpha)) / step;
      EXPECT_NEAR(d[k], fd, kFdTol * max_grad)
          << "score " << k << " scale " << scale;
    }
  }
}

TEST(FastLoss, SinkhornGradScaleOutputsAndScratchReuse) {
  torch::manual_seed(7);
  const int64_t n = 44;
  const int64_t l = 41;
  const int iters = 35;
  const torch::Tensor scores = torch::randn({n, l}).contiguous();
  const std::vector<float> s(scores.data_ptr<float>(),
                             scores.data_ptr<float>() + n * l);
  const std::vector<int64_t> ids = RandomLabelIds(n, l, 35);
  std::vector<float> g(static_cast<size_t>((n + 1) * (l + 1)));
  std::vector<float> w(g.size());
  BuildFrameTargets(ids.data(), n, l, true, g.data(), w.data());

  FrameLossScratch fresh;
  std::vector<float> d1(static_cast<size_t>(n * l));
  std::vector<float> a1(g.size());
  double alpha1 = 0.0;
  const double loss1 = SinkhornLossFrame(s.data(),
                                         l,
                                         n,
                                         l,
                                         1.0,
                                         iters,
                                         g.data(),
                                         w.data(),
                                         a1.data(),
                                         d1.data(),
                                         l,
                                         1.0,
                                         &alpha1,
                                         fresh);

  // A scratch used for a larger and a smaller frame first gives the same.
  FrameLossScratch reused;
  {
    const int64_t n2 = 100;
    const int64_t l2 = 53;
    const torch::Tensor big = torch::randn({n2, l2}).contiguous();
    const std::vector<int64_t> ids2 = RandomLabelIds(n2, l2, 50);
    std::vector<float> g2(static_cast<size_t>((n2 + 1) * (l2 + 1)));
    std::vector<float> w2(g2.size());
    BuildFrameTargets(ids2.data(), n2, l2, true, g2.data(), w2.data());
    std::vector<float> d2(static_cast<size_t>(n2 * l2));
    double unused = 0.0;
    SinkhornLossFrame(big.data_ptr<float>(),
                      l2,
                      n2,
                      l2,
                      1.0,
                      iters,
                      g2.data(),
                      w2.data(),
                      nullptr,
                      d2.data(),
                      l2,
                      1.0,
                      &unused,
                      reused);
    SinkhornLossFrame(big.data_ptr<float>(),
                      l2,
                      5,
                      3,
                      1.0,
                      1,
                      g2.data(),
                      w2.data(),
                      nullptr,
                      d2.data(),
                      l2,
                      1.0,
                      &unused,
                      reused);
  }
  std::vector<float> d2(static_cast<size_t>(n * l));
  std::vector<float> a2(g.size());
  double alpha2 = 0.25;  // accumulated into
  const double loss2 = SinkhornLossFrame(s.data(),
                                         l,
                                         n,
                                         l,
                                         1.0,
                                         iters,
                                         g.data(),
                                         w.data(),
                                         a2.data(),
                                         d2.data(),
                                         l,
                                         0.5,
                                         &alpha2,
                                         reused);
  EXPECT_EQ(loss1, loss2);
  EXPECT_EQ(a1, a2);
  EXPECT_DOUBLE_EQ(alpha2, 0.25 + 0.5 * alpha1);
  for (size_t k = 0; k < d1.size(); ++k) {
    ASSERT_FLOAT_EQ(d2[k], 0.5f * d1[k]) << k;
  }
  // Forward only: same loss, nothing else needed.
  EXPECT_EQ(loss1,
            SinkhornLossFrame(s.data(),
                              l,
                              n,
                              l,
                              1.0,
                              iters,
                              g.data(),
                              w.data(),
                              nullptr,
                              nullptr,
                              l,
                              1.0,
                              nullptr,
                              reused));
  EXPECT_THROW(SinkhornLossFrame(s.data(),
                                 l,
                                 0,
                                 l,
                                 1.0,
                                 iters,
                                 g.data(),
                                 w.data(),
                                 nullptr,
                                 nullptr,
                                 l,
                                 1.0,
                                 nullptr,
                                 reused),
               InternalError);
}

// ---------------------------------------------------------------------------
// Log-softmax.

TEST(FastLoss, LogSoftmaxMatchesTorch) {
  torch::manual_seed(9);
  MaxErrors worst;
  FrameLossScratch scratch;
  for (const bool quirk : {true, false}) {
    for (const int64_t n : {5, 44, 70}) {
      for (const int64_t l : {3, 41}) {
        for (const double scale : {1.0, 30.0}) {
          const torch::Tensor scores =
              (torch::randn({n, l + 1}) * scale).to(torch::kFloat);
          const std::vector<int64_t> ids =
              RandomLabelIds(n, l, RandomNumReal(n, l));
          const std::string context = "n=" + std::to_string(n) +
                                      " l=" + std::to_string(l) +
                                      " scale=" + std::to_string(scale) +
                                      " quirk=" + std::to_string(quirk);
          const TorchReference ref = TorchLogSoftmax(scores, quirk, ids);
          const int64_t ld_s = l + 4;
          const int64_t ld_d = l + 2;
          const std::vector<float> s = Strided(scores, ld_s);
          std::vector<float> g(static_cast<size_t>(n * (l + 1)));
          std::vector<float> w(g.size());
          BuildFrameTargets(ids.data(), n, l, false, g.data(), w.data());
          std::vector<float> a(g.size());
          std::vector<float> d(static_cast<size_t>(n * ld_d), 1234.0f);
          const double loss = LogSoftmaxLossFrame(s.data(),
                                                  ld_s,
                                                  n,
                                                  l,
                                                  quirk,
                                                  g.data(),
                                                  w.data(),
                                                  a.data(),
                                                  d.data(),
                                                  ld_d,
                                                  1.0,
                                                  scratch);
          const double loss_err = RelativeError(loss, ref.loss, 1e-12);
          EXPECT_LE(loss_err, kValueTol) << context;
          worst.loss = std::max(worst.loss, loss_err);
          const torch::Tensor at =
              torch::from_blob(a.data(), {n, l + 1}, torch::kFloat)
                  .to(torch::kDouble);
          const double a_err = ((at - ref.log_assignment).abs() /
                                ref.log_assignment.abs().clamp_min(1.0))
                                   .max()
                                   .item<double>();
          EXPECT_LE(a_err, kValueTol) << context;
          worst.log_assignment = std::max(worst.log_assignment, a_err);
          worst.d_scores = std::max(
              worst.d_scores,
              CheckGradient(
                  FromStrided(d, n, l + 1, ld_d), ref.d_scores, context));
          for (int64_t i = 0; i < n; ++i) {
            ASSERT_EQ(d[static_cast<size_t>(i * ld_d + l + 1)], 1234.0f)
                << context;
          }
        }
      }
    }
  }
  worst.Print("log-softmax");
}

}  // namespace
}  // namespace soma
