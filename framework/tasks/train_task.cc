// `soma train`: trains the labeler on synthetic frames made on the fly
// (`task.data: synth`, the synthesizer of cfg.body/layout/motion/noise/synth,
// train and val splits) or on HDF5 datasets (`task.data: hdf5`). Sizes come
// from cfg.train (set by `scale=paper|cpu`), the model from cfg.model and
// cfg.normalization, the optimiser and schedule from cfg.optimizer and
// cfg.scheduler. Outputs in the run dir: metrics.csv, loss.png,
// accuracy.png, checkpoints/{last,best}.pt. Re-running in the same run dir
// (hydra.run.dir=<dir>) resumes from checkpoints/last.pt.
#include "framework/config/decode.h"
#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/core/logging.h"
#include "framework/core/plot.h"
#include "framework/core/random.h"
#include "framework/model/labeler.h"
#include "framework/model/loss.h"
#include "framework/model/torch_utils.h"
#include "framework/synth/synthesizer.h"
#include "framework/tasks/components.h"
#include "framework/tasks/task.h"
#include "framework/train/batch_source.h"
#include "framework/train/optimizer.h"
#include "framework/train/schedule.h"
#include "framework/train/trainer.h"

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <torch/utils.h>

#include <optional>

namespace soma {
namespace {

struct TrainTaskOptions {
  std::string data = "synth";  // synth | hdf5
  std::string train_file;      // data=hdf5
  std::string val_file;        // data=hdf5
  bool plot = true;
};

void PlotCurves(const TrainSummary& summary, const std::filesystem::path& dir) {
  PlotSeries train_loss{"train_loss", {}, {}};
  PlotSeries val_loss{"val_loss", {}, {}};
  PlotSeries acc{"val_acc", {}, {}};
  PlotSeries f1{"val_f1", {}, {}};
  for (const EpochMetrics& m : summary.history) {
    const double x = m.epoch;
    train_loss.x.push_back(x);
    train_loss.y.push_back(m.train_loss);
    val_loss.x.push_back(x);
    val_loss.y.push_back(m.val_loss);
    acc.x.push_back(x);
    acc.y.push_back(m.val_acc);
    f1.x.push_back(x);
    f1.y.push_back(m.val_f1);
  }
  PlotOptions loss_options;
  loss_options.title = "labelling loss (sum over a batch)";
  loss_options.x_label = "epoch";
  loss_options.y_label = "loss";
  LinePlot({train_loss, val_loss}, loss_options).WritePng(dir / "loss.png");
  PlotOptions acc_options;
  acc_options.title = "validation accuracy and macro F1";
  acc_options.x_label = "epoch";
  acc_options.y_label = "score";
  acc_options.y_range = std::make_pair(0.0, 1.0);
  LinePlot({acc, f1}, acc_options).WritePng(dir / "accuracy.png");
}

class TrainTask : public Task {
 public:
  explicit TrainTask(TrainTaskOptions options) : options_(std::move(options)) {}

  void Run(const ConfigNode& cfg, RunContext& ctx) override {
    SetTorchThreads(ctx.num_threads);
    BuildContext build(ctx.seed, ctx.output_dir.string());
    TrainerOptions trainer_options = DecodeTrainerOptions(cfg.at("train"));
    trainer_options.seed = ctx.seed;
    const Rng root(ctx.seed);

    // Data.
    std::optional<Synthesizer> train_synth;
    std::optional<Synthesizer> val_synth;
    std::unique_ptr<BatchSource> train;
    std::unique_ptr<BatchSource> val;
    if (options_.data == "synth") {
      train_synth.emplace(BuildSynthesizer(cfg, Split::kTrain, build));
      val_synth.emplace(BuildSynthesizer(cfg, Split::kVal, build));
      train = std::make_unique<SynthBatchSource>(
          *train_synth,
          trainer_options.synth_data == "stream"
              ? SynthBatchSource::Mode::kStream
              : SynthBatchSource::Mode::kPool,
          root.Stream("data/train").seed(),
          trainer_options.train_frames,
          trainer_options.data_threads);
      val = std::make_unique<SynthBatchSource>(*val_synth,
                                               SynthBatchSource::Mode::kFixed,
                                               root.Stream("data/val").seed(),
                                               trainer_options.val_frames,
                                               trainer_options.data_threads);
    } else {
      train = std::make_unique<Hdf5BatchSource>(
          options_.train_file, true, root.Stream("data/train").seed());
      val = std::make_unique<Hdf5BatchSource>(options_.val_file, false, 0);
    }
    const std::vector<std::string> labels = train->labels();
    SOMA_LOG(INFO,
             "train: {} labels, {} points per frame, {} train frames per "
             "epoch, {} val frames",
             labels.size(),
             train->num_points(),
             train->frames_per_epoch(),
             val->frames_per_epoch());

    // Model, loss, optimiser, schedule.
    torch::manual_seed(root.Stream("model/init").seed());
    Labeler model = BuildLabeler(cfg.at("model"),
                                 cfg.at("normalization"),
                                 static_cast<int64_t>(labels.size()),
                                 build);
    SOMA_LOG(INFO,
             "train: labeler with {} trainable parameters",
             CountTrainableParameters(*model));
    if (model->conditioned()) {
      if (const SlotTable* table = train->slot_table(); table != nullptr) {
        // A layout per placement block (synth.layout_sampler, or a dataset
        // `soma synth` wrote with one): each batch brings its slots; the
        // checkpoint holds no layout (its labels are the slots, its config
        // the sampler), so `soma label` needs one.
        SOMA_LOG(INFO,
                 "train: layout-conditioned labeler, {} label slots, a "
                 "layout per placement block sampled from [{}]",
                 labels.size(),
                 fmt::join(table->layouts, ", "));
      } else if (!train_synth.has_value()) {
        throw ConfigError(fmt::format(
            "model=soma_any_layout trains on task.data=synth, or on a dataset "
            "of frames with label slots (soma synth with "
            "synth/layout_sampler=...); {} has none",
            options_.train_file));
      } else {
        // One fixed layout per run: the label slots are the synthesizer's
        // layout, saved with the checkpoints.
        model->SetLayout(LayoutSlotDescriptors(BuildBody(cfg, build),
                                               train_synth->superset(),
                                               model->descriptor_width()));
        SOMA_LOG(INFO,
                 "train: layout-conditioned labeler, {} label slots from the "
                 "synthesizer's layout",
                 labels.size());
      }
    }
    std::shared_ptr<const LabelingLoss> loss =
        Instantiate<LabelingLoss>(cfg.at("loss"), build);
    const std::unique_ptr<OptimizerSpec> optimizer =
        Instantiate<OptimizerSpec>(cfg.at("optimizer"), build);
    std::unique_ptr<LrScheduler> scheduler =
        Instantiate<LrScheduler>(cfg.at("scheduler"), build);
    ModelIdentity identity;
    identity.model_config = ConfigNode::EmptyMap();
    identity.model_config.Set("model", cfg.at("model"));
    identity.model_config.Set("normalization", cfg.at("normalization"));
    if (const SlotTable* table = train->slot_table(); table != nullptr) {
      // Trained on sampled layouts: recorded with the model (a resume must
      // sample the same ones; `soma label` asks for a layout). From a
      // dataset: its file and the layouts of its slot table.
      if (train_synth.has_value()) {
        identity.model_config.Set("layout_sampler",
                                  cfg.at("synth").at("layout_sampler"));
      } else {
        ConfigNode sampler = ConfigNode::EmptyMap();
        sampler.Set("dataset", ConfigNode::FromString(options_.train_file));
        ConfigNode layouts = ConfigNode::EmptyList();
        for (const std::string& name : table->layouts) {
          layouts.Append(ConfigNode::FromString(name));
        }
        sampler.Set("layouts", std::move(layouts));
        identity.model_config.Set("layout_sampler", std::move(sampler));
      }
    }
    identity.labels = labels;
    identity.config_yaml = DumpYaml(cfg);

    Trainer trainer(trainer_options,
                    model,
                    loss,
                    *optimizer,
                    std::move(scheduler),
                    identity,
                    ctx.output_dir);
    const TrainSummary summary = trainer.Train(*train, *val);
    SOMA_LOG(INFO, "train: {}", summary.BriefReport());
    if (options_.plot && !summary.history.empty()) {
      PlotCurves(summary, ctx.output_dir);
    }
    if (summary.termination == TrainSummary::Termination::kNonFiniteLoss) {
      throw Error(summary.message);
    }
    const EpochMetrics last = summary.last();
    double wall = 0;
    double frames_per_s = 0;
    for (const EpochMetrics& m : summary.history) {
      wall += m.wall_s;
      frames_per_s += m.frames_per_s;
    }
    ctx.ReportMetric("epochs", summary.epochs_completed);
    ctx.ReportMetric("val_loss", last.val_loss);
    ctx.ReportMetric("val_acc", last.val_acc);
    ctx.ReportMetric("val_f1", last.val_f1);
    ctx.ReportMetric("val_acc_frame", last.val_acc_frame);
    ctx.ReportMetric("best_val_loss", summary.best_val_loss);
    ctx.ReportMetric("best_epoch", summary.best_epoch);
    ctx.ReportMetric("train_wall_s", wall);
    if (!summary.history.empty()) {
      ctx.ReportMetric(
          "train_frames_per_s",
          frames_per_s / static_cast<double>(summary.history.size()));
    }
  }

 private:
  TrainTaskOptions options_;
};

}  // namespace

void RegisterTrainTask(Registry<Task>& registry) {
  registry.Register("train", [](const ConfigNode& node, BuildContext&) {
    ConfigReader reader(node);
    TrainTaskOptions options;
    reader.Read("data", &options.data);
    if (const ConfigNode* f = reader.Child("train_file");
        f != nullptr && !f->IsNull()) {
      options.train_file = f->AsString();
    }
    if (const ConfigNode* f = reader.Child("val_file");
        f != nullptr && !f->IsNull()) {
      options.val_file = f->AsString();
    }
    reader.Read("plot", &options.plot);
    reader.Check("data",
                 options.data == "synth" || options.data == "hdf5",
                 "data is synth or hdf5");
    reader.Check("train_file",
                 options.data != "hdf5" || !options.train_file.empty(),
                 "data=hdf5 needs task.train_file");
    reader.Check("val_file",
                 options.data != "hdf5" || !options.val_file.empty(),
                 "data=hdf5 needs task.val_file");
    reader.Finish();
    return std::make_unique<TrainTask>(options);
  });
}

}  // namespace soma
