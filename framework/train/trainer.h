// The SOMA trainer (REFERENCE 2.3-2.5): epochs of Adam steps on the
// labelling loss, per-epoch validation (loss, accuracy, macro F1),
// ReduceLROnPlateau and early stopping on val_loss, `metrics.csv`,
// checkpoints `checkpoints/{last,best}.pt`, resume and fine-tuning.
//
//   Trainer trainer(options, model, loss, optimizer_spec, std::move(sched),
//                   identity, run_dir);
//   TrainSummary summary = trainer.Train(train_source, val_source);
//
// Determinism. Every random number derives from (seed, epoch, batch): the
// sources are pure functions of (epoch, range) (batch_source.h) and torch's
// global generator is reseeded before every batch with
// Rng(seed).Stream("torch").Stream(epoch).Stream(batch). With the same
// config, seed and thread count, two runs write identical metrics.csv except
// the last two columns (wall_s, frames_per_s), and a run resumed from
// `last.pt` (after a crash or `kill -9`) ends with the same metrics and
// weights as an uninterrupted one: the checkpoint holds everything that
// carries over between epochs (weights and BatchNorm buffers, Adam moments
// and step counts, learning rate, scheduler and early-stopping state, best
// val_loss, the metrics history, torch's generator state; with
// `ema_decay` the weight average as `model` and the trained weights as
// `train_model`).
//
// metrics.csv columns: epoch (completed epochs, 1-based), step (optimizer
// steps so far), train_loss (mean over the epoch's batches of the batch loss,
// which is the *sum* over the batch's frames as released), val_loss (nanmean
// of per-batch losses), val_acc, val_f1 (per batch pooled, mean over batches,
// REFERENCE 2.5), val_acc_frame, val_f1_frame (per frame, mean over frames,
// REFERENCE 4.3), lr (the learning rate used in the epoch), wall_s (seconds
// of the epoch incl. validation), frames_per_s (training frames per second).
// Only the last two depend on the machine.
#pragma once

#include "framework/config/node.h"
#include "framework/model/labeler.h"
#include "framework/train/schedule.h"

#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace torch::optim {
class Optimizer;
}  // namespace torch::optim

namespace soma {

class BatchSource;
class FastTrainer;
class LabelingLoss;
class OptimizerSpec;
class WeightAverage;

/// Options of the trainer (the `train` config group, configs/train/).
struct TrainerOptions {
  int64_t batch_size = 256;    // frames per optimizer step (drop_last)
  int64_t val_batch_size = 0;  // frames per validation batch; 0 = batch_size
  int max_epochs = 50;
  EarlyStoppingOptions early_stopping;  // patience 8 on val_loss
  /// Synthetic data only (read by the train task): frames per training epoch
  /// (fresh frames every epoch) and size of the fixed validation set.
  int64_t train_frames = 100000;
  int64_t val_frames = 10000;
  /// "stream": fresh frames every epoch; "pool": the train_frames are
  /// synthesised once (during epoch 1) and reshuffled every epoch.
  std::string synth_data = "stream";
  int data_threads = 1;  // threads of the background synthesis / reading
  int prefetch = 2;      // batches read ahead (0 = synchronous)
  /// "auto": resume from `<run_dir>/checkpoints/last.pt` if it exists;
  /// "never": start fresh (an existing last.pt is overwritten); else the
  /// path of a checkpoint to resume from (full state).
  std::string resume = "auto";
  /// Fine-tuning: a checkpoint whose weights (only) initialise the model.
  /// Ignored when resuming.
  std::string init_from;
  bool progress = true;  // progress bar on stderr
  /// "fast": the hand-written training engine (model/fast_train.h) where
  /// the model supports it, else torch with a logged reason; "torch":
  /// libtorch autograd and torch::optim.
  std::string engine = "fast";
  /// "fp32", or "bf16": the fast engine's per-point convolution products in
  /// bf16 with fp32 accumulation and fp32 master weights, on AMX or
  /// AVX512_BF16 (elsewhere fp32 with a logged reason). The torch engine is
  /// always fp32.
  std::string precision = "fp32";
  /// Clip the global L2 norm of the gradients to this value before every
  /// optimizer step (Lightning's `gradient_clip_val`, algorithm "norm");
  /// 0 = off.
  double gradient_clip_val = 0.0;
  /// Decay of an exponential moving average of the weights (Polyak
  /// averaging, weight_average.h), updated after every optimizer step;
  /// validation, the scheduler, early stopping and both checkpoints' `model`
  /// use the average, and the checkpoints also hold the trained weights
  /// (`train_model`) to resume from. 0 = off (SOMA: off).
  double ema_decay = 0.0;
  uint64_t seed = 0;      // root seed (from the run, not the `train` group)
  void Validate() const;  // ConfigError on violation
};

/// Decodes the `train` group (unknown keys are an error). `seed` is left 0.
TrainerOptions DecodeTrainerOptions(const ConfigNode& node);

/// What identifies a model for checkpoint compatibility, plus provenance.
struct ModelIdentity {
  /// A map `{model: ..., normalization: ...}` of resolved config nodes; a
  /// checkpoint whose stored identity differs is refused naming the key.
  ConfigNode model_config;
  std::vector<std::string> labels;  // L label names, id order
  std::string config_yaml;          // the composed run config (provenance)
};

/// One row of metrics.csv.
struct EpochMetrics {
  int epoch = 0;  // completed epochs (1-based)
  int64_t step = 0;
  double train_loss = 0;
  double val_loss = 0;
  double val_acc = 0;
  double val_f1 = 0;
  double val_acc_frame = 0;
  double val_f1_frame = 0;
  double lr = 0;
  double wall_s = 0;
  double frames_per_s = 0;
  /// Validation per sampled layout (a layout-sampled stream; empty
  /// otherwise), in SlotTable::layouts order: layout_metrics.csv.
  struct Layout {
    std::string name;    // "cmu41", "random" (the pool), ...
    int64_t frames = 0;  // validation frames of that layout
    int64_t pairs = 0;   // scored (point, label) pairs, as val_acc
    int64_t correct = 0;
    double accuracy() const {
      return pairs > 0 ? static_cast<double>(correct) / pairs : 0.0;
    }
  };
  std::vector<Layout> layouts;
};

/// layout_metrics.csv of a history: `epoch,layout,frames,pairs,correct,
/// accuracy`, one line per epoch and sampled layout (only the header when
/// no epoch has layouts).
std::string LayoutMetricsCsv(const std::vector<EpochMetrics>& history);
/// Fills the `layouts` of `history`'s epochs from LayoutMetricsCsv text
/// (rows of epochs not in `history` are ignored). IoError naming `source`
/// for a malformed row.
void ParseLayoutMetricsCsv(const std::string& csv,
                           const std::string& source,
                           std::vector<EpochMetrics>* history);

/// The metrics.csv header line (without newline).
std::string MetricsCsvHeader();
/// One metrics.csv line (without newline).
std::string MetricsCsvRow(const EpochMetrics& m);

/// How a Train() call ended.
struct TrainSummary {
  enum class Termination {
    kMaxEpochs,       // max_epochs reached
    kEarlyStopping,   // val_loss stopped improving (or was non-finite)
    kNonFiniteLoss,   // NaN guard: a training loss was not finite
    kAlreadyFinished  // resumed a run that had already finished
  };
  Termination termination = Termination::kMaxEpochs;
  std::string message;
  int start_epoch = 0;  // completed epochs when Train() started (resume)
  int epochs_completed = 0;
  int best_epoch = 0;  // 1-based epoch of the best val_loss (best.pt)
  double best_val_loss = 0;
  std::vector<EpochMetrics> history;  // all epochs, including resumed ones
  double wall_s = 0;                  // this call

  /// The last row (zeros if none).
  EpochMetrics last() const {
    return history.empty() ? EpochMetrics{} : history.back();
  }
  std::string BriefReport() const;
};

std::string ToString(TrainSummary::Termination termination);

/// The stored metadata of a checkpoint.
struct CheckpointInfo {
  int epoch = 0;  // completed epochs
  int64_t step = 0;
  double lr = 0;
  ConfigNode model_config;  // {model, normalization}
  std::vector<std::string> labels;
  std::string config_yaml;
  std::string metrics_csv;
  bool finished = false;
};

/// Reads a checkpoint's metadata; IoError if unreadable.
CheckpointInfo ReadCheckpointInfo(const std::filesystem::path& path);

/// Throws ConfigError if `info` (from `path`) does not match `identity`,
/// naming the first differing key (`model.d_model: 16 in the checkpoint, 32
/// in the config`) or label. A key added to the model config after
/// checkpoints were first written (`model.label_encoder.fourier_bands`)
/// reads, where absent on either side, as the value every earlier model had.
void CheckCompatible(const CheckpointInfo& info,
                     const ModelIdentity& identity,
                     const std::filesystem::path& path);

/// Loads the weights (parameters and buffers) of a checkpoint into `model`
/// after CheckCompatible (fine-tuning, TrainerOptions::init_from). A
/// layout-conditioned `model` (model=soma_any_layout) may start from a
/// checkpoint of another layout or layout sampler: only the network's
/// config is compared (not `layout_sampler`, not the label names), and the
/// model keeps its own layout (`layout_descriptors`, the label slots of this
/// run).
void LoadCheckpointWeights(const std::filesystem::path& path,
                           const ModelIdentity& identity,
                           LabelerImpl& model);

/// A labeler rebuilt from a checkpoint's stored model config and labels,
/// with its weights, in eval mode.
Labeler LoadLabelerFromCheckpoint(const std::filesystem::path& path);

class Trainer {
 public:
  /// Called after every training batch (tests use it to inject crashes).
  struct BatchEvent {
    int epoch = 0;  // 1-based
    int batch = 0;  // 1-based within the epoch
    int64_t step = 0;
    double loss = 0;
  };
  struct Callbacks {
    std::function<void(const BatchEvent&)> on_batch_end;
    std::function<void(const EpochMetrics&)> on_epoch_end;
  };

  /// `model` is trained in place; the optimizer is built from
  /// `optimizer` on its parameters. Outputs go to `run_dir` (created).
  Trainer(TrainerOptions options,
          Labeler model,
          std::shared_ptr<const LabelingLoss> loss,
          const OptimizerSpec& optimizer,
          std::unique_ptr<LrScheduler> scheduler,
          ModelIdentity identity,
          std::filesystem::path run_dir);
  ~Trainer();

  void set_callbacks(Callbacks callbacks) { callbacks_ = std::move(callbacks); }

  /// Trains until max_epochs, early stopping or a non-finite loss. Resumes
  /// or fine-tunes per options. The sources' labels must equal the
  /// identity's labels. Exceptions (I/O, a callback) propagate; the last
  /// completed epoch's checkpoint stays valid.
  TrainSummary Train(const BatchSource& train, const BatchSource& val);

  const Labeler& model() const { return model_; }
  /// The engine the steps run on: "fast" or "torch" (after a fallback).
  std::string engine() const { return fast_ != nullptr ? "fast" : "torch"; }
  torch::optim::Optimizer& optimizer() { return *optimizer_; }
  std::filesystem::path last_checkpoint() const;
  std::filesystem::path best_checkpoint() const;
  std::filesystem::path metrics_path() const;
  /// layout_metrics.csv (written when validation has sampled layouts).
  std::filesystem::path layout_metrics_path() const;

 private:
  struct State;
  void Resume(const std::filesystem::path& path, State* state);
  void SaveCheckpoints(const State& state, bool is_best);
  EpochMetrics Validate(const BatchSource& val, EpochMetrics row);

  TrainerOptions options_;
  Labeler model_;
  std::shared_ptr<const LabelingLoss> loss_;
  std::unique_ptr<torch::optim::Optimizer> optimizer_;
  std::unique_ptr<LrScheduler> scheduler_;
  EarlyStopping early_stopping_;
  ModelIdentity identity_;
  std::filesystem::path run_dir_;
  Callbacks callbacks_;
  std::unique_ptr<FastTrainer> fast_;       // null: the torch engine
  std::unique_ptr<WeightAverage> average_;  // null: ema_decay = 0
};

/// Registers the optimizers, schedulers and the `train` config group.
void RegisterTrainerConfigGroup();

}  // namespace soma
