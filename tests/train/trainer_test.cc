// The trainer on a tiny model and a tiny learnable point-labelling task:
// the loss decreases, runs are deterministic, resume (also after a crash
// mid-epoch) ends where an uninterrupted run ends, the NaN guard, refusal of
// mismatching checkpoints, fine-tuning, and Adam's classic L2 decay.
#include "framework/train/trainer.h"

#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/random.h"
#include "framework/model/loss.h"
#include "framework/model/torch_utils.h"
#include "framework/testing/testing.h"
#include "framework/train/batch_source.h"
#include "framework/train/optimizer.h"
#include "framework/train/schedule.h"
#include "framework/train/weight_average.h"

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <csignal>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

namespace soma {
namespace {

constexpr int kLabels = 6;
constexpr int kPoints = 8;  // L + 2 ghost slots

std::vector<std::string> Labels() {
  std::vector<std::string> labels;
  for (int i = 0; i < kLabels; ++i) labels.push_back("M" + std::to_string(i));
  return labels;
}

// Label j sits near a fixed position; each frame drops up to one label, adds
// up to one ghost, shuffles the points and zero-pads to kPoints.
LabeledFrames TinyFrames(int64_t frames, uint64_t seed) {
  Rng layout(1234);
  std::vector<std::array<float, 3>> centers(kLabels);
  for (auto& c : centers) {
    for (float& v : c) v = static_cast<float>(layout.Uniform(-1, 1));
  }
  LabeledFrames out;
  out.num_points = kPoints;
  out.points.assign(static_cast<size_t>(frames * kPoints * 3), 0.0f);
  out.labels.assign(static_cast<size_t>(frames * kPoints), kLabels);
  for (int64_t f = 0; f < frames; ++f) {
    Rng rng = Rng(seed).Stream(static_cast<uint64_t>(f));
    std::vector<std::pair<std::array<float, 3>, int>> points;
    const int dropped = static_cast<int>(rng.UniformInt(-1, kLabels - 1));
    for (int j = 0; j < kLabels; ++j) {
      if (j == dropped) continue;
      std::array<float, 3> p = centers[static_cast<size_t>(j)];
      for (float& v : p) v += static_cast<float>(rng.Normal(0, 0.05));
      points.push_back({p, j});
    }
    if (rng.Bernoulli(0.5)) {
      std::array<float, 3> ghost;
      for (float& v : ghost) v = static_cast<float>(rng.Uniform(-1.5, 1.5));
      points.push_back({ghost, kLabels});
    }
    const std::vector<int> perm = rng.Permutation(kPoints);
    size_t next = 0;
    for (int slot : perm) {
      if (next >= points.size()) break;
      float* dst = out.frame_points(f) + slot * 3;
      for (int c = 0; c < 3; ++c) dst[c] = points[next].first[c];
      out.frame_labels(f)[slot] = static_cast<int16_t>(points[next].second);
      ++next;
    }
  }
  return out;
}

ConfigNode ModelConfig(int d_model = 16) {
  return ParseYaml(fmt::format("model:\n"
                               "  name: soma\n"
                               "  d_model: {}\n"
                               "  hidden: 16\n"
                               "  backbone:\n"
                               "    name: self_attention\n"
                               "    num_layers: 1\n"
                               "    num_heads: 2\n"
                               "normalization:\n"
                               "  name: sinkhorn\n"
                               "  num_iters: 5\n",
                               d_model),
                   "test");
}

class TrainerTest : public ::testing::Test {
 protected:
  void SetUp() override {
    previous_threads_ = TorchThreads();
    SetTorchThreads(1);
    train_ = std::make_unique<InMemoryBatchSource>(
        TinyFrames(64, 1), Labels(), true, 5);
    val_ = std::make_unique<InMemoryBatchSource>(
        TinyFrames(32, 2), Labels(), false, 0);
    root_ = testing::CreateTestDir();
  }
  void TearDown() override { SetTorchThreads(previous_threads_); }

  TrainerOptions Options(int epochs) const {
    TrainerOptions options;
    options.batch_size = 16;
    options.max_epochs = epochs;
    options.progress = false;
    options.seed = 99;
    return options;
  }

  std::unique_ptr<Trainer> MakeTrainer(
      const TrainerOptions& options,
      const std::filesystem::path& dir,
      ConfigNode config = ModelConfig(),
      std::vector<std::string> labels = Labels(),
      double lr = 3e-3,
      std::unique_ptr<LrScheduler> scheduler = nullptr) {
    torch::manual_seed(7);
    Labeler model = BuildLabeler(config.at("model"),
                                 config.at("normalization"),
                                 static_cast<int64_t>(labels.size()));
    AdamOptions adam;
    adam.lr = lr;
    ModelIdentity identity{config, labels, "seed: 99\n"};
    return std::make_unique<Trainer>(
        options,
        model,
        std::make_shared<SomaLabelingLoss>(),
        AdamSpec(adam),
        scheduler != nullptr ? std::move(scheduler)
                             : std::make_unique<ReduceLrOnPlateau>(),
        identity,
        dir);
  }

  std::unique_ptr<InMemoryBatchSource> train_;
  std::unique_ptr<InMemoryBatchSource> val_;
  std::filesystem::path root_;
  int previous_threads_ = 1;
};

// metrics.csv without the machine-dependent columns (wall_s, frames_per_s).
std::string DeterministicColumns(const std::filesystem::path& csv) {
  std::istringstream in(ReadFile(csv));
  std::string line, out;
  while (std::getline(in, line)) {
    for (int i = 0; i < 2; ++i) line = line.substr(0, line.rfind(','));
    out += line + "\n";
  }
  return out;
}

void ExpectSameParameters(const Labeler& a, const Labeler& b) {
  const auto pa = a->named_parameters();
  const auto pb = b->named_parameters();
  ASSERT_EQ(pa.size(), pb.size());
  for (size_t i = 0; i < pa.size(); ++i) {
    EXPECT_TRUE(torch::equal(pa[i].value(), pb[i].value())) << pa[i].key();
  }
}

// Parameters and buffers.
void ExpectSameWeights(const Labeler& a, const Labeler& b) {
  ExpectSameParameters(a, b);
  const auto ba = a->named_buffers();
  const auto bb = b->named_buffers();
  ASSERT_EQ(ba.size(), bb.size());
  for (size_t i = 0; i < ba.size(); ++i) {
    EXPECT_TRUE(torch::equal(ba[i].value(), bb[i].value())) << ba[i].key();
  }
}

TEST_F(TrainerTest, LossDecreasesOnATinySet) {
  const auto dir = root_;
  auto trainer = MakeTrainer(Options(12), dir, ModelConfig(), Labels(), 1e-2);
  const TrainSummary summary = trainer->Train(*train_, *val_);
  ASSERT_EQ(summary.history.size(), 12u) << summary.BriefReport();
  EXPECT_EQ(summary.termination, TrainSummary::Termination::kMaxEpochs);
  const EpochMetrics first = summary.history.front();
  const EpochMetrics last = summary.history.back();
  EXPECT_LT(last.train_loss, 0.6 * first.train_loss);
  EXPECT_LT(last.val_loss, first.val_loss);
  EXPECT_GT(last.val_acc, first.val_acc);
  EXPECT_EQ(last.step, 12 * 4);
  for (const EpochMetrics& m : summary.history) {
    EXPECT_TRUE(std::isfinite(m.train_loss) && std::isfinite(m.val_loss));
    EXPECT_GE(m.val_acc, 0);
    EXPECT_LE(m.val_acc, 1);
    EXPECT_GE(m.val_f1, 0);
    EXPECT_LE(m.val_f1, 1);
  }
  for (const torch::Tensor& p : trainer->model()->parameters()) {
    EXPECT_TRUE(torch::isfinite(p).all().item<bool>());
  }
  EXPECT_TRUE(std::filesystem::exists(dir / "metrics.csv"));
  EXPECT_TRUE(std::filesystem::exists(dir / "checkpoints" / "last.pt"));
  EXPECT_TRUE(std::filesystem::exists(dir / "checkpoints" / "best.pt"));
  const CheckpointInfo info = ReadCheckpointInfo(dir / "checkpoints/last.pt");
  EXPECT_EQ(info.epoch, 12);
  EXPECT_EQ(info.step, 48);
  EXPECT_EQ(info.labels, Labels());
  const CheckpointInfo best = ReadCheckpointInfo(dir / "checkpoints/best.pt");
  EXPECT_EQ(best.epoch, summary.best_epoch);
}

TEST_F(TrainerTest, SameSeedSameMetrics) {
  const auto a = root_ / "a";
  const auto b = root_ / "b";
  MakeTrainer(Options(3), a)->Train(*train_, *val_);
  MakeTrainer(Options(3), b)->Train(*train_, *val_);
  const std::string csv = DeterministicColumns(a / "metrics.csv");
  EXPECT_EQ(csv, DeterministicColumns(b / "metrics.csv"));
  EXPECT_EQ(std::count(csv.begin(), csv.end(), '\n'), 4);
  // Another seed changes the numbers.
  const auto c = root_ / "c";
  TrainerOptions other = Options(3);
  other.seed = 100;
  auto train_other = std::make_unique<InMemoryBatchSource>(
      TinyFrames(64, 1), Labels(), true, 6);
  MakeTrainer(other, c)->Train(*train_other, *val_);
  EXPECT_NE(csv, DeterministicColumns(c / "metrics.csv"));
}

TEST_F(TrainerTest, ResumeEndsLikeAnUninterruptedRun) {
  const auto full = root_ / "full";
  auto reference = MakeTrainer(Options(3), full);
  reference->Train(*train_, *val_);

  // One epoch, then a fresh Trainer (new process) continues to 3.
  const auto split = root_ / "split";
  MakeTrainer(Options(1), split)->Train(*train_, *val_);
  auto resumed = MakeTrainer(Options(3), split);
  const TrainSummary summary = resumed->Train(*train_, *val_);
  EXPECT_EQ(summary.start_epoch, 1);
  EXPECT_EQ(summary.epochs_completed, 3);
  EXPECT_EQ(DeterministicColumns(full / "metrics.csv"),
            DeterministicColumns(split / "metrics.csv"));
  ExpectSameWeights(reference->model(), resumed->model());
}

TEST_F(TrainerTest, CrashMidEpochLosesOnlyThatEpoch) {
  const auto full = root_ / "full";
  auto reference = MakeTrainer(Options(3), full);
  reference->Train(*train_, *val_);

  const auto dir = root_ / "crash";
  auto crashing = MakeTrainer(Options(3), dir);
  crashing->set_callbacks(
      Trainer::Callbacks{.on_batch_end =
                             [](const Trainer::BatchEvent& e) {
                               if (e.epoch == 2 && e.batch == 2)
                                 throw std::runtime_error("kill");
                             },
                         .on_epoch_end = nullptr});
  EXPECT_THROW(crashing->Train(*train_, *val_), std::runtime_error);
  EXPECT_EQ(ReadCheckpointInfo(dir / "checkpoints/last.pt").epoch, 1);
  // A torn temp file of a checkpoint write in progress is ignored.
  WriteFileAtomic(dir / "checkpoints" / "last.pt.tmp.12345", "torn");
  {
    std::ofstream torn(dir / "checkpoints" / "last.pt.tmp.999");
    torn << "PK\x03\x04 truncated";
  }
  auto resumed = MakeTrainer(Options(3), dir);
  const TrainSummary summary = resumed->Train(*train_, *val_);
  EXPECT_EQ(summary.start_epoch, 1);
  EXPECT_EQ(DeterministicColumns(full / "metrics.csv"),
            DeterministicColumns(dir / "metrics.csv"));
  ExpectSameWeights(reference->model(), resumed->model());

  // Resuming a finished run trains nothing more.
  auto again = MakeTrainer(Options(3), dir);
  const TrainSummary done = again->Train(*train_, *val_);
  EXPECT_EQ(done.start_epoch, 3);
  EXPECT_EQ(done.history.size(), 3u);
}

TEST_F(TrainerTest, Sigusr1CheckpointsMidEpochAndResumesExactly) {
  // The preemption signal of the SLURM launcher (issue #24): SIGUSR1 makes
  // the trainer checkpoint at the next batch, in the middle of an epoch,
  // and die of the signal; the resumed run ends like an uninterrupted one.
  const auto full = root_ / "full";
  auto reference = MakeTrainer(Options(3), full);
  reference->Train(*train_, *val_);

  const auto dir = root_ / "preempted";
  // "fast": the forked child writes into this test's directory.
  GTEST_FLAG_SET(death_test_style, "fast");
  EXPECT_EXIT(
      {
        auto preempted = MakeTrainer(Options(3), dir);
        preempted->set_callbacks(
            Trainer::Callbacks{.on_batch_end =
                                   [](const Trainer::BatchEvent& e) {
                                     if (e.epoch == 2 && e.batch == 2)
                                       ::raise(SIGUSR1);
                                   },
                               .on_epoch_end = nullptr});
        preempted->Train(*train_, *val_);
        std::exit(0);  // not reached: the signal ends the process
      },
      ::testing::KilledBySignal(SIGUSR1),
      "SIGUSR1: checkpointed epoch 2 after batch 2/4");
  // 4 batches per epoch: epoch 1 and 2 batches of epoch 2.
  const CheckpointInfo info = ReadCheckpointInfo(dir / "checkpoints/last.pt");
  EXPECT_EQ(info.epoch, 1);
  EXPECT_EQ(info.step, 6);
  auto resumed = MakeTrainer(Options(3), dir);
  const TrainSummary summary = resumed->Train(*train_, *val_);
  EXPECT_EQ(summary.start_epoch, 1);
  EXPECT_EQ(summary.epochs_completed, 3);
  EXPECT_EQ(DeterministicColumns(full / "metrics.csv"),
            DeterministicColumns(dir / "metrics.csv"));
  ExpectSameWeights(reference->model(), resumed->model());
}

TEST_F(TrainerTest, NonFiniteLossStopsWithEpochStepBatch) {
  LabeledFrames frames = TinyFrames(64, 1);
  frames.points[0] = std::nanf("");
  InMemoryBatchSource bad(std::move(frames), Labels(), false, 0);
  const auto dir = root_;
  const TrainSummary summary = MakeTrainer(Options(2), dir)->Train(bad, *val_);
  EXPECT_EQ(summary.termination, TrainSummary::Termination::kNonFiniteLoss);
  EXPECT_NE(summary.message.find("non-finite loss at epoch 1 step 1 batch 1"),
            std::string::npos)
      << summary.message;
  EXPECT_FALSE(std::filesystem::exists(dir / "checkpoints" / "last.pt"));
}

TEST_F(TrainerTest, RefusesAMismatchingCheckpoint) {
  const auto dir = root_;
  MakeTrainer(Options(1), dir)->Train(*train_, *val_);
  // Another d_model in the same run dir: resume is refused naming the key.
  const std::string message = testing::ErrorMessage<ConfigError>([&] {
    MakeTrainer(Options(2), dir, ModelConfig(24))->Train(*train_, *val_);
  });
  EXPECT_NE(message.find("model.d_model"), std::string::npos) << message;
  EXPECT_NE(message.find("16"), std::string::npos) << message;
  // Other labels: refused naming the label.
  std::vector<std::string> labels = Labels();
  labels[3] = "XX";
  InMemoryBatchSource train(TinyFrames(64, 1), labels, true, 5);
  InMemoryBatchSource val(TinyFrames(32, 2), labels, false, 0);
  const std::string label_message = testing::ErrorMessage<ConfigError>([&] {
    MakeTrainer(Options(2), dir, ModelConfig(), labels)->Train(train, val);
  });
  EXPECT_NE(label_message.find("'M3' vs 'XX'"), std::string::npos)
      << label_message;
  // Fine-tuning from a mismatching checkpoint is refused too.
  TrainerOptions finetune = Options(1);
  finetune.init_from = (dir / "checkpoints" / "best.pt").string();
  const std::string init_message = testing::ErrorMessage<ConfigError>([&] {
    MakeTrainer(finetune, root_ / "ft", ModelConfig(24))->Train(*train_, *val_);
  });
  EXPECT_NE(init_message.find("model.d_model"), std::string::npos);
  // Not a checkpoint at all.
  WriteFileAtomic(dir / "junk.pt", "junk");
  TrainerOptions junk = Options(1);
  junk.resume = (dir / "junk.pt").string();
  EXPECT_THROW(MakeTrainer(junk, root_ / "j")->Train(*train_, *val_), IoError);
}

TEST_F(TrainerTest, FineTuningLoadsWeightsOnly) {
  const auto dir = root_ / "pre";
  auto pre = MakeTrainer(Options(2), dir);
  pre->Train(*train_, *val_);
  TrainerOptions options = Options(0);  // load and stop
  options.init_from = (dir / "checkpoints" / "last.pt").string();
  auto tuned = MakeTrainer(options, root_ / "ft");
  const TrainSummary summary = tuned->Train(*train_, *val_);
  EXPECT_EQ(summary.start_epoch, 0);
  ExpectSameWeights(pre->model(), tuned->model());
  // The stand-alone loader gives the same network.
  Labeler loaded = LoadLabelerFromCheckpoint(dir / "checkpoints" / "last.pt");
  ExpectSameWeights(pre->model(), loaded);
}

// Layout-conditioned training on per-frame label slots (issue #25 item 1):
// two "layouts" of the tiny scene, the same six markers in two slot orders
// (layout 1 also pads two slots); each marker has one descriptor. Only the
// descriptors say which slot is which marker.
constexpr int kSlots = 8;
constexpr int kJoints = 2;  // descriptor width LabelDescriptorWidth(2) = 13

void AddSlots(LabeledFrames* frames, SlotTable* table) {
  const int q = 3 + 3 + 1 + kJoints + 4;
  Rng rng(77);
  std::vector<std::vector<float>> marker(kLabels, std::vector<float>(q));
  for (auto& d : marker) {
    for (float& v : d) v = static_cast<float>(rng.Normal());
  }
  table->width = q;
  table->layouts = {"in_order", "reversed"};
  // Rows 0-5: layout 0's markers; rows 6-11: layout 1's.
  for (int k = 0; k < 2; ++k) {
    for (int j = 0; j < kLabels; ++j) {
      table->rows.insert(table->rows.end(), marker[j].begin(), marker[j].end());
      table->names.push_back("M" + std::to_string(j));
      table->row_layout.push_back(k);
    }
  }
  frames->num_slots = kSlots;
  frames->slots.assign(static_cast<size_t>(frames->num_frames() * kSlots), -1);
  for (int64_t f = 0; f < frames->num_frames(); ++f) {
    const bool reversed = (f / 4) % 2 == 1;
    int16_t* slots = frames->frame_slots(f);
    for (int s = 0; s < kLabels; ++s) {
      slots[s] =
          static_cast<int16_t>(reversed ? kLabels + (kLabels - 1 - s) : s);
    }
    int16_t* labels = frames->frame_labels(f);
    for (int p = 0; p < kPoints; ++p) {
      if (labels[p] == kLabels) {
        labels[p] = kSlots;  // null = S
      } else if (reversed) {
        labels[p] = static_cast<int16_t>(kLabels - 1 - labels[p]);
      }
    }
  }
}

ConfigNode ConditionedConfig() {
  return ParseYaml(fmt::format("model:\n"
                               "  name: soma_any_layout\n"
                               "  d_model: 16\n"
                               "  hidden: 16\n"
                               "  backbone:\n"
                               "    name: self_attention\n"
                               "    num_layers: 1\n"
                               "    num_heads: 2\n"
                               "  label_encoder:\n"
                               "    num_joints: {}\n"
                               "    hidden: 16\n"
                               "    num_layers: 1\n"
                               "    num_heads: 2\n"
                               "normalization:\n"
                               "  name: sinkhorn\n"
                               "  num_iters: 5\n",
                               kJoints),
                   "test");
}

std::vector<std::string> SlotNames() {
  std::vector<std::string> names;
  for (int s = 0; s < kSlots; ++s) names.push_back("slot" + std::to_string(s));
  return names;
}

// The tiny frames with per-frame label slots (AddSlots), as a training and a
// validation source that share one slot table.
struct SlottedSources {
  SlotTable table;
  std::unique_ptr<InMemoryBatchSource> train;
  std::unique_ptr<InMemoryBatchSource> val;
};

SlottedSources MakeSlottedSources() {
  LabeledFrames train_frames = TinyFrames(64, 1);
  LabeledFrames val_frames = TinyFrames(32, 2);
  SlottedSources out;
  AddSlots(&train_frames, &out.table);
  AddSlots(&val_frames, &out.table);  // same table contents (appended twice)
  out.table.rows.resize(out.table.rows.size() / 2);
  out.table.names.resize(out.table.names.size() / 2);
  out.table.row_layout.resize(out.table.row_layout.size() / 2);
  out.train = std::make_unique<InMemoryBatchSource>(
      std::move(train_frames), SlotNames(), true, 5);
  out.val = std::make_unique<InMemoryBatchSource>(
      std::move(val_frames), SlotNames(), false, 0);
  out.train->SetSlotTable(out.table);
  out.val->SetSlotTable(out.table);
  return out;
}

TEST_F(TrainerTest, ConditionedModelTrainsOnPerFrameSlots) {
  const SlottedSources slotted = MakeSlottedSources();
  InMemoryBatchSource& train = *slotted.train;
  InMemoryBatchSource& val = *slotted.val;
  auto trainer =
      MakeTrainer(Options(15), root_, ConditionedConfig(), SlotNames(), 1e-2);
  ASSERT_TRUE(trainer->model()->conditioned());
  const TrainSummary summary = trainer->Train(train, val);
  ASSERT_EQ(summary.history.size(), 15u) << summary.BriefReport();
  const EpochMetrics first = summary.history.front();
  const EpochMetrics last = summary.history.back();
  EXPECT_LT(last.train_loss, 0.6 * first.train_loss);
  EXPECT_LT(last.val_loss, first.val_loss);
  // Both slot orders are labelled: well above the 1/7 of a guess.
  EXPECT_GT(last.val_acc, 0.6) << summary.BriefReport();

  // The same frames for a fixed-head model: refused, one line.
  auto fixed =
      MakeTrainer(Options(1), root_ / "fixed", ModelConfig(), SlotNames());
  const std::string message =
      testing::ErrorMessage<ConfigError>([&] { fixed->Train(train, val); });
  EXPECT_NE(message.find("use model=soma_any_layout"), std::string::npos)
      << message;
}

TEST_F(TrainerTest, ConditionedModelFineTunesOnAnotherLayout) {
  // Pre-training on sampled slots (its identity records a layout sampler,
  // its labels are slot names) ...
  const SlottedSources slotted = MakeSlottedSources();
  const SlotTable& table = slotted.table;
  ConfigNode sampled = ConditionedConfig();
  sampled.Set("layout_sampler", ParseYaml("name: mixed\n", "test"));
  auto pre = MakeTrainer(Options(2), root_ / "pre", sampled, SlotNames());
  pre->Train(*slotted.train, *slotted.val);

  // ... then fine-tuned on one fixed layout of six named markers: the
  // network's weights come from the checkpoint, the layout stays the run's.
  const int q = static_cast<int>(table.width);
  const torch::Tensor layout =
      torch::tensor(std::vector<float>(table.rows.begin(),
                                       table.rows.begin() + kLabels * q))
          .reshape({kLabels, q});
  TrainerOptions options = Options(0);  // load and stop
  options.init_from = (root_ / "pre" / "checkpoints" / "last.pt").string();
  auto tuned =
      MakeTrainer(options, root_ / "ft", ConditionedConfig(), Labels());
  Labeler tuned_model = tuned->model();  // shares the trainer's network
  tuned_model->SetLayout(layout);
  tuned->Train(*train_, *val_);
  ExpectSameParameters(pre->model(), tuned->model());
  ASSERT_TRUE(tuned->model()->HoldsLayout());
  const torch::Tensor held = tuned->model()->layout_descriptors;
  ASSERT_EQ(held.size(0), kLabels);
  EXPECT_TRUE(torch::equal(held, layout));

  // And it trains on that layout from there.
  options.max_epochs = 2;
  auto trained =
      MakeTrainer(options, root_ / "ft2", ConditionedConfig(), Labels());
  Labeler trained_model = trained->model();
  trained_model->SetLayout(layout);
  const TrainSummary summary = trained->Train(*train_, *val_);
  ASSERT_EQ(summary.history.size(), 2u) << summary.BriefReport();
  EXPECT_TRUE(std::isfinite(summary.history.back().val_loss));

  // A checkpoint written before a model key existed (the pre-training's
  // config has no label_encoder.fourier_bands or relative_bias) starts a
  // model that states the value every earlier model had, and not one that
  // differs.
  TrainerOptions load_only = options;
  load_only.max_epochs = 0;
  ConfigNode explicit_bands = ConditionedConfig();
  explicit_bands.at("model").at("label_encoder").Set("fourier_bands", 0);
  explicit_bands.at("model").at("label_encoder").Set("relative_bias", 0);
  auto stated =
      MakeTrainer(load_only, root_ / "ft_bands", explicit_bands, Labels());
  Labeler stated_model = stated->model();
  stated_model->SetLayout(layout);
  stated->Train(*train_, *val_);
  ExpectSameParameters(pre->model(), stated->model());
  explicit_bands.at("model").at("label_encoder").Set("fourier_bands", 2);
  const std::string bands_message = testing::ErrorMessage<ConfigError>([&] {
    MakeTrainer(load_only, root_ / "ft_bands2", explicit_bands, Labels())
        ->Train(*train_, *val_);
  });
  EXPECT_NE(bands_message.find("model.label_encoder.fourier_bands = 0 in the "
                               "checkpoint, 2 in the config"),
            std::string::npos)
      << bands_message;

  // Another network is still refused, naming the key.
  ConfigNode wider = ConditionedConfig();
  wider.at("model").Set("d_model", ParseYaml("24", "test"));
  const std::string message = testing::ErrorMessage<ConfigError>([&] {
    MakeTrainer(options, root_ / "ft3", wider, Labels())->Train(*train_, *val_);
  });
  EXPECT_NE(message.find("model.d_model"), std::string::npos) << message;
}

TEST(Adam, WeightDecayIsClassicL2) {
  // Zero loss gradient, theta = 2, wd = 0.01, lr = 0.1. Classic L2: g = 0.02,
  // the first Adam step moves by lr * sign(g) -> 1.9. AdamW would give
  // 2 - lr * wd * 2 = 1.998.
  torch::Tensor theta = torch::full({1}, 2.0, torch::requires_grad());
  AdamOptions options;
  options.lr = 0.1;
  options.weight_decay = 0.01;
  auto optimizer = AdamSpec(options).Build({theta});
  (theta * 0).sum().backward();
  optimizer->step();
  EXPECT_NEAR(theta.item<double>(), 1.9, 1e-6);
  EXPECT_DOUBLE_EQ(GetLearningRate(*optimizer), 0.1);
  SetLearningRate(*optimizer, 0.01);
  EXPECT_DOUBLE_EQ(GetLearningRate(*optimizer), 0.01);
}

TrainerOptions WithEngine(TrainerOptions options, const std::string& engine) {
  options.engine = engine;
  return options;
}

TEST_F(TrainerTest, FastAndTorchEnginesTrainAlike) {
  const auto fast_dir = root_ / "fast";
  const auto torch_dir = root_ / "torch";
  auto fast = MakeTrainer(WithEngine(Options(3), "fast"), fast_dir);
  auto reference = MakeTrainer(WithEngine(Options(3), "torch"), torch_dir);
  EXPECT_EQ(fast->engine(), "fast");
  EXPECT_EQ(reference->engine(), "torch");
  const TrainSummary a = fast->Train(*train_, *val_);
  const TrainSummary b = reference->Train(*train_, *val_);
  ASSERT_EQ(a.history.size(), 3u);
  ASSERT_EQ(b.history.size(), 3u);
  // Same initialisation and batches: the engines differ by float rounding
  // only, which grows slowly over the steps.
  EXPECT_NEAR(a.history[0].train_loss,
              b.history[0].train_loss,
              1e-3 * b.history[0].train_loss);
  for (size_t e = 0; e < 3; ++e) {
    EXPECT_NEAR(a.history[e].val_loss,
                b.history[e].val_loss,
                2e-2 * b.history[e].val_loss)
        << "epoch " << e + 1;
  }
}

TEST_F(TrainerTest, EnginesShareCheckpoints) {
  // Fast for one epoch, then torch resumes to two; and the other way round.
  for (const auto& [first, second] :
       std::vector<std::pair<std::string, std::string>>{{"fast", "torch"},
                                                        {"torch", "fast"}}) {
    const auto dir = root_ / (first + "_then_" + second);
    MakeTrainer(WithEngine(Options(1), first), dir)->Train(*train_, *val_);
    auto resumed = MakeTrainer(WithEngine(Options(2), second), dir);
    const TrainSummary summary = resumed->Train(*train_, *val_);
    EXPECT_EQ(summary.start_epoch, 1) << first;
    ASSERT_EQ(summary.history.size(), 2u) << first;
    EXPECT_EQ(summary.history[1].step, 8) << first;
    EXPECT_LT(summary.history[1].val_loss, summary.history[0].val_loss)
        << first << " then " << second;
    // The checkpoint labels with the eval-mode torch forward as well.
    Labeler loaded = LoadLabelerFromCheckpoint(dir / "checkpoints/last.pt");
    ExpectSameWeights(loaded, resumed->model());
  }
}

double GradientNorm(const Labeler& model) {
  double sum = 0;
  for (const torch::Tensor& p : model->parameters()) {
    if (p.grad().defined()) sum += p.grad().square().sum().item<double>();
  }
  return std::sqrt(sum);
}

TEST_F(TrainerTest, GradientClippingBoundsTheNormOnBothEngines) {
  constexpr double kClip = 0.05;
  for (const std::string engine : {"fast", "torch"}) {
    for (const double clip : {0.0, kClip}) {
      TrainerOptions options = WithEngine(Options(1), engine);
      options.gradient_clip_val = clip;
      auto trainer =
          MakeTrainer(options, root_ / fmt::format("{}_{}", engine, clip));
      double max_norm = 0;
      Trainer* raw = trainer.get();
      trainer->set_callbacks(
          Trainer::Callbacks{.on_batch_end = [&](const Trainer::BatchEvent&) {
            // The gradients the step used stay in .grad() after it.
            max_norm = std::max(max_norm, GradientNorm(raw->model()));
          }});
      trainer->Train(*train_, *val_);
      if (clip > 0) {
        EXPECT_LE(max_norm, clip * (1 + 1e-4)) << engine;
        EXPECT_GT(max_norm, 0.5 * clip) << engine;
      } else {
        EXPECT_GT(max_norm, 10 * kClip) << engine << ": unclipped norms";
      }
    }
  }
}

TEST_F(TrainerTest, CosineScheduleSetsEveryStepsRateAndResumes) {
  CosineOptions cosine;
  cosine.warmup_steps = 3;
  cosine.final_factor = 0.1;
  const double lr = 3e-3;
  const auto full = root_ / "full";
  std::vector<double> seen;
  auto trainer = MakeTrainer(Options(3),
                             full,
                             ModelConfig(),
                             Labels(),
                             lr,
                             std::make_unique<WarmupCosineLr>(cosine));
  Trainer* raw = trainer.get();
  trainer->set_callbacks(
      Trainer::Callbacks{.on_batch_end = [&](const Trainer::BatchEvent&) {
        seen.push_back(GetLearningRate(raw->optimizer()));
      }});
  const TrainSummary summary = trainer->Train(*train_, *val_);
  const WarmupCosineLr schedule(cosine);
  ASSERT_EQ(seen.size(), 12u);  // 3 epochs x 4 batches
  for (size_t s = 0; s < seen.size(); ++s) {
    EXPECT_DOUBLE_EQ(seen[s], schedule.StepLr(s, 12, lr)) << "step " << s;
  }
  EXPECT_DOUBLE_EQ(seen[2], lr);  // the warm-up's last step
  EXPECT_DOUBLE_EQ(summary.history.back().lr, seen.back());

  // Interrupted after one epoch: the resumed run repeats the same rates.
  const auto split = root_ / "split";
  MakeTrainer(Options(1),
              split,
              ModelConfig(),
              Labels(),
              lr,
              std::make_unique<WarmupCosineLr>(cosine))
      ->Train(*train_, *val_);
  auto resumed = MakeTrainer(Options(3),
                             split,
                             ModelConfig(),
                             Labels(),
                             lr,
                             std::make_unique<WarmupCosineLr>(cosine));
  resumed->Train(*train_, *val_);
  EXPECT_EQ(DeterministicColumns(full / "metrics.csv"),
            DeterministicColumns(split / "metrics.csv"));
  ExpectSameWeights(trainer->model(), resumed->model());
}

TrainerOptions WithAverage(TrainerOptions options, double decay) {
  options.ema_decay = decay;
  return options;
}

TEST_F(TrainerTest, WeightAverageIsCheckpointedAndLeavesTrainingAsIs) {
  constexpr double kDecay = 0.8;
  for (const std::string engine : {"fast", "torch"}) {
    const auto plain_dir = root_ / (engine + "_plain");
    const auto dir = root_ / (engine + "_averaged");
    auto plain = MakeTrainer(WithEngine(Options(3), engine), plain_dir);
    auto trainer =
        MakeTrainer(WithAverage(WithEngine(Options(3), engine), kDecay), dir);
    // The average of the weights after every step, in double, by hand.
    std::vector<torch::Tensor> expected;
    Trainer* raw = trainer.get();
    const auto weights = [&] {
      return WeightAverage::WeightsOf(*raw->model());
    };
    for (const torch::Tensor& w : weights()) {
      expected.push_back(w.detach().to(torch::kDouble));
    }
    trainer->set_callbacks(
        Trainer::Callbacks{.on_batch_end = [&](const Trainer::BatchEvent& e) {
          const double d = WeightAverage::DecayAt(kDecay, e.step);
          const std::vector<torch::Tensor> now = weights();
          for (size_t i = 0; i < now.size(); ++i) {
            const torch::Tensor w = now[i].detach().to(torch::kDouble);
            expected[i] = now[i].is_floating_point()
                              ? d * expected[i] + (1 - d) * w
                              : w;  // num_batches_tracked: copied
          }
        }});
    const TrainSummary a = plain->Train(*train_, *val_);
    const TrainSummary b = trainer->Train(*train_, *val_);
    ASSERT_EQ(b.history.size(), 3u) << engine;
    // Averaging does not touch the trained weights (no lr change in 3
    // epochs), but validation sees the average.
    ExpectSameWeights(plain->model(), trainer->model());
    EXPECT_NE(a.history.back().val_loss, b.history.back().val_loss) << engine;
    // Both checkpoints' model is the average (num_batches_tracked, an
    // integer, is the live count).
    Labeler loaded = LoadLabelerFromCheckpoint(dir / "checkpoints/last.pt");
    const std::vector<torch::Tensor> got = WeightAverage::WeightsOf(*loaded);
    ASSERT_EQ(got.size(), expected.size());
    for (size_t i = 0; i < got.size(); ++i) {
      EXPECT_TRUE(
          torch::allclose(got[i].to(torch::kDouble), expected[i], 1e-5, 1e-6))
          << engine << ", weight " << i;
    }
    EXPECT_FALSE(torch::equal(loaded->parameters()[0],
                              trainer->model()->parameters()[0]));
  }
}

TEST_F(TrainerTest, ResumeWithWeightAverageEndsLikeAnUninterruptedRun) {
  const TrainerOptions options = WithAverage(Options(3), 0.8);
  TrainerOptions one = options;
  one.max_epochs = 1;
  const auto full = root_ / "full";
  auto reference = MakeTrainer(options, full);
  reference->Train(*train_, *val_);
  const auto split = root_ / "split";
  MakeTrainer(one, split)->Train(*train_, *val_);
  auto resumed = MakeTrainer(options, split);
  EXPECT_EQ(resumed->Train(*train_, *val_).start_epoch, 1);
  // Validation reads the average: equal metrics need it restored exactly.
  EXPECT_EQ(DeterministicColumns(full / "metrics.csv"),
            DeterministicColumns(split / "metrics.csv"));
  ExpectSameWeights(reference->model(), resumed->model());
  ExpectSameWeights(LoadLabelerFromCheckpoint(full / "checkpoints/last.pt"),
                    LoadLabelerFromCheckpoint(split / "checkpoints/last.pt"));
  // A checkpoint without an average resumes into an averaged run (the
  // average starts from its weights), and the other way round.
  const auto plain = root_ / "plain";
  TrainerOptions plain_one = Options(1);
  MakeTrainer(plain_one, plain)->Train(*train_, *val_);
  EXPECT_EQ(MakeTrainer(WithAverage(Options(2), 0.8), plain)
                ->Train(*train_, *val_)
                .epochs_completed,
            2);
  auto unaveraged = MakeTrainer(Options(3), plain);
  EXPECT_EQ(unaveraged->Train(*train_, *val_).epochs_completed, 3);
}

TEST(TrainerOptions, DecodeAndValidate) {
  const TrainerOptions options = DecodeTrainerOptions(
      ParseYaml("batch_size: 32\nmax_epochs: 4\nresume: false\n"
                "early_stopping: {patience: 2}\n",
                "t"));
  EXPECT_EQ(options.batch_size, 32);
  EXPECT_EQ(options.max_epochs, 4);
  EXPECT_EQ(options.resume, "never");
  EXPECT_EQ(options.early_stopping.patience, 2);
  EXPECT_THROW(DecodeTrainerOptions(ParseYaml("batch_size: 0\n", "t")),
               ConfigError);
  EXPECT_THROW(DecodeTrainerOptions(ParseYaml("bach_size: 3\n", "t")),
               ConfigError);
  EXPECT_EQ(options.engine, "fast");
  EXPECT_EQ(DecodeTrainerOptions(ParseYaml("engine: torch\n", "t")).engine,
            "torch");
  EXPECT_THROW(DecodeTrainerOptions(ParseYaml("engine: jax\n", "t")),
               ConfigError);
  EXPECT_EQ(options.precision, "fp32");
  EXPECT_EQ(DecodeTrainerOptions(ParseYaml("precision: bf16\n", "t")).precision,
            "bf16");
  EXPECT_THROW(DecodeTrainerOptions(ParseYaml("precision: fp16\n", "t")),
               ConfigError);
  EXPECT_EQ(options.gradient_clip_val, 0.0);
  EXPECT_EQ(DecodeTrainerOptions(ParseYaml("gradient_clip_val: 1.5\n", "t"))
                .gradient_clip_val,
            1.5);
  EXPECT_THROW(DecodeTrainerOptions(ParseYaml("gradient_clip_val: -1\n", "t")),
               ConfigError);
  EXPECT_EQ(options.ema_decay, 0.0);
  EXPECT_EQ(
      DecodeTrainerOptions(ParseYaml("ema_decay: 0.999\n", "t")).ema_decay,
      0.999);
  for (const char* bad : {"ema_decay: 1\n", "ema_decay: -0.1\n"}) {
    EXPECT_THROW(DecodeTrainerOptions(ParseYaml(bad, "t")), ConfigError) << bad;
  }
}

TEST(LayoutMetricsCsv, RoundTripsPerEpochLayoutCounts) {
  std::vector<EpochMetrics> history(2);
  history[0].epoch = 1;
  history[1].epoch = 2;
  history[0].layouts = {
      {.name = "cmu41", .frames = 32, .pairs = 1000, .correct = 250},
      {.name = "a,b.json", .frames = 32, .pairs = 900, .correct = 0}};
  history[1].layouts = {
      {.name = "cmu41", .frames = 32, .pairs = 1000, .correct = 500},
      {.name = "random", .frames = 30, .pairs = 800, .correct = 400}};
  const std::string csv = LayoutMetricsCsv(history);
  EXPECT_EQ(csv,
            "epoch,layout,frames,pairs,correct,accuracy\n"
            "1,cmu41,32,1000,250,0.25\n"
            "1,a;b.json,32,900,0,0\n"
            "2,cmu41,32,1000,500,0.5\n"
            "2,random,30,800,400,0.5\n");
  std::vector<EpochMetrics> parsed(2);
  parsed[0].epoch = 1;
  parsed[1].epoch = 2;
  ParseLayoutMetricsCsv(csv, "ckpt", &parsed);
  ASSERT_EQ(parsed[1].layouts.size(), 2u);
  EXPECT_EQ(parsed[1].layouts[1].name, "random");
  EXPECT_EQ(parsed[1].layouts[1].frames, 30);
  EXPECT_EQ(parsed[1].layouts[1].correct, 400);
  EXPECT_DOUBLE_EQ(parsed[0].layouts[0].accuracy(), 0.25);
  EXPECT_EQ(LayoutMetricsCsv(parsed), csv);
  EXPECT_EQ(LayoutMetricsCsv({}),
            "epoch,layout,frames,pairs,correct,accuracy\n");
  EXPECT_THROW(ParseLayoutMetricsCsv("h\n1,cmu41,3\n", "ckpt", &parsed),
               IoError);
}

}  // namespace
}  // namespace soma
