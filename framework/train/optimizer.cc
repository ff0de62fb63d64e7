#include "framework/train/optimizer.h"

#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/registry/registry.h"

#include <fmt/format.h>
#include <torch/optim/adam.h>
#include <torch/optim/optimizer.h>

namespace soma {

void AdamOptions::Validate() const {
  if (!(lr > 0) || !(beta1 >= 0 && beta1 < 1) || !(beta2 >= 0 && beta2 < 1) ||
      !(eps > 0) || !(weight_decay >= 0)) {
    throw ConfigError(fmt::format(
        "Invalid configuration. optimizer = {{lr: {}, betas: [{}, {}], eps: "
        "{}, weight_decay: {}}}. Violated constraint: lr > 0, 0 <= betas < 1, "
        "eps > 0, weight_decay >= 0",
        lr,
        beta1,
        beta2,
        eps,
        weight_decay));
  }
}

AdamOptions DecodeAdamOptions(const ConfigNode& node) {
  ConfigReader reader(node);
  AdamOptions options;
  std::vector<double> betas = {options.beta1, options.beta2};
  reader.Read("lr", &options.lr);
  reader.Read("betas", &betas);
  reader.Read("eps", &options.eps);
  reader.Read("weight_decay", &options.weight_decay);
  reader.Read("amsgrad", &options.amsgrad);
  reader.Check("betas", betas.size() == 2, "betas has 2 entries");
  options.beta1 = betas[0];
  options.beta2 = betas[1];
  reader.Check("lr", options.lr > 0, "lr > 0");
  reader.Check("betas",
               betas[0] >= 0 && betas[0] < 1 && betas[1] >= 0 && betas[1] < 1,
               "0 <= beta < 1");
  reader.Check("eps", options.eps > 0, "eps > 0");
  reader.Check("weight_decay", options.weight_decay >= 0, "weight_decay >= 0");
  reader.Finish();
  return options;
}

AdamSpec::AdamSpec(const AdamOptions& options) : options_(options) {
  options_.Validate();
}

std::unique_ptr<torch::optim::Optimizer> AdamSpec::Build(
    std::vector<at::Tensor> parameters) const {
  torch::optim::AdamOptions adam(options_.lr);
  adam.betas({options_.beta1, options_.beta2});
  adam.eps(options_.eps);
  // libtorch's Adam adds weight_decay * param to the gradient (classic L2,
  // as torch.optim.Adam); AdamW would decouple it. Tested in trainer_test.
  adam.weight_decay(options_.weight_decay);
  adam.amsgrad(options_.amsgrad);
  return std::make_unique<torch::optim::Adam>(std::move(parameters), adam);
}

double GetLearningRate(const torch::optim::Optimizer& optimizer) {
  SOMA_CHECK(!optimizer.param_groups().empty());
  return optimizer.param_groups().front().options().get_lr();
}

void SetLearningRate(torch::optim::Optimizer& optimizer, double lr) {
  for (torch::optim::OptimizerParamGroup& group : optimizer.param_groups()) {
    group.options().set_lr(lr);
  }
}

void RegisterOptimizers() {
  GetRegistry<OptimizerSpec>().Register(
      "adam", [](const ConfigNode& node, BuildContext&) {
        return std::make_unique<AdamSpec>(DecodeAdamOptions(node));
      });
  RegisterConfigGroup<OptimizerSpec>("optimizer");
}

}  // namespace soma
