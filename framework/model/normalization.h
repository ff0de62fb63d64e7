// Output normalisations of the SOMA labeler (paper Sec. 4.2; REFERENCE 1.4,
// 1.5): log-domain optimal transport with dustbins (Sinkhorn, the default)
// and the log-softmax ablation with an extra null column.
#pragma once

#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

#include <cstdint>
#include <memory>
#include <string>
#include <string_view>

namespace soma {

class LabelingLoss;
namespace fast {
class NormalizationLossOp;
}  // namespace fast

/// Turns the score matrix S (`B x N x C`) into the augmented log assignment
/// A'. Registry kind "normalization" (configs/normalization/).
class NormalizationImpl : public torch::nn::Module {
 public:
  static constexpr std::string_view kRegistryName = "normalization";

  /// Columns the score head must produce for `num_labels` labels: L for
  /// optimal transport, L + 1 (null column) for log-softmax.
  virtual int64_t NumScoreColumns(int64_t num_labels) const = 0;
  /// True when A' has the dustbin row (N + 1 rows), false for N rows.
  virtual bool HasDustbinRow() const = 0;
  /// `scores`: `B x N x NumScoreColumns(L)` -> A': `B x (N+1) x (L+1)` with
  /// the dustbin row, else `B x N x (L+1)`; log values whose point rows are
  /// log-distributions over the L+1 columns.
  virtual torch::Tensor forward(const torch::Tensor& scores) = 0;
  /// This normalization followed by `loss` in the hand-written training
  /// engine (fast_train.h); nullptr with the reason in `*why_not` when
  /// either has no fast path (the default).
  virtual std::unique_ptr<fast::NormalizationLossOp> MakeFastLossOp(
      const LabelingLoss& loss, std::string* why_not);
};
TORCH_MODULE(Normalization);

/// Options of the optimal-transport normalization.
struct SinkhornOptions {
  int num_iters = 35;           // Sinkhorn iterations (paper Appendix C)
  double init_bin_score = 1.0;  // initial value of the learnable dustbin score
  void Validate() const;        // ConfigError on violation
};

/// Log-domain optimal transport with dustbins and a learnable dustbin score
/// alpha (parameter `bin_score`, a 0-dim tensor) (REFERENCE 1.4).
class SinkhornImpl : public NormalizationImpl {
 public:
  explicit SinkhornImpl(const SinkhornOptions& options = {});
  int64_t NumScoreColumns(int64_t num_labels) const override {
    return num_labels;
  }
  bool HasDustbinRow() const override { return true; }
  torch::Tensor forward(const torch::Tensor& scores) override;
  std::unique_ptr<fast::NormalizationLossOp> MakeFastLossOp(
      const LabelingLoss& loss, std::string* why_not) override;
  const SinkhornOptions& options() const { return options_; }

  torch::Tensor bin_score;

 private:
  SinkhornOptions options_;
};
TORCH_MODULE(Sinkhorn);

/// log_softmax over L+1 columns (the head predicts the null column itself).
class LogSoftmaxImpl : public NormalizationImpl {
 public:
  int64_t NumScoreColumns(int64_t num_labels) const override {
    return num_labels + 1;
  }
  bool HasDustbinRow() const override { return false; }
  torch::Tensor forward(const torch::Tensor& scores) override;
  std::unique_ptr<fast::NormalizationLossOp> MakeFastLossOp(
      const LabelingLoss& loss, std::string* why_not) override;
};
TORCH_MODULE(LogSoftmax);

/// Log-domain optimal transport with dustbins (SuperGlue's algorithm as used
/// by SOMA, REFERENCE 1.4), differentiable.
///
/// `scores`: `B x N x L` couplings; `bin_score`: scalar alpha. Builds Z
/// (`B x (N+1) x (L+1)`, alpha in the dustbin row, column and corner), the
/// log marginals `norm = -log(N+L)`, log_mu = [norm x N, log(L) + norm],
/// log_nu = [norm x L, log(N) + norm], runs `num_iters` iterations of
/// `u = log_mu - logsumexp_j(Z + v)` then `v = log_nu - logsumexp_i(Z + u)`
/// from u = v = 0, and returns `P = Z + u + v - norm` (`B x (N+1) x (L+1)`).
torch::Tensor LogOptimalTransport(const torch::Tensor& scores,
                                  const torch::Tensor& bin_score,
                                  int num_iters);

}  // namespace soma
