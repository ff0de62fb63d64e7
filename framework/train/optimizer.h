// Optimisers selected from the `optimizer` config group (REFERENCE 2.4):
// Adam, lr 1e-3, betas (0.9, 0.999), eps 1e-8, weight decay 5e-5 as classic
// L2 (added to the gradient before the moments, torch.optim.Adam; not AdamW),
// on every trainable parameter.
#pragma once

#include "framework/config/node.h"

#include <ATen/core/Tensor.h>

#include <memory>
#include <string_view>
#include <vector>

namespace torch::optim {
class Optimizer;
}  // namespace torch::optim

namespace soma {

/// Options of `name: adam`.
struct AdamOptions {
  double lr = 1e-3;
  double beta1 = 0.9;
  double beta2 = 0.999;
  double eps = 1e-8;
  double weight_decay = 5e-5;  // classic L2: g <- g + wd * theta
  bool amsgrad = false;
  void Validate() const;  // ConfigError on violation
};

AdamOptions DecodeAdamOptions(const ConfigNode& node);

/// A factory of optimisers (the config is decoded once; the optimiser is
/// built on the model's parameters later). Registry kind "optimizer".
class OptimizerSpec {
 public:
  static constexpr std::string_view kRegistryName = "optimizer";
  virtual ~OptimizerSpec() = default;
  virtual std::unique_ptr<torch::optim::Optimizer> Build(
      std::vector<at::Tensor> parameters) const = 0;
  /// The initial learning rate.
  virtual double lr() const = 0;
};

/// `name: adam`.
class AdamSpec : public OptimizerSpec {
 public:
  explicit AdamSpec(const AdamOptions& options = {});
  std::unique_ptr<torch::optim::Optimizer> Build(
      std::vector<at::Tensor> parameters) const override;
  double lr() const override { return options_.lr; }
  const AdamOptions& options() const { return options_; }

 private:
  AdamOptions options_;
};

/// The learning rate of the first parameter group.
double GetLearningRate(const torch::optim::Optimizer& optimizer);
/// Sets the learning rate of every parameter group.
void SetLearningRate(torch::optim::Optimizer& optimizer, double lr);

/// Registers `adam` and the `optimizer` config group.
void RegisterOptimizers();

}  // namespace soma
