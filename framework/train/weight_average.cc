#include "framework/train/weight_average.h"

#include "framework/core/error.h"

#include <ATen/ATen.h>
#include <c10/core/GradMode.h>
#include <fmt/format.h>
#include <torch/nn/module.h>
#include <torch/serialize/output-archive.h>

#include <algorithm>
#include <utility>

namespace soma {

WeightAverage::WeightAverage(std::vector<at::Tensor> weights, double decay)
    : weights_(std::move(weights)), decay_(decay) {
  if (!(decay > 0.0 && decay < 1.0)) {
    throw ConfigError(fmt::format(
        "Invalid configuration. train.ema_decay = {}. Violated constraint: "
        "0 < ema_decay < 1 (0 turns the weight average off)",
        decay));
  }
}

std::vector<at::Tensor> WeightAverage::WeightsOf(
    const torch::nn::Module& module) {
  std::vector<at::Tensor> weights = module.parameters();
  for (const at::Tensor& buffer : module.buffers()) weights.push_back(buffer);
  return weights;
}

double WeightAverage::DecayAt(double decay, int64_t step) {
  const double t = static_cast<double>(std::max<int64_t>(step, 0));
  return std::min(decay, (1.0 + t) / (10.0 + t));
}

void WeightAverage::Reset() {
  c10::NoGradGuard no_grad;
  average_.clear();
  average_.reserve(weights_.size());
  for (const at::Tensor& w : weights_) {
    average_.push_back(w.detach().clone());
  }
}

void WeightAverage::Update(int64_t step) {
  SOMA_CHECK_EQ(average_.size(), weights_.size());
  c10::NoGradGuard no_grad;
  const double weight = 1.0 - DecayAt(decay_, step);
  for (size_t i = 0; i < weights_.size(); ++i) {
    const at::Tensor w = weights_[i].detach();
    at::Tensor& a = average_[i];
    SOMA_CHECK(a.sizes() == w.sizes());
    if (at::isFloatingType(w.scalar_type())) {
      a.lerp_(w, weight);  // a + weight * (w - a)
    } else {
      a.copy_(w);
    }
  }
}

void WeightAverage::Swap() {
  SOMA_CHECK_EQ(average_.size(), weights_.size());
  c10::NoGradGuard no_grad;
  for (size_t i = 0; i < weights_.size(); ++i) {
    at::Tensor w = weights_[i].detach();
    SOMA_CHECK(average_[i].sizes() == w.sizes());
    const at::Tensor held = w.clone();
    w.copy_(average_[i]);
    average_[i].copy_(held);
  }
}

void WeightAverage::SaveAverage(
    const torch::nn::Module& module,
    torch::serialize::OutputArchive* archive) const {
  SOMA_CHECK_EQ(average_.size(), weights_.size());
  const auto average_of = [this](const at::Tensor& tensor) {
    for (size_t i = 0; i < weights_.size(); ++i) {
      if (weights_[i].unsafeGetTensorImpl() == tensor.unsafeGetTensorImpl()) {
        return average_[i].clone();
      }
    }
    return tensor.detach().clone();  // not averaged (none in a labeller)
  };
  // The layout of Module::save (libtorch): the module's own parameters and
  // buffers by name, then one nested archive per serialisable child.
  for (const auto& p : module.named_parameters(/*recurse=*/false)) {
    archive->write(p.key(), average_of(p.value()));
  }
  for (const auto& b : module.named_buffers(/*recurse=*/false)) {
    archive->write(b.key(), average_of(b.value()), /*is_buffer=*/true);
  }
  for (const auto& child : module.named_children()) {
    if (!child.value()->is_serializable()) continue;
    torch::serialize::OutputArchive nested(archive->compilation_unit());
    SaveAverage(*child.value(), &nested);
    archive->write(child.key(), nested);
  }
}

WeightAverage::Swapped::Swapped(WeightAverage* average) : average_(average) {
  if (average_ != nullptr) average_->Swap();
}

WeightAverage::Swapped::~Swapped() {
  if (average_ != nullptr) average_->Swap();
}

}  // namespace soma
