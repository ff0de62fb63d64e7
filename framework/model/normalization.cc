#include "framework/model/normalization.h"

#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/model/fast_train.h"
#include "framework/model/loss.h"
#include "framework/model/register.h"
#include "framework/model/torch_utils.h"
#include "framework/registry/registry.h"

#include <fmt/format.h>
#include <torch/torch.h>

#include <cmath>
#include <memory>

namespace soma {

void SinkhornOptions::Validate() const {
  if (num_iters < 0) {
    throw ConfigError(
        fmt::format("Invalid configuration. num_iters = {}. Violated "
                    "constraint: num_iters >= 0",
                    num_iters));
  }
  if (!std::isfinite(init_bin_score)) {
    throw ConfigError(
        fmt::format("Invalid configuration. init_bin_score = {}. Violated "
                    "constraint: finite",
                    init_bin_score));
  }
}

torch::Tensor LogOptimalTransport(const torch::Tensor& scores,
                                  const torch::Tensor& bin_score,
                                  int num_iters) {
  if (scores.dim() != 3) {
    throw ShapeError(
        fmt::format("LogOptimalTransport: scores must be B x N x L, got {}",
                    ShapeString(scores)));
  }
  const int64_t batch = scores.size(0);
  const int64_t n = scores.size(1);
  const int64_t l = scores.size(2);
  const auto options = scores.options();
  const torch::Tensor alpha = bin_score.to(options).reshape({});
  // Couplings Z: scores with the dustbin column, row and corner set to alpha.
  const torch::Tensor bins0 = alpha.expand({batch, n, 1});
  const torch::Tensor bins1 = alpha.expand({batch, 1, l});
  const torch::Tensor corner = alpha.expand({batch, 1, 1});
  const torch::Tensor couplings = torch::cat(
      {torch::cat({scores, bins0}, 2), torch::cat({bins1, corner}, 2)}, 1);
  // Each point and label carries mass 1/(N+L); the dustbins L/(N+L), N/(N+L).
  const double norm = -std::log(static_cast<double>(n + l));
  torch::Tensor log_mu = torch::full({n + 1}, norm, options);
  torch::Tensor log_nu = torch::full({l + 1}, norm, options);
  log_mu.index_put_({n}, std::log(static_cast<double>(l)) + norm);
  log_nu.index_put_({l}, std::log(static_cast<double>(n)) + norm);
  log_mu = log_mu.unsqueeze(0).expand({batch, n + 1});
  log_nu = log_nu.unsqueeze(0).expand({batch, l + 1});
  torch::Tensor u = torch::zeros({batch, n + 1}, options);
  torch::Tensor v = torch::zeros({batch, l + 1}, options);
  for (int it = 0; it < num_iters; ++it) {
    u = log_mu - torch::logsumexp(couplings + v.unsqueeze(1), 2);
    v = log_nu - torch::logsumexp(couplings + u.unsqueeze(2), 1);
  }
  return couplings + u.unsqueeze(2) + v.unsqueeze(1) - norm;
}

SinkhornImpl::SinkhornImpl(const SinkhornOptions& options) : options_(options) {
  options_.Validate();
  bin_score = register_parameter(
      "bin_score", torch::tensor(static_cast<float>(options_.init_bin_score)));
}

torch::Tensor SinkhornImpl::forward(const torch::Tensor& scores) {
  return LogOptimalTransport(scores, bin_score, options_.num_iters);
}

torch::Tensor LogSoftmaxImpl::forward(const torch::Tensor& scores) {
  return torch::log_softmax(scores, -1);
}

std::unique_ptr<fast::NormalizationLossOp> NormalizationImpl::MakeFastLossOp(
    const LabelingLoss& /*loss*/, std::string* why_not) {
  if (why_not != nullptr) {
    *why_not =
        fmt::format("the normalization {} has no fast training path", name());
  }
  return nullptr;
}

namespace {

/// True with the loss's options if it has a fast path, else false with the
/// reason in `*why_not`.
bool FastLossOptions(const LabelingLoss& loss,
                     LabelingLossOptions* options,
                     std::string* why_not) {
  if (loss.FastOptions(options)) return true;
  if (why_not != nullptr) *why_not = "the loss has no fast training path";
  return false;
}

}  // namespace

std::unique_ptr<fast::NormalizationLossOp> SinkhornImpl::MakeFastLossOp(
    const LabelingLoss& loss, std::string* why_not) {
  LabelingLossOptions options;
  if (!FastLossOptions(loss, &options, why_not)) return nullptr;
  return fast::MakeSinkhornLossOp(bin_score, options_.num_iters);
}

std::unique_ptr<fast::NormalizationLossOp> LogSoftmaxImpl::MakeFastLossOp(
    const LabelingLoss& loss, std::string* why_not) {
  LabelingLossOptions options;
  if (!FastLossOptions(loss, &options, why_not)) return nullptr;
  return fast::MakeLogSoftmaxLossOp(options);
}

void RegisterNormalizations() {
  Registry<NormalizationImpl>& registry = GetRegistry<NormalizationImpl>();
  registry.Register("sinkhorn", [](const ConfigNode& node, BuildContext&) {
    ConfigReader reader(node);
    SinkhornOptions options;
    reader.Read("num_iters", &options.num_iters);
    reader.Read("init_bin_score", &options.init_bin_score);
    reader.Check("num_iters", options.num_iters >= 0, "num_iters >= 0");
    reader.Check(
        "init_bin_score", std::isfinite(options.init_bin_score), "finite");
    reader.Finish();
    return std::make_unique<SinkhornImpl>(options);
  });
  registry.Register("log_softmax", [](const ConfigNode& node, BuildContext&) {
    ConfigReader reader(node);
    reader.Finish();
    return std::make_unique<LogSoftmaxImpl>();
  });
  RegisterConfigGroup<NormalizationImpl>("normalization");
}

}  // namespace soma
