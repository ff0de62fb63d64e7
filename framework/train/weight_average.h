// An exponential moving average of a model's weights (Polyak averaging, as
// in Polyak & Juditsky 1992 and the `ModelEma` of timm / TensorFlow's
// ExponentialMovingAverage with `num_updates`): after optimizer step t
// (1-based), every floating-point weight w has an average
//
//   a <- d_t a + (1 - d_t) w,   d_t = min(decay, (1 + t) / (10 + t)),
//
// so the first steps are averaged over a short horizon and the horizon grows
// to ~1 / (1 - decay) steps (decay 0.999 from step ~9,000). Integer tensors
// (BatchNorm's num_batches_tracked) are copied. The trainer validates and
// checkpoints the average (`train.ema_decay`, trainer.h).
//
//   WeightAverage average(WeightAverage::WeightsOf(*model), 0.999);
//   average.Reset();               // a = w, after loading any weights
//   ... optimizer step t ...; average.Update(t);
//   { WeightAverage::Swapped in(&average); Validate(); }  // w <-> a
//   average.SaveAverage(*model, &archive);  // as Module::save, averaged
//
// The average holds the model's own tensor handles, not copies of their
// storage: a checkpoint load (Module::load replaces storage with `set_`) is
// seen by the next Reset().
#pragma once

#include <ATen/core/Tensor.h>

#include <cstdint>
#include <vector>

namespace torch::nn {
class Module;
}  // namespace torch::nn
namespace torch::serialize {
class OutputArchive;
}  // namespace torch::serialize

namespace soma {

class WeightAverage {
 public:
  /// `weights`: the model's parameters and buffers (handles, not clones;
  /// WeightsOf). `decay` in (0, 1); ConfigError otherwise.
  WeightAverage(std::vector<at::Tensor> weights, double decay);

  /// A module's parameters, then its buffers (handles).
  static std::vector<at::Tensor> WeightsOf(const torch::nn::Module& module);

  /// The decay of step `step` (1-based): min(decay, (1 + step) / (10 +
  /// step)).
  static double DecayAt(double decay, int64_t step);

  /// The average becomes the current weights (shapes may have changed since
  /// construction, e.g. after a checkpoint load).
  void Reset();
  /// Folds the weights after optimizer step `step` (1-based) into the
  /// average. Reset() must have been called.
  void Update(int64_t step);
  /// Exchanges the weights and their average, bit for bit; twice restores.
  void Swap();
  /// Writes `module` to `archive` as `module.save(archive)` does, with each
  /// of this average's weights replaced by a copy of its average (Module::load
  /// reads it back; the archive does not alias the live weights, which an
  /// archive of `module.save` would until it is serialised).
  void SaveAverage(const torch::nn::Module& module,
                   torch::serialize::OutputArchive* archive) const;

  /// Swaps the average in for a scope (validation, saving), exception-safe.
  class Swapped {
   public:
    /// `average` may be null (no averaging: does nothing).
    explicit Swapped(WeightAverage* average);
    ~Swapped();
    Swapped(const Swapped&) = delete;
    Swapped& operator=(const Swapped&) = delete;

   private:
    WeightAverage* average_;
  };

 private:
  std::vector<at::Tensor> weights_;  // the model's tensors
  std::vector<at::Tensor> average_;  // one per weight, same shape
  double decay_;
};

}  // namespace soma
