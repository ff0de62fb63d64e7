#include "framework/train/trainer.h"

#include "framework/config/decode.h"
#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/logging.h"
#include "framework/core/progress.h"
#include "framework/core/random.h"
#include "framework/core/timer.h"
#include "framework/model/fast_labeler.h"
#include "framework/model/fast_train.h"
#include "framework/model/inference.h"
#include "framework/model/loss.h"
#include "framework/registry/registry.h"
#include "framework/train/batch_source.h"
#include "framework/train/metrics.h"
#include "framework/train/optimizer.h"
#include "framework/train/weight_average.h"

#include <ATen/CPUGeneratorImpl.h>
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <mutex>
#include <sstream>
#include <string_view>
#include <unistd.h>

namespace soma {
namespace {

constexpr std::string_view kCheckpointFormat = "soma-checkpoint";
constexpr int64_t kCheckpointVersion = 1;

std::string JoinLines(const std::vector<std::string>& items) {
  std::string out;
  for (const std::string& item : items) {
    out += item;
    out += '\n';
  }
  return out;
}

std::vector<std::string> SplitLines(const std::string& text) {
  std::vector<std::string> out;
  size_t pos = 0;
  while (pos < text.size()) {
    size_t end = text.find('\n', pos);
    if (end == std::string::npos) end = text.size();
    out.push_back(text.substr(pos, end - pos));
    pos = end + 1;
  }
  return out;
}

std::string ReadString(torch::serialize::InputArchive& archive,
                       const std::string& key,
                       const std::filesystem::path& path) {
  c10::IValue value;
  if (!archive.try_read(key, value) || !value.isString()) {
    throw IoError(fmt::format(
        "{}: not a soma checkpoint (missing '{}')", path.string(), key));
  }
  return value.toStringRef();
}

int64_t ReadInt(torch::serialize::InputArchive& archive,
                const std::string& key,
                const std::filesystem::path& path) {
  c10::IValue value;
  if (!archive.try_read(key, value) || !value.isInt()) {
    throw IoError(fmt::format(
        "{}: not a soma checkpoint (missing '{}')", path.string(), key));
  }
  return value.toInt();
}

double ReadDouble(torch::serialize::InputArchive& archive,
                  const std::string& key,
                  const std::filesystem::path& path) {
  c10::IValue value;
  if (!archive.try_read(key, value) || !value.isDouble()) {
    throw IoError(fmt::format(
        "{}: not a soma checkpoint (missing '{}')", path.string(), key));
  }
  return value.toDouble();
}

torch::serialize::InputArchive OpenCheckpoint(
    const std::filesystem::path& path) {
  if (!std::filesystem::is_regular_file(path)) {
    throw IoError(fmt::format("checkpoint {} does not exist", path.string()));
  }
  torch::serialize::InputArchive archive;
  try {
    archive.load_from(path.string());
  } catch (const c10::Error& e) {
    throw IoError(fmt::format("{}: cannot read checkpoint ({})",
                              path.string(),
                              e.what_without_backtrace()));
  }
  if (ReadString(archive, "meta_format", path) != kCheckpointFormat) {
    throw IoError(fmt::format("{}: not a soma checkpoint", path.string()));
  }
  const int64_t version = ReadInt(archive, "meta_version", path);
  if (version != kCheckpointVersion) {
    throw IoError(fmt::format("{}: checkpoint version {} (expected {})",
                              path.string(),
                              version,
                              kCheckpointVersion));
  }
  return archive;
}

/// A model-config key added after checkpoints were first written, and the
/// value every model before it had.
struct AddedModelKey {
  std::string_view parent;  // dotted path in CheckpointInfo::model_config
  std::string_view key;
  int64_t value;
};

/// CheckCompatible fills them into both model configs where absent, so that
/// fine-tuning and resuming accept a checkpoint written before the key
/// existed whose model is the configured one.
constexpr AddedModelKey kAddedModelKeys[] = {
    {"model.label_encoder", "fourier_bands", 0},  // issue #25, 1917811
    {"model.label_encoder", "relative_bias", 0},  // issue #25
};

void FillAddedModelKeys(ConfigNode* model_config) {
  for (const AddedModelKey& added : kAddedModelKeys) {
    ConfigNode* parent = model_config->FindPath(added.parent);
    if (parent == nullptr || !parent->IsMap() ||
        parent->Find(added.key) != nullptr) {
      continue;
    }
    parent->Set(added.key, ConfigNode(added.value));
  }
}

CheckpointInfo ReadInfo(torch::serialize::InputArchive& archive,
                        const std::filesystem::path& path) {
  CheckpointInfo info;
  info.epoch = static_cast<int>(ReadInt(archive, "meta_epoch", path));
  info.step = ReadInt(archive, "meta_step", path);
  info.lr = ReadDouble(archive, "meta_lr", path);
  info.model_config = ParseYaml(ReadString(archive, "meta_model_config", path),
                                path.string() + ":model_config");
  info.labels = SplitLines(ReadString(archive, "meta_labels", path));
  info.config_yaml = ReadString(archive, "meta_config", path);
  info.metrics_csv = ReadString(archive, "meta_metrics_csv", path);
  info.finished = ReadInt(archive, "meta_finished", path) != 0;
  return info;
}

/// The first key path where `a` (checkpoint) and `b` (config) differ; ""
/// if equal. `*va`, `*vb` describe the two values.
std::string FirstDifference(const ConfigNode& a,
                            const ConfigNode& b,
                            const std::string& path,
                            std::string* va,
                            std::string* vb) {
  auto child_path = [&](const std::string& key) {
    return path.empty() ? key : path + "." + key;
  };
  if (a.IsMap() && b.IsMap()) {
    for (const auto& [key, child] : a.entries()) {
      const ConfigNode* other = b.Find(key);
      if (other == nullptr) {
        *va = child.Describe();
        *vb = "<absent>";
        return child_path(key);
      }
      std::string diff =
          FirstDifference(child, *other, child_path(key), va, vb);
      if (!diff.empty()) return diff;
    }
    for (const auto& [key, child] : b.entries()) {
      if (a.Find(key) == nullptr) {
        *va = "<absent>";
        *vb = child.Describe();
        return child_path(key);
      }
    }
    return "";
  }
  if (a.IsList() && b.IsList() && a.size() == b.size()) {
    for (size_t i = 0; i < a.size(); ++i) {
      std::string diff = FirstDifference(
          a.at(i), b.at(i), fmt::format("{}[{}]", path, i), va, vb);
      if (!diff.empty()) return diff;
    }
    return "";
  }
  if (a.IsScalar() && b.IsScalar() && DumpFlow(a) == DumpFlow(b)) return "";
  *va = a.Describe();
  *vb = b.Describe();
  return path.empty() ? "<root>" : path;
}

struct Tensors {
  torch::Tensor points;  // B x N x 3 float
  torch::Tensor labels;  // B x N int64
  /// Frames with label slots (a layout-sampled source): B x S x Q
  /// descriptors gathered from the source's SlotTable, B x S mask.
  bool has_slots = false;
  LabelSlots slots;
};

Tensors ToTensors(const LabeledFrames& frames,
                  const SlotTable* table = nullptr) {
  const int64_t b = frames.num_frames();
  const int64_t n = frames.num_points;
  Tensors t;
  t.points =
      torch::from_blob(
          const_cast<float*>(frames.points.data()), {b, n, 3}, torch::kFloat)
          .clone();
  t.labels =
      torch::from_blob(
          const_cast<int16_t*>(frames.labels.data()), {b, n}, torch::kShort)
          .to(torch::kLong);
  if (frames.num_slots > 0) {
    if (table == nullptr) {
      throw InternalError(
          "Trainer: the frames carry label slots but their source has no "
          "slot table");
    }
    t.has_slots = true;
    t.slots = GatherLabelSlots(frames, *table);
  }
  return t;
}

/// The model's forward on a batch: with the batch's label slots when it
/// carries them.
LabelerOutput ForwardBatch(Labeler& model, const Tensors& t) {
  return t.has_slots ? model->ForwardSlots(t.points, t.slots)
                     : model->forward(t.points);
}

/// The loss targets of a batch; a padded slot's column (always "not
/// available", its mass sent to the dustbin) does not enter the loss.
AugmentedTargets BatchTargets(const Tensors& t, int64_t num_labels) {
  AugmentedTargets targets = BuildAugmentedTargets(t.labels, num_labels);
  if (t.has_slots) {
    const torch::Tensor columns =
        torch::cat({t.slots.mask.to(torch::kFloat),
                    torch::ones({t.labels.size(0), 1})},
                   1)
            .unsqueeze(1);  // B x 1 x L+1
    targets.weights = (targets.weights * columns).contiguous();
  }
  return targets;
}

/// Adds each frame's scored pairs (those with valid[i], as in
/// train/metrics.h) to its layout's entry (one per SlotTable::layouts); a
/// frame's layout is that of its first slot's row.
void AddLayoutCounts(const LabeledFrames& frames,
                     const SlotTable& table,
                     const int64_t* gt,
                     const int64_t* pred,
                     const bool* valid,
                     std::vector<EpochMetrics::Layout>* counts) {
  const int64_t n = frames.num_points;
  for (int64_t f = 0; f < frames.num_frames(); ++f) {
    const int16_t* slots = frames.frame_slots(f);
    const int16_t* first = std::find_if(
        slots, slots + frames.num_slots, [](int16_t r) { return r >= 0; });
    if (first == slots + frames.num_slots) continue;
    EpochMetrics::Layout& c = (*counts)[static_cast<size_t>(
        table.row_layout[static_cast<size_t>(*first)])];
    for (int64_t i = f * n; i < (f + 1) * n; ++i) {
      if (!valid[i]) continue;
      ++c.pairs;
      c.correct += gt[i] == pred[i];
    }
    ++c.frames;
  }
}

// SIGUSR1 while training (SLURM's --signal=B:USR1 passed on by the launcher's
// wrapper, or `kill -USR1`): checkpoint at the next batch boundary, then
// die of the signal, like a kill, so that nothing records the run as ended.
volatile std::sig_atomic_t g_usr1_received = 0;

extern "C" void OnTrainUsr1(int) { g_usr1_received = 1; }

/// Installs the SIGUSR1 handler for the lifetime of the object.
class Usr1Guard {
 public:
  Usr1Guard() {
    g_usr1_received = 0;
    struct sigaction action {};
    action.sa_handler = OnTrainUsr1;
    sigemptyset(&action.sa_mask);
    action.sa_flags = SA_RESTART;
    installed_ = ::sigaction(SIGUSR1, &action, &previous_) == 0;
  }
  ~Usr1Guard() {
    if (installed_) ::sigaction(SIGUSR1, &previous_, nullptr);
  }
  Usr1Guard(const Usr1Guard&) = delete;
  Usr1Guard& operator=(const Usr1Guard&) = delete;
  bool received() const { return g_usr1_received != 0; }
  /// Restores the default action and dies of SIGUSR1 (exit status 138).
  [[noreturn]] void Die() {
    struct sigaction action {};
    action.sa_handler = SIG_DFL;
    sigemptyset(&action.sa_mask);
    ::sigaction(SIGUSR1, &action, nullptr);
    std::fflush(nullptr);
    ::raise(SIGUSR1);
    ::_exit(128 + SIGUSR1);  // not reached
  }

 private:
  struct sigaction previous_ {};
  bool installed_ = false;
};

std::string CsvDouble(double value) { return fmt::format("{}", value); }

std::vector<BatchRequest> PlanBatches(int epoch,
                                      int64_t num_batches,
                                      int64_t batch_size) {
  std::vector<BatchRequest> requests;
  requests.reserve(static_cast<size_t>(num_batches));
  for (int64_t b = 0; b < num_batches; ++b) {
    requests.push_back(BatchRequest{epoch, b * batch_size, batch_size});
  }
  return requests;
}

std::vector<EpochMetrics> ParseMetricsCsv(const std::string& csv) {
  std::vector<EpochMetrics> rows;
  const std::vector<std::string> lines = SplitLines(csv);
  for (size_t i = 1; i < lines.size(); ++i) {  // skip the header
    if (lines[i].empty()) continue;
    std::vector<double> v;
    std::stringstream stream(lines[i]);
    std::string cell;
    while (std::getline(stream, cell, ',')) {
      v.push_back(std::strtod(cell.c_str(), nullptr));
    }
    if (v.size() != 11) {
      throw IoError(fmt::format(
          "checkpoint metrics row '{}' has {} columns", lines[i], v.size()));
    }
    EpochMetrics m;
    m.epoch = static_cast<int>(v[0]);
    m.step = static_cast<int64_t>(v[1]);
    m.train_loss = v[2];
    m.val_loss = v[3];
    m.val_acc = v[4];
    m.val_f1 = v[5];
    m.val_acc_frame = v[6];
    m.val_f1_frame = v[7];
    m.lr = v[8];
    m.wall_s = v[9];
    m.frames_per_s = v[10];
    rows.push_back(m);
  }
  return rows;
}

std::string MetricsCsv(const std::vector<EpochMetrics>& history) {
  std::string csv = MetricsCsvHeader() + "\n";
  for (const EpochMetrics& m : history) csv += MetricsCsvRow(m) + "\n";
  return csv;
}

}  // namespace

// ---------------------------------------------------------------------------
// Options

void TrainerOptions::Validate() const {
  auto fail = [](std::string_view key, auto value, std::string_view what) {
    throw ConfigError(fmt::format(
        "Invalid configuration. train.{} = {}. Violated constraint: {}",
        key,
        value,
        what));
  };
  if (batch_size < 1) fail("batch_size", batch_size, "batch_size >= 1");
  if (val_batch_size < 0) {
    fail("val_batch_size", val_batch_size, "val_batch_size >= 0");
  }
  if (max_epochs < 0) fail("max_epochs", max_epochs, "max_epochs >= 0");
  if (train_frames < 1) fail("train_frames", train_frames, "train_frames >= 1");
  if (val_frames < 1) fail("val_frames", val_frames, "val_frames >= 1");
  if (synth_data != "pool" && synth_data != "stream") {
    fail("synth_data", synth_data, "synth_data is pool or stream");
  }
  if (data_threads < 1) fail("data_threads", data_threads, "data_threads >= 1");
  if (prefetch < 0) fail("prefetch", prefetch, "prefetch >= 0");
  if (engine != "fast" && engine != "torch") {
    fail("engine", engine, "engine is fast or torch");
  }
  if (precision != "fp32" && precision != "bf16") {
    fail("precision", precision, "precision is fp32 or bf16");
  }
  if (!(gradient_clip_val >= 0)) {
    fail("gradient_clip_val", gradient_clip_val, "gradient_clip_val >= 0");
  }
  if (!(ema_decay >= 0 && ema_decay < 1)) {
    fail("ema_decay", ema_decay, "0 <= ema_decay < 1 (0 = off)");
  }
  early_stopping.Validate();
}

TrainerOptions DecodeTrainerOptions(const ConfigNode& node) {
  ConfigReader reader(node);
  TrainerOptions options;
  reader.Read("batch_size", &options.batch_size);
  reader.Read("val_batch_size", &options.val_batch_size);
  reader.Read("max_epochs", &options.max_epochs);
  reader.Read("train_frames", &options.train_frames);
  reader.Read("val_frames", &options.val_frames);
  reader.Read("synth_data", &options.synth_data);
  reader.Read("data_threads", &options.data_threads);
  reader.Read("prefetch", &options.prefetch);
  reader.Read("progress", &options.progress);
  reader.Read("engine", &options.engine);
  reader.Read("precision", &options.precision);
  reader.Read("gradient_clip_val", &options.gradient_clip_val);
  reader.Read("ema_decay", &options.ema_decay);
  if (const ConfigNode* resume = reader.Child("resume");
      resume != nullptr && !resume->IsNull()) {
    if (resume->IsBool()) {
      options.resume = resume->AsBool() ? "auto" : "never";
    } else {
      options.resume = resume->AsString();
    }
  }
  if (const ConfigNode* init = reader.Child("init_from");
      init != nullptr && !init->IsNull()) {
    options.init_from = init->AsString();
  }
  if (const ConfigNode* es = reader.Child("early_stopping"); es != nullptr) {
    options.early_stopping = DecodeEarlyStoppingOptions(*es);
  }
  reader.Check("batch_size", options.batch_size >= 1, "batch_size >= 1");
  reader.Check(
      "val_batch_size", options.val_batch_size >= 0, "val_batch_size >= 0");
  reader.Check("max_epochs", options.max_epochs >= 0, "max_epochs >= 0");
  reader.Check("train_frames", options.train_frames >= 1, "train_frames >= 1");
  reader.Check("val_frames", options.val_frames >= 1, "val_frames >= 1");
  reader.Check("synth_data",
               options.synth_data == "pool" || options.synth_data == "stream",
               "synth_data is pool or stream");
  reader.Check("data_threads", options.data_threads >= 1, "data_threads >= 1");
  reader.Check("prefetch", options.prefetch >= 0, "prefetch >= 0");
  reader.Check("engine",
               options.engine == "fast" || options.engine == "torch",
               "engine is fast or torch");
  reader.Check("precision",
               options.precision == "fp32" || options.precision == "bf16",
               "precision is fp32 or bf16");
  reader.Check("gradient_clip_val",
               options.gradient_clip_val >= 0,
               "gradient_clip_val >= 0");
  reader.Check("ema_decay",
               options.ema_decay >= 0 && options.ema_decay < 1,
               "0 <= ema_decay < 1 (0 = off)");
  reader.Finish();
  return options;
}

void RegisterTrainerConfigGroup() {
  RegisterConfigGroup(
      "train", "trainer", [](const ConfigNode& node, BuildContext&) {
        DecodeTrainerOptions(node).Validate();
      });
}

// ---------------------------------------------------------------------------
// Metrics and summary

std::string LayoutMetricsCsv(const std::vector<EpochMetrics>& history) {
  std::string csv = "epoch,layout,frames,pairs,correct,accuracy\n";
  for (const EpochMetrics& m : history) {
    for (const EpochMetrics::Layout& l : m.layouts) {
      std::string name = l.name;  // a layout file's path may hold commas
      std::replace(name.begin(), name.end(), ',', ';');
      csv += fmt::format("{},{},{},{},{},{}\n",
                         m.epoch,
                         name,
                         l.frames,
                         l.pairs,
                         l.correct,
                         CsvDouble(l.accuracy()));
    }
  }
  return csv;
}

void ParseLayoutMetricsCsv(const std::string& csv,
                           const std::string& source,
                           std::vector<EpochMetrics>* history) {
  const std::vector<std::string> lines = SplitLines(csv);
  for (size_t i = 1; i < lines.size(); ++i) {  // skip the header
    if (lines[i].empty()) continue;
    std::vector<std::string> cells;
    std::stringstream stream(lines[i]);
    std::string cell;
    while (std::getline(stream, cell, ',')) cells.push_back(cell);
    if (cells.size() != 6) {
      throw IoError(
          fmt::format("{}: layout metrics row '{}' has {} columns, "
                      "expected 6",
                      source,
                      lines[i],
                      cells.size()));
    }
    const int epoch = std::atoi(cells[0].c_str());
    for (EpochMetrics& m : *history) {
      if (m.epoch != epoch) continue;
      EpochMetrics::Layout layout;
      layout.name = cells[1];
      layout.frames = std::strtoll(cells[2].c_str(), nullptr, 10);
      layout.pairs = std::strtoll(cells[3].c_str(), nullptr, 10);
      layout.correct = std::strtoll(cells[4].c_str(), nullptr, 10);
      m.layouts.push_back(std::move(layout));
    }
  }
}

std::string MetricsCsvHeader() {
  return "epoch,step,train_loss,val_loss,val_acc,val_f1,val_acc_frame,"
         "val_f1_frame,lr,wall_s,frames_per_s";
}

std::string MetricsCsvRow(const EpochMetrics& m) {
  return fmt::format("{},{},{},{},{},{},{},{},{},{:.3f},{:.1f}",
                     m.epoch,
                     m.step,
                     CsvDouble(m.train_loss),
                     CsvDouble(m.val_loss),
                     CsvDouble(m.val_acc),
                     CsvDouble(m.val_f1),
                     CsvDouble(m.val_acc_frame),
                     CsvDouble(m.val_f1_frame),
                     CsvDouble(m.lr),
                     m.wall_s,
                     m.frames_per_s);
}

std::string ToString(TrainSummary::Termination termination) {
  switch (termination) {
    case TrainSummary::Termination::kMaxEpochs:
      return "max_epochs";
    case TrainSummary::Termination::kEarlyStopping:
      return "early_stopping";
    case TrainSummary::Termination::kNonFiniteLoss:
      return "non_finite_loss";
    case TrainSummary::Termination::kAlreadyFinished:
      return "already_finished";
  }
  return "unknown";
}

std::string TrainSummary::BriefReport() const {
  const EpochMetrics m = last();
  return fmt::format(
      "training ended ({}): {} epochs, best val_loss {:.6g} at epoch {}; "
      "last val_acc {:.4f}, val_f1 {:.4f}; {}",
      ToString(termination),
      epochs_completed,
      best_val_loss,
      best_epoch,
      m.val_acc,
      m.val_f1,
      message);
}

// ---------------------------------------------------------------------------
// Checkpoints

CheckpointInfo ReadCheckpointInfo(const std::filesystem::path& path) {
  torch::serialize::InputArchive archive = OpenCheckpoint(path);
  return ReadInfo(archive, path);
}

void CheckCompatible(const CheckpointInfo& info,
                     const ModelIdentity& identity,
                     const std::filesystem::path& path) {
  ConfigNode checkpoint_config = info.model_config;
  ConfigNode config = identity.model_config;
  FillAddedModelKeys(&checkpoint_config);
  FillAddedModelKeys(&config);
  std::string va, vb;
  const std::string diff =
      FirstDifference(checkpoint_config, config, "", &va, &vb);
  if (!diff.empty()) {
    throw ConfigError(fmt::format(
        "Checkpoint {} does not match the model: {} = {} in the checkpoint, "
        "{} in the config",
        path.string(),
        diff,
        va,
        vb));
  }
  if (info.labels != identity.labels) {
    size_t i = 0;
    while (i < info.labels.size() && i < identity.labels.size() &&
           info.labels[i] == identity.labels[i]) {
      ++i;
    }
    throw ConfigError(fmt::format(
        "Checkpoint {} does not match the model: labels differ ({} labels "
        "in the checkpoint, {} in the config; first difference at id {}: "
        "'{}' vs '{}')",
        path.string(),
        info.labels.size(),
        identity.labels.size(),
        i,
        i < info.labels.size() ? info.labels[i] : "<none>",
        i < identity.labels.size() ? identity.labels[i] : "<none>"));
  }
}

namespace {

// Loads the weights stored under `key` ("model": the model to use, the
// weight average when training averaged; "train_model": the trained weights
// of such a run).
void LoadModelArchive(torch::serialize::InputArchive& archive,
                      const std::filesystem::path& path,
                      LabelerImpl& model,
                      const std::string& key = "model") {
  torch::serialize::InputArchive model_archive;
  if (!archive.try_read(key, model_archive)) {
    throw IoError(fmt::format("{}: checkpoint has no {}", path.string(), key));
  }
  // Module::load would silently resize a parameter of another shape; the
  // identity check normally prevents that, this catches the rest.
  std::vector<std::vector<int64_t>> shapes;
  for (const torch::Tensor& p : model.parameters()) {
    shapes.push_back(p.sizes().vec());
  }
  torch::NoGradGuard no_grad;
  try {
    model.load(model_archive);
  } catch (const c10::Error& e) {
    throw IoError(fmt::format("{}: cannot load the model weights ({})",
                              path.string(),
                              e.what_without_backtrace()));
  }
  size_t i = 0;
  for (const auto& p : model.named_parameters()) {
    if (p.value().sizes().vec() != shapes[i++]) {
      throw ConfigError(fmt::format(
          "Checkpoint {} does not match the model: parameter {} has shape {} "
          "in the checkpoint, {} in the model",
          path.string(),
          p.key(),
          fmt::join(p.value().sizes().vec(), "x"),
          fmt::join(shapes[i - 1], "x")));
    }
  }
}

}  // namespace

void LoadCheckpointWeights(const std::filesystem::path& path,
                           const ModelIdentity& identity,
                           LabelerImpl& model) {
  torch::serialize::InputArchive archive = OpenCheckpoint(path);
  const CheckpointInfo info = ReadInfo(archive, path);
  if (!model.conditioned()) {
    CheckCompatible(info, identity, path);
    LoadModelArchive(archive, path, model);
    return;
  }
  // A layout-conditioned model's weights hold no layout: its labels are an
  // input. Fine-tuning it on another layout (or sampler) compares the
  // network's config only, and keeps this run's label slots.
  CheckpointInfo network = info;
  ModelIdentity run = identity;
  for (ConfigNode* config : {&network.model_config, &run.model_config}) {
    if (config->IsMap()) config->Erase("layout_sampler");
  }
  network.labels.clear();
  run.labels.clear();
  CheckCompatible(network, run, path);
  const torch::Tensor layout = model.layout_descriptors.clone();
  LoadModelArchive(archive, path, model);
  torch::NoGradGuard no_grad;
  model.layout_descriptors.set_(layout);
}

Labeler LoadLabelerFromCheckpoint(const std::filesystem::path& path) {
  torch::serialize::InputArchive archive = OpenCheckpoint(path);
  const CheckpointInfo info = ReadInfo(archive, path);
  const ConfigNode* model_node = info.model_config.Find("model");
  const ConfigNode* norm_node = info.model_config.Find("normalization");
  if (model_node == nullptr || norm_node == nullptr) {
    throw IoError(
        fmt::format("{}: checkpoint model config lacks model/normalization",
                    path.string()));
  }
  Labeler model = BuildLabeler(
      *model_node, *norm_node, static_cast<int64_t>(info.labels.size()));
  LoadModelArchive(archive, path, *model);
  model->eval();
  return model;
}

// ---------------------------------------------------------------------------
// Trainer

struct Trainer::State {
  int epoch = 0;  // completed epochs
  int64_t step = 0;
  double lr = 0;
  double best_val_loss = std::numeric_limits<double>::infinity();
  int best_epoch = 0;
  bool finished = false;
  std::string finish_reason;
  std::vector<EpochMetrics> history;
  // A checkpoint written in the middle of an epoch (on SIGUSR1): the batches
  // of epoch `epoch` + 1 already trained, their summed loss and training
  // time. 0 at an epoch's end.
  int64_t batch = 0;
  double epoch_loss_sum = 0;
  double epoch_train_s = 0;
};

Trainer::Trainer(TrainerOptions options,
                 Labeler model,
                 std::shared_ptr<const LabelingLoss> loss,
                 const OptimizerSpec& optimizer,
                 std::unique_ptr<LrScheduler> scheduler,
                 ModelIdentity identity,
                 std::filesystem::path run_dir)
    : options_(std::move(options)),
      model_(std::move(model)),
      loss_(std::move(loss)),
      optimizer_(optimizer.Build(model_->parameters())),
      scheduler_(std::move(scheduler)),
      early_stopping_(options_.early_stopping),
      identity_(std::move(identity)),
      run_dir_(std::move(run_dir)) {
  options_.Validate();
  SOMA_CHECK(loss_ != nullptr);
  if (scheduler_ == nullptr) scheduler_ = std::make_unique<ConstantLr>();
  SOMA_CHECK_EQ(static_cast<int64_t>(identity_.labels.size()),
                model_->num_labels());
  CreateDirectories(run_dir_ / "checkpoints");
  if (options_.engine == "fast") {
    std::string why_not;
    FastTrainerOptions fast_options;
    if (options_.precision == "bf16") {
      if (internal::DefaultBf16Backend() != internal::Bf16Backend::kNone) {
        fast_options.bf16 = true;
      } else {
        SOMA_LOG(WARNING,
                 "train: precision=bf16 needs AVX512_BF16 or AMX-BF16, which "
                 "this CPU (or kernel) does not provide; training in fp32");
      }
    }
    fast_ = FastTrainer::Create(*model_, *loss_, fast_options, &why_not);
    if (fast_ == nullptr) {
      SOMA_LOG(WARNING,
               "train: engine=fast cannot train this model ({}); using the "
               "torch engine",
               why_not);
    }
  }
  if (fast_ == nullptr && options_.precision == "bf16") {
    SOMA_LOG(WARNING,
             "train: precision=bf16 applies to the fast engine only; the torch "
             "engine trains in fp32");
  }
  if (options_.ema_decay > 0) {
    average_ = std::make_unique<WeightAverage>(
        WeightAverage::WeightsOf(*model_), options_.ema_decay);
  }
}

Trainer::~Trainer() = default;

std::filesystem::path Trainer::last_checkpoint() const {
  return run_dir_ / "checkpoints" / "last.pt";
}
std::filesystem::path Trainer::best_checkpoint() const {
  return run_dir_ / "checkpoints" / "best.pt";
}
std::filesystem::path Trainer::metrics_path() const {
  return run_dir_ / "metrics.csv";
}
std::filesystem::path Trainer::layout_metrics_path() const {
  return run_dir_ / "layout_metrics.csv";
}

void Trainer::Resume(const std::filesystem::path& path, State* state) {
  torch::serialize::InputArchive archive = OpenCheckpoint(path);
  const CheckpointInfo info = ReadInfo(archive, path);
  CheckCompatible(info, identity_, path);
  LoadModelArchive(archive, path, *model_);
  // A run with a weight average stores it as `model` and the weights it
  // trains as `train_model`.
  torch::serialize::InputArchive trained;
  if (archive.try_read("train_model", trained)) {
    if (average_ != nullptr) average_->Reset();
    LoadModelArchive(archive, path, *model_, "train_model");
    if (average_ == nullptr) {
      SOMA_LOG(WARNING,
               "train: {} holds a weight average but train.ema_decay is 0: "
               "continuing from its trained weights without one",
               path.string());
    }
  } else if (average_ != nullptr) {
    average_->Reset();
    SOMA_LOG(WARNING,
             "train: {} holds no weight average; the average "
             "(train.ema_decay={}) starts from its weights",
             path.string(),
             options_.ema_decay);
  }
  torch::serialize::InputArchive optimizer_archive;
  if (!archive.try_read("optimizer", optimizer_archive)) {
    throw IoError(
        fmt::format("{}: checkpoint has no optimizer state", path.string()));
  }
  optimizer_->load(optimizer_archive);
  scheduler_->LoadState(ReadString(archive, "meta_scheduler", path));
  early_stopping_.LoadState(ReadString(archive, "meta_early_stopping", path));
  torch::Tensor rng_state;
  if (archive.try_read("rng_torch", rng_state)) {
    at::Generator generator = at::detail::getDefaultCPUGenerator();
    std::lock_guard<std::mutex> lock(generator.mutex());
    generator.set_state(rng_state);
  }
  state->epoch = info.epoch;
  state->step = info.step;
  state->lr = info.lr;
  state->best_val_loss = ReadDouble(archive, "meta_best_val_loss", path);
  state->best_epoch =
      static_cast<int>(ReadInt(archive, "meta_best_epoch", path));
  state->finished = info.finished;
  state->finish_reason = ReadString(archive, "meta_finish_reason", path);
  state->history = ParseMetricsCsv(info.metrics_csv);
  if (c10::IValue layouts;
      archive.try_read("meta_layout_metrics_csv", layouts) &&
      layouts.isString()) {
    ParseLayoutMetricsCsv(
        layouts.toStringRef(), path.string(), &state->history);
  }
  // Mid-epoch keys (absent in checkpoints written at an epoch's end).
  c10::IValue value;
  state->batch = archive.try_read("meta_batch", value) && value.isInt()
                     ? value.toInt()
                     : 0;
  state->epoch_loss_sum =
      state->batch > 0 ? ReadDouble(archive, "meta_epoch_loss_sum", path) : 0;
  state->epoch_train_s =
      state->batch > 0 ? ReadDouble(archive, "meta_epoch_train_s", path) : 0;
  SetLearningRate(*optimizer_, state->lr);
}

void Trainer::SaveCheckpoints(const State& state, bool is_best) {
  torch::serialize::OutputArchive archive;
  torch::serialize::OutputArchive model_archive;
  if (average_ != nullptr) {
    average_->SaveAverage(*model_, &model_archive);
    torch::serialize::OutputArchive trained;
    model_->save(trained);
    archive.write("train_model", trained);
  } else {
    model_->save(model_archive);
  }
  archive.write("model", model_archive);
  torch::serialize::OutputArchive optimizer_archive;
  optimizer_->save(optimizer_archive);
  archive.write("optimizer", optimizer_archive);
  archive.write("meta_format", c10::IValue(std::string(kCheckpointFormat)));
  archive.write("meta_version", c10::IValue(kCheckpointVersion));
  archive.write("meta_epoch", c10::IValue(static_cast<int64_t>(state.epoch)));
  archive.write("meta_step", c10::IValue(state.step));
  archive.write("meta_lr", c10::IValue(state.lr));
  archive.write("meta_best_val_loss", c10::IValue(state.best_val_loss));
  archive.write("meta_best_epoch",
                c10::IValue(static_cast<int64_t>(state.best_epoch)));
  archive.write("meta_finished",
                c10::IValue(static_cast<int64_t>(state.finished ? 1 : 0)));
  archive.write("meta_finish_reason", c10::IValue(state.finish_reason));
  archive.write("meta_model_config",
                c10::IValue(DumpYaml(identity_.model_config)));
  archive.write("meta_labels", c10::IValue(JoinLines(identity_.labels)));
  archive.write("meta_config", c10::IValue(identity_.config_yaml));
  archive.write("meta_metrics_csv", c10::IValue(MetricsCsv(state.history)));
  if (!state.history.empty() && !state.history.back().layouts.empty()) {
    archive.write("meta_layout_metrics_csv",
                  c10::IValue(LayoutMetricsCsv(state.history)));
  }
  archive.write("meta_scheduler", c10::IValue(scheduler_->SaveState()));
  archive.write("meta_early_stopping",
                c10::IValue(early_stopping_.SaveState()));
  if (state.batch > 0) {
    archive.write("meta_batch", c10::IValue(state.batch));
    archive.write("meta_epoch_loss_sum", c10::IValue(state.epoch_loss_sum));
    archive.write("meta_epoch_train_s", c10::IValue(state.epoch_train_s));
  }
  {
    at::Generator generator = at::detail::getDefaultCPUGenerator();
    std::lock_guard<std::mutex> lock(generator.mutex());
    archive.write("rng_torch", generator.get_state());
  }
  std::ostringstream bytes;
  archive.save_to(bytes);
  const std::string data = bytes.str();
  if (is_best) WriteFileAtomic(best_checkpoint(), data);
  WriteFileAtomic(last_checkpoint(), data);
}

EpochMetrics Trainer::Validate(const BatchSource& val, EpochMetrics row) {
  const int64_t total = val.frames_per_epoch();
  int64_t batch = options_.val_batch_size > 0 ? options_.val_batch_size
                                              : options_.batch_size;
  batch = std::min(batch, total);
  const int64_t num_batches = total / batch;  // drop_last, as released
  const int64_t num_labels = model_->num_labels();
  LabelingMetrics metrics(static_cast<int>(num_labels));
  if (val.slot_table() != nullptr) {
    for (const std::string& name : val.slot_table()->layouts) {
      row.layouts.push_back({.name = name});
    }
  }
  double loss_sum = 0;
  int64_t loss_count = 0;
  model_->eval();
  {
    torch::NoGradGuard no_grad;
    const WeightAverage::Swapped averaged(average_.get());
    // The fast engine validates on the optimised inference forward (a
    // snapshot of this epoch's weights; matches the eval-mode torch forward
    // to ~1e-5).
    std::unique_ptr<FastLabeler> fast_eval;
    if (fast_ != nullptr && FastLabeler::Supports(*model_)) {
      fast_eval = std::make_unique<FastLabeler>(*model_);
    }
    Prefetcher prefetcher(
        val, PlanBatches(0, num_batches, batch), options_.prefetch);
    LabeledFrames frames;
    while (prefetcher.Next(&frames)) {
      const Tensors t = ToTensors(frames, val.slot_table());
      const LabelerOutput out = fast_eval != nullptr && !t.has_slots
                                    ? fast_eval->Forward(t.points)
                                    : ForwardBatch(model_, t);
      const double loss =
          loss_->Compute(out.log_assignment, BatchTargets(t, num_labels))
              .item<double>();
      if (!std::isnan(loss)) {
        loss_sum += loss;
        ++loss_count;
      }
      const torch::Tensor valid = t.points.ne(0).any(2).contiguous();
      const torch::Tensor predicted =
          ResolveDuplicateLabels(out.label_ids, valid, num_labels)
              .to(torch::kLong)
              .contiguous();
      metrics.AddBatch(t.labels.data_ptr<int64_t>(),
                       predicted.data_ptr<int64_t>(),
                       valid.data_ptr<bool>(),
                       t.labels.size(0),
                       t.labels.size(1));
      if (t.has_slots) {
        AddLayoutCounts(frames,
                        *val.slot_table(),
                        t.labels.data_ptr<int64_t>(),
                        predicted.data_ptr<int64_t>(),
                        valid.data_ptr<bool>(),
                        &row.layouts);
      }
    }
  }
  model_->train();
  if (!row.layouts.empty()) {
    std::vector<std::string> parts;
    for (const EpochMetrics::Layout& c : row.layouts) {
      parts.push_back(fmt::format(
          "{} {}",
          c.name,
          c.pairs > 0
              ? fmt::format("{:.4f} ({} frames)", c.accuracy(), c.frames)
              : std::string("- (no frames)")));
    }
    SOMA_LOG(INFO,
             "train: epoch {} validation accuracy per layout: {}",
             row.epoch,
             fmt::join(parts, ", "));
  }
  row.val_loss = loss_count > 0 ? loss_sum / static_cast<double>(loss_count)
                                : std::numeric_limits<double>::quiet_NaN();
  row.val_acc = metrics.batch_accuracy();
  row.val_f1 = metrics.batch_f1();
  row.val_acc_frame = metrics.frame_accuracy();
  row.val_f1_frame = metrics.frame_f1();
  return row;
}

TrainSummary Trainer::Train(const BatchSource& train, const BatchSource& val) {
  Timer total_timer;
  if (train.labels() != identity_.labels || val.labels() != identity_.labels) {
    throw ConfigError(fmt::format(
        "Trainer: the data's labels ({} train, {} val) differ from the "
        "model's {} labels",
        train.num_labels(),
        val.num_labels(),
        identity_.labels.size()));
  }
  if ((train.slot_table() != nullptr || val.slot_table() != nullptr) &&
      !model_->conditioned()) {
    throw ConfigError(
        "Trainer: the data has a layout per placement block "
        "(synth.layout_sampler) but the model has a fixed layout; use "
        "model=soma_any_layout");
  }
  if ((train.slot_table() == nullptr) != (val.slot_table() == nullptr)) {
    throw ConfigError(fmt::format(
        "Trainer: the {} data has a layout per placement block (label slots) "
        "and the {} data has not; give both sets the same kind of frames",
        train.slot_table() != nullptr ? "train" : "val",
        train.slot_table() != nullptr ? "val" : "train"));
  }
  const int64_t num_batches = train.frames_per_epoch() / options_.batch_size;
  if (num_batches < 1) {
    throw ConfigError(fmt::format(
        "Invalid configuration. train.batch_size = {}. Violated constraint: "
        "batch_size <= frames per epoch ({})",
        options_.batch_size,
        train.frames_per_epoch()));
  }

  State state;
  state.lr = GetLearningRate(*optimizer_);
  std::filesystem::path resume_path;
  if (options_.resume == "auto") {
    if (std::filesystem::exists(last_checkpoint())) {
      resume_path = last_checkpoint();
    }
  } else if (options_.resume != "never" && !options_.resume.empty()) {
    resume_path = options_.resume;
  }
  TrainSummary summary;
  if (!resume_path.empty()) {
    Resume(resume_path, &state);
    SOMA_LOG(INFO,
             "train: resumed from {} after epoch {}{} (step {}, lr {})",
             resume_path.string(),
             state.epoch,
             state.batch > 0 ? fmt::format(" and {} batches of epoch {}",
                                           state.batch,
                                           state.epoch + 1)
                             : std::string(),
             state.step,
             state.lr);
  } else if (!options_.init_from.empty()) {
    LoadCheckpointWeights(options_.init_from, identity_, *model_);
    SOMA_LOG(INFO, "train: weights initialised from {}", options_.init_from);
  }
  if (resume_path.empty() && average_ != nullptr) average_->Reset();
  summary.start_epoch = state.epoch;

  auto finish = [&](TrainSummary::Termination termination,
                    std::string message) {
    summary.termination = termination;
    summary.message = std::move(message);
    summary.epochs_completed = state.epoch;
    summary.best_epoch = state.best_epoch;
    summary.best_val_loss = state.best_val_loss;
    summary.history = state.history;
    summary.wall_s = total_timer.ElapsedSeconds();
    return summary;
  };
  if (state.finished) {
    return finish(
        TrainSummary::Termination::kAlreadyFinished,
        "the checkpoint's run had already finished: " + state.finish_reason);
  }

  const int64_t num_labels = model_->num_labels();
  const int64_t frames_per_epoch = num_batches * options_.batch_size;
  const int64_t total_steps = num_batches * options_.max_epochs;
  const int remaining = std::max(0, options_.max_epochs - state.epoch);
  ProgressBar progress(
      remaining * frames_per_epoch - state.batch * options_.batch_size,
      ProgressBar::Options{
          .label = "train", .unit = "frames", .enabled = options_.progress});
  const Rng torch_stream = Rng(options_.seed).Stream("torch");
  model_->train();
  std::string kernels;
  if (fast_ != nullptr) {
    kernels = fmt::format(
        " ({} kernels{})",
        fast_->isa() == internal::KernelIsa::kAvx512 ? "AVX-512" : "portable",
        fast_->bf16() ? fmt::format(", bf16 products on {}",
                                    internal::Bf16BackendName(
                                        internal::DefaultBf16Backend()))
                      : "");
  }
  SOMA_LOG(INFO,
           "train: {} engine{}, {} intra-op thread(s){}",
           engine(),
           kernels,
           at::get_num_threads(),
           average_ != nullptr
               ? fmt::format("; validation and checkpoints use a weight "
                             "average (ema_decay {})",
                             options_.ema_decay)
               : std::string());

  Usr1Guard usr1;
  while (state.epoch < options_.max_epochs) {
    const int epoch = state.epoch;  // 0-based index of the epoch being run
    Timer epoch_timer;
    EpochMetrics row;
    row.epoch = epoch + 1;
    row.lr = state.lr;
    // A mid-epoch checkpoint resumes after its batches (their plan is a
    // pure function of epoch and batch index).
    const int64_t first_batch = std::min(state.batch, num_batches);
    double loss_sum = state.epoch_loss_sum;
    const double train_s_before = state.epoch_train_s;
    state.batch = 0;
    state.epoch_loss_sum = 0;
    state.epoch_train_s = 0;
    {
      std::vector<BatchRequest> plan =
          PlanBatches(epoch, num_batches, options_.batch_size);
      plan.erase(plan.begin(), plan.begin() + first_batch);
      Prefetcher prefetcher(train, std::move(plan), options_.prefetch);
      LabeledFrames frames;
      const Rng epoch_stream =
          torch_stream.Stream(static_cast<uint64_t>(epoch));
      for (int64_t b = first_batch; b < num_batches; ++b) {
        if (!prefetcher.Next(&frames)) {
          throw InternalError("Trainer: the prefetcher ran out of batches");
        }
        torch::manual_seed(
            epoch_stream.Stream(static_cast<uint64_t>(b)).seed());
        const double step_lr =
            scheduler_->StepLr(state.step, total_steps, state.lr);
        SetLearningRate(*optimizer_, step_lr);
        row.lr = step_lr;  // metrics.csv: the rate of the epoch's last step
        const Tensors t = ToTensors(frames, train.slot_table());
        // Forward and loss (the fast engine also computes the gradients).
        torch::Tensor loss;
        double value = 0.0;
        if (fast_ != nullptr) {
          value =
              fast_->Step(t.points, t.labels, t.has_slots ? &t.slots : nullptr);
        } else {
          const LabelerOutput out = ForwardBatch(model_, t);
          loss =
              loss_->Compute(out.log_assignment, BatchTargets(t, num_labels));
          if (model_->options().position_loss > 0.0) {
            loss = loss + model_->PositionLoss(
                              out.point_keys,
                              t.has_slots ? t.slots : model_->LayoutSlots(),
                              t.labels);
          }
          value = loss.item<double>();
        }
        if (!std::isfinite(value)) {
          const std::string message = fmt::format(
              "non-finite loss at epoch {} step {} batch {}/{} (loss = {})",
              epoch + 1,
              state.step + 1,
              b + 1,
              num_batches,
              value);
          SOMA_LOG(ERROR, "train: {}", message);
          progress.Finish();
          return finish(TrainSummary::Termination::kNonFiniteLoss, message);
        }
        if (fast_ == nullptr) {
          optimizer_->zero_grad();
          loss.backward();
        }
        if (options_.gradient_clip_val > 0) {
          torch::nn::utils::clip_grad_norm_(model_->parameters(),
                                            options_.gradient_clip_val);
        }
        if (fast_ == nullptr || !FusedAdamStep(*optimizer_)) {
          optimizer_->step();
        }
        ++state.step;
        if (average_ != nullptr) average_->Update(state.step);
        loss_sum += value;
        progress.Update(
            options_.batch_size,
            fmt::format(
                "ep {}/{} loss={:.4g}", epoch + 1, options_.max_epochs, value));
        if (callbacks_.on_batch_end) {
          callbacks_.on_batch_end(BatchEvent{
              epoch + 1, static_cast<int>(b + 1), state.step, value});
        }
        if (usr1.received() && b + 1 < num_batches) {
          // (After the last batch the epoch's end checkpoints anyway.)
          state.batch = b + 1;
          state.epoch_loss_sum = loss_sum;
          state.epoch_train_s = train_s_before + epoch_timer.ElapsedSeconds();
          SaveCheckpoints(state, false);
          progress.Finish();
          SOMA_LOG(WARNING,
                   "train: SIGUSR1: checkpointed epoch {} after batch {}/{} "
                   "(step {}) to {}; stopping (re-run to resume)",
                   epoch + 1,
                   b + 1,
                   num_batches,
                   state.step,
                   last_checkpoint().string());
          usr1.Die();
        }
      }
      if (prefetcher.wait_seconds() > 0.05 * epoch_timer.ElapsedSeconds()) {
        SOMA_LOG(DEBUG,
                 "train: waited {:.1f}s for data in epoch {}",
                 prefetcher.wait_seconds(),
                 epoch + 1);
      }
    }
    const double train_s = train_s_before + epoch_timer.ElapsedSeconds();
    row.step = state.step;
    row.train_loss = loss_sum / static_cast<double>(num_batches);
    row = Validate(val, row);
    row.wall_s = train_s_before + epoch_timer.ElapsedSeconds();
    row.frames_per_s = static_cast<double>(frames_per_epoch) / train_s;

    // End of epoch: schedule, early stopping, best, checkpoint, metrics.
    state.lr = scheduler_->Step(row.val_loss, state.lr);
    SetLearningRate(*optimizer_, state.lr);
    const bool stop = early_stopping_.Update(row.val_loss);
    const bool is_best = row.val_loss < state.best_val_loss;
    if (is_best) {
      state.best_val_loss = row.val_loss;
      state.best_epoch = epoch + 1;
    }
    state.epoch = epoch + 1;
    state.history.push_back(row);
    if (stop) {  // (max_epochs needs no flag: a resume checks the count)
      state.finished = true;
      state.finish_reason = "early stopping: " + early_stopping_.reason();
    }
    SaveCheckpoints(state, is_best);
    WriteFileAtomic(metrics_path(), MetricsCsv(state.history));
    if (!row.layouts.empty()) {
      WriteFileAtomic(layout_metrics_path(), LayoutMetricsCsv(state.history));
    }
    SOMA_LOG(INFO,
             "epoch {}/{}: train_loss {:.5g} val_loss {:.5g} val_acc {:.4f} "
             "val_f1 {:.4f} lr {:.3g} ({:.1f}s, {:.0f} frames/s){}",
             row.epoch,
             options_.max_epochs,
             row.train_loss,
             row.val_loss,
             row.val_acc,
             row.val_f1,
             row.lr,
             row.wall_s,
             row.frames_per_s,
             is_best ? " *" : "");
    if (callbacks_.on_epoch_end) callbacks_.on_epoch_end(row);
    if (usr1.received() && !stop && state.epoch < options_.max_epochs) {
      progress.Finish();
      SOMA_LOG(WARNING,
               "train: SIGUSR1: checkpointed after epoch {} to {}; stopping "
               "(re-run to resume)",
               state.epoch,
               last_checkpoint().string());
      usr1.Die();
    }
    if (stop) {
      progress.Finish();
      return finish(TrainSummary::Termination::kEarlyStopping,
                    early_stopping_.reason());
    }
  }
  progress.Finish();
  return finish(TrainSummary::Termination::kMaxEpochs,
                fmt::format("max_epochs = {} reached", options_.max_epochs));
}

}  // namespace soma
