// Learning-rate schedules and early stopping, stepped once per epoch on the
// validation loss (REFERENCE 2.4), or per optimizer step:
//
//   ReduceLROnPlateau(mode min, factor 0.1, patience 3, threshold 1e-4 rel,
//                     cooldown 0, min_lr 0)        configs/scheduler/plateau
//   linear warm-up + cosine decay (per step)      configs/scheduler/cosine
//   EarlyStopping(monitor val_loss, mode min, min_delta 0, patience 8)
//                                                  train.early_stopping
//
// Both are plain value types without torch, with their state serialised to a
// text blob stored in the checkpoint, so that a resumed run takes exactly the
// same decisions as an uninterrupted one.
#pragma once

#include "framework/config/node.h"

#include <cstdint>
#include <limits>
#include <memory>
#include <string>
#include <string_view>

namespace soma {

/// A learning-rate schedule stepped once per epoch with the monitored metric
/// (val_loss). Registry kind "scheduler" (configs/scheduler/).
class LrScheduler {
 public:
  static constexpr std::string_view kRegistryName = "scheduler";
  virtual ~LrScheduler() = default;
  /// Consumes the epoch's metric; returns the learning rate for the next
  /// epoch given the current one.
  virtual double Step(double metric, double lr) = 0;
  /// The learning rate of optimizer step `step` (0-based, counted over the
  /// whole run) of `total_steps` planned, given the epoch's learning rate.
  /// Schedules that act per step (warm-up, cosine) override it; the default
  /// keeps the epoch's rate. A pure function of its arguments, so a resumed
  /// run repeats the rates of an uninterrupted one.
  virtual double StepLr(int64_t /*step*/,
                        int64_t /*total_steps*/,
                        double epoch_lr) const {
    return epoch_lr;
  }
  /// The full state as text (exact round trip through LoadState).
  virtual std::string SaveState() const = 0;
  /// Restores SaveState(); InternalError on malformed text.
  virtual void LoadState(std::string_view state) = 0;
};

/// `name: none`: a constant learning rate.
class ConstantLr : public LrScheduler {
 public:
  double Step(double /*metric*/, double lr) override { return lr; }
  std::string SaveState() const override { return ""; }
  void LoadState(std::string_view /*state*/) override {}
};

/// Options of ReduceLROnPlateau (PyTorch defaults, mode min, threshold mode
/// rel).
struct PlateauOptions {
  double factor = 0.1;      // lr <- max(lr * factor, min_lr); 0 < factor < 1
  int patience = 3;         // bad epochs tolerated before a reduction
  double threshold = 1e-4;  // relative improvement: m < best * (1 - threshold)
  int cooldown = 0;         // epochs after a reduction without counting
  double min_lr = 0.0;      // lower bound of the learning rate
  double eps = 1e-8;        // reductions smaller than eps are ignored
  void Validate() const;    // ConfigError on violation
};

/// torch.optim.lr_scheduler.ReduceLROnPlateau (mode min, rel threshold), one
/// parameter group:
///   better = metric < best * (1 - threshold)   (NaN is never better)
///   better: best = metric, bad = 0; else bad += 1
///   in cooldown: cooldown_counter -= 1, bad = 0
///   bad > patience: lr = max(lr * factor, min_lr) if the change > eps;
///                   cooldown_counter = cooldown, bad = 0
class ReduceLrOnPlateau : public LrScheduler {
 public:
  explicit ReduceLrOnPlateau(const PlateauOptions& options = {});
  double Step(double metric, double lr) override;
  std::string SaveState() const override;
  void LoadState(std::string_view state) override;

  double best() const { return best_; }
  int num_bad_epochs() const { return num_bad_epochs_; }
  int cooldown_counter() const { return cooldown_counter_; }
  const PlateauOptions& options() const { return options_; }

 private:
  PlateauOptions options_;
  double best_ = std::numeric_limits<double>::infinity();
  int num_bad_epochs_ = 0;
  int cooldown_counter_ = 0;
  int64_t last_epoch_ = 0;
};

/// Options of the warm-up + cosine schedule.
struct CosineOptions {
  int64_t warmup_steps = 500;  // linear ramp from lr / warmup_steps to lr
  double final_factor = 0.01;  // lr at the last step = final_factor * lr
  void Validate() const;       // ConfigError on violation
};

/// `name: cosine`: a linear warm-up over the first `warmup_steps` optimizer
/// steps, then a half cosine from the optimizer's lr down to
/// `final_factor * lr` at the run's last planned step (max_epochs x batches
/// per epoch; Loshchilov & Hutter 2017, SGDR without restarts; Goyal et al.
/// 2017 for the warm-up):
///   s <  W:  lr_s = lr * (s + 1) / W
///   s >= W:  lr_s = lr * (f + (1 - f) * (1 + cos(pi * (s - W) / (T - W))) / 2)
/// The epoch-level rate stays the optimizer's lr (Step returns it as is).
class WarmupCosineLr : public LrScheduler {
 public:
  explicit WarmupCosineLr(const CosineOptions& options = {});
  double Step(double /*metric*/, double lr) override { return lr; }
  double StepLr(int64_t step,
                int64_t total_steps,
                double epoch_lr) const override;
  std::string SaveState() const override { return ""; }
  void LoadState(std::string_view /*state*/) override {}
  const CosineOptions& options() const { return options_; }

 private:
  CosineOptions options_;
};

/// Options of early stopping (Lightning EarlyStopping, mode min).
struct EarlyStoppingOptions {
  bool enabled = true;
  int patience = 8;          // stop after this many epochs without improvement
  double min_delta = 0.0;    // improvement: metric < best - min_delta
  bool check_finite = true;  // stop at once on a non-finite metric
  void Validate() const;     // ConfigError on violation
};

/// Lightning's EarlyStopping on a metric to minimise: improvement when
/// `metric < best - min_delta` (best starts at +inf) resets the wait count;
/// otherwise the wait count grows and training stops when it reaches
/// `patience`. A non-finite metric stops at once under `check_finite`.
class EarlyStopping {
 public:
  explicit EarlyStopping(const EarlyStoppingOptions& options = {});
  /// Consumes the epoch's metric; true when training should stop.
  bool Update(double metric);
  bool should_stop() const { return stopped_; }
  double best() const { return best_; }
  int wait_count() const { return wait_count_; }
  /// Why it stopped ("" while running).
  const std::string& reason() const { return reason_; }

  std::string SaveState() const;
  void LoadState(std::string_view state);

 private:
  EarlyStoppingOptions options_;
  double best_ = std::numeric_limits<double>::infinity();
  int wait_count_ = 0;
  bool stopped_ = false;
  std::string reason_;
};

/// Decoders (unknown keys are an error).
PlateauOptions DecodePlateauOptions(const ConfigNode& node);
CosineOptions DecodeCosineOptions(const ConfigNode& node);
EarlyStoppingOptions DecodeEarlyStoppingOptions(const ConfigNode& node);

/// Registers schedulers `plateau`, `cosine` and `none` and the `scheduler`
/// config group.
void RegisterSchedulers();

}  // namespace soma
