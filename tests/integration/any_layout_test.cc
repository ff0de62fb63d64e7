// model=soma_any_layout end to end (issue #25 item 1, first slice): `soma
// train` on the synthesizer's layout on the fast engine (its point side on
// the kernels, its label side on torch), the checkpoint holds the layout's
// label slots and loads, and `soma label` labels the bundled clip with it.
// Second slice: training with a layout per placement block
// (synth/layout_sampler=builtin), resumed, recorded in the checkpoint; and
// `soma label` / `soma label_eval` with a layout given at label time. Third
// slice: the random pool, through an HDF5 dataset of slotted frames.
#include "framework/body/marker_layout.h"
#include "framework/body/procedural_body.h"
#include "framework/config/app.h"
#include "framework/config/yaml_io.h"
#include "framework/core/file.h"
#include "framework/eval/calibration.h"
#include "framework/io/c3d.h"
#include "framework/model/label_encoder.h"
#include "framework/model/labeler.h"
#include "framework/tasks/task.h"
#include "framework/testing/testing.h"
#include "framework/train/trainer.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <torch/torch.h>

#include "tests/integration/soma_command.h"
#include <algorithm>
#include <filesystem>
#include <string>
#include <vector>

namespace soma {
namespace {

namespace fs = std::filesystem;

int CountOccurrences(const std::string& text, const std::string& needle) {
  int count = 0;
  for (size_t at = text.find(needle); at != std::string::npos;
       at = text.find(needle, at + 1)) {
    ++count;
  }
  return count;
}

/// `soma train` overrides of a tiny layout-conditioned model, shared by the
/// tests below: the run dir, epochs and data sizes vary.
std::vector<std::string> TinyTrainArgs(const fs::path& run,
                                       int epochs,
                                       int train_frames,
                                       int val_frames) {
  return {"task=train",
          "model=soma_any_layout",
          "scale=cpu",
          "hydra.run.dir=" + run.string(),
          "model.d_model=16",
          "model.hidden=16",
          "model.backbone.num_layers=1",
          "model.backbone.num_heads=2",
          "model.label_encoder.num_heads=2",
          "model.label_encoder.num_layers=1",
          "normalization.num_iters=5",
          "train.batch_size=16",
          "train.train_frames=" + std::to_string(train_frames),
          "train.val_frames=" + std::to_string(val_frames),
          "train.max_epochs=" + std::to_string(epochs),
          "train.progress=false",
          "threads=1"};
}

TEST(AnyLayout, TrainsSavesLoadsAndLabelsTheBundledClip) {
  const fs::path dir = testing::CreateTestDir();
  const fs::path run = dir / "train";
  const std::string configs = (testing::SourceDir() / "configs").string();
  auto train_args = [&](int epochs) {
    std::vector<std::string> args = TinyTrainArgs(run, epochs, 32, 16);
    args.push_back("train.engine=fast");
    return args;
  };
  ASSERT_EQ(RunHydraApp(train_args(1), configs, "config", RunConfiguredTask),
            0);
  // The fast engine trains it (its label side on torch autograd).
  const std::string log = ReadFile(run / "soma.log");
  EXPECT_EQ(CountOccurrences(log, "train: fast engine ("), 1) << log;
  EXPECT_EQ(CountOccurrences(log, "cannot train this model"), 0) << log;

  // The checkpoint is a conditioned labeler holding the training layout's
  // label slots (cmu41 on the procedural body, the default config).
  const Labeler model =
      LoadLabelerFromCheckpoint(run / "checkpoints" / "best.pt");
  ASSERT_TRUE(model->conditioned());
  ASSERT_EQ(model->num_labels(), 41);
  const BodyModel body = MakeProceduralBody();
  const torch::Tensor expected = LayoutSlotDescriptors(
      body, MakeBuiltinLayout(body, "cmu41"), model->descriptor_width());
  EXPECT_TRUE(torch::equal(model->layout_descriptors, expected));

  // Same run dir, one more epoch: resumes from last.pt (weights, optimizer
  // and the label slots).
  ASSERT_EQ(RunHydraApp(train_args(2), configs, "config", RunConfiguredTask),
            0);
  const std::string metrics = ReadFile(run / "metrics.csv");
  EXPECT_EQ(std::count(metrics.begin(), metrics.end(), '\n'), 3) << metrics;

  // `soma label` with it on the bundled clip.
  std::string err;
  const fs::path clip = testing::SourceDir() / "data" / "cmu_01_01_f0-599.c3d";
  ASSERT_EQ(testing::RunSomaTask(
                dir,
                {"label",
                 "hydra.run.dir=label",
                 "task.input=" + clip.string(),
                 "task.checkpoint=" + (run / "checkpoints/best.pt").string()},
                &err),
            0)
      << err;
  const C3dData labeled =
      ReadC3d(dir / "label" / "cmu_01_01_f0-599_labeled.c3d");
  EXPECT_EQ(labeled.num_frames, 600);
  ASSERT_GE(labeled.num_points, 41);
  EXPECT_EQ(labeled.labels[0], "C7");  // the checkpoint's label order
}

std::vector<std::string> SampledTrainArgs(const fs::path& run, int epochs) {
  std::vector<std::string> args = TinyTrainArgs(run, epochs, 64, 128);
  args.insert(args.begin() + 2, "synth/layout_sampler=builtin");
  return args;
}

TEST(AnyLayout, TrainsOnALayoutPerPlacementBlockAndResumes) {
  const fs::path dir = testing::CreateTestDir();
  const fs::path run = dir / "train";
  const std::string configs = (testing::SourceDir() / "configs").string();
  ASSERT_EQ(RunHydraApp(
                SampledTrainArgs(run, 1), configs, "config", RunConfiguredTask),
            0);
  const std::string log = ReadFile(run / "soma.log");
  EXPECT_THAT(log,
              ::testing::HasSubstr("96 label slots, a layout per placement "
                                   "block sampled from [cmu41, pig39, "
                                   "soma53]"));
  // Validation accuracy per layout, one line per epoch.
  EXPECT_EQ(CountOccurrences(log,
                             "epoch 1 validation accuracy per layout: "
                             "cmu41 "),
            1)
      << log;

  // The checkpoint: a conditioned labeler over 96 slots, no stored layout
  // (each batch brought its own), the sampler recorded with the model.
  const fs::path best = run / "checkpoints" / "best.pt";
  const CheckpointInfo info = ReadCheckpointInfo(best);
  const ConfigNode* sampler = info.model_config.Find("layout_sampler");
  ASSERT_NE(sampler, nullptr);
  EXPECT_EQ(sampler->at("name").AsString(), "builtin");
  EXPECT_EQ(info.labels.size(), 96u);
  const Labeler model = LoadLabelerFromCheckpoint(best);
  ASSERT_TRUE(model->conditioned());
  EXPECT_EQ(model->num_labels(), 96);
  EXPECT_FALSE(model->layout_descriptors.ne(0).any().item<bool>());

  // soma calibrate labels each validation frame against its own sampled
  // layout, as the training's validation did: the same accuracy.
  std::string err;
  ASSERT_EQ(testing::RunSomaTask(
                dir,
                {"calibrate",
                 "hydra.run.dir=calibrate",
                 "task.checkpoint=" + best.string(),
                 "task.output=" + (dir / "calibration.yaml").string()},
                &err),
            0)
      << err;
  EXPECT_THAT(ReadFile(dir / "calibrate" / "soma.log"),
              ::testing::HasSubstr("each frame is labelled against its own"));
  const ConfigNode calibrated =
      ParseYaml(ReadFile(dir / "calibrate" / "metrics.yaml"), "metrics.yaml");
  const ConfigNode trained =
      ParseYaml(ReadFile(run / "metrics.yaml"), "metrics.yaml");
  EXPECT_NEAR(calibrated.at("accuracy").AsDouble(),
              trained.at("val_acc").AsDouble(),
              1e-3);
  EXPECT_GT(ReadCalibration(dir / "calibration.yaml").temperature, 0.0);

  // Resumes in the same run dir.
  ASSERT_EQ(RunHydraApp(
                SampledTrainArgs(run, 2), configs, "config", RunConfiguredTask),
            0);
  const std::string metrics = ReadFile(run / "metrics.csv");
  EXPECT_EQ(std::count(metrics.begin(), metrics.end(), '\n'), 3) << metrics;
  EXPECT_THAT(ReadFile(run / "soma.log"),
              ::testing::HasSubstr("train: resumed from"));
  // layout_metrics.csv: a row per epoch and layout, epoch 1's rows carried
  // through the resume by the checkpoint.
  const std::string layouts = ReadFile(run / "layout_metrics.csv");
  EXPECT_EQ(std::count(layouts.begin(), layouts.end(), '\n'), 1 + 2 * 3)
      << layouts;
  EXPECT_THAT(layouts, ::testing::HasSubstr("\n1,pig39,"));
  EXPECT_THAT(layouts, ::testing::HasSubstr("\n2,soma53,"));

  // A fixed-head model cannot train on sampled layouts: one line, non-zero.
  std::vector<std::string> fixed = SampledTrainArgs(dir / "fixed", 1);
  fixed[1] = "model=soma";
  fixed.erase(std::remove_if(fixed.begin(),
                             fixed.end(),
                             [](const std::string& a) {
                               return a.rfind("model.label_encoder", 0) == 0;
                             }),
              fixed.end());
  EXPECT_NE(RunHydraApp(fixed, configs, "config", RunConfiguredTask), 0);
  EXPECT_THAT(ReadFile(dir / "fixed" / "soma.log"),
              ::testing::HasSubstr("use model=soma_any_layout"));
}

TEST(AnyLayout, LabelsWithALayoutGivenAtLabelTime) {
  const fs::path dir = testing::CreateTestDir();
  const std::string configs = (testing::SourceDir() / "configs").string();
  // A conditioned model with 60 slots trained on sampled layouts, and a
  // fixed-head model trained on cmu41 (one tiny epoch each).
  std::vector<std::string> sampled = SampledTrainArgs(dir / "sampled", 1);
  sampled.push_back("synth.layout_sampler.max_labels=60");
  ASSERT_EQ(RunHydraApp(sampled, configs, "config", RunConfiguredTask), 0);
  std::vector<std::string> fixed = SampledTrainArgs(dir / "fixed", 1);
  fixed[1] = "model=soma";
  fixed.erase(std::remove_if(fixed.begin(),
                             fixed.end(),
                             [](const std::string& a) {
                               return a.rfind("model.label_encoder", 0) == 0 ||
                                      a.rfind("synth/layout_sampler", 0) == 0;
                             }),
              fixed.end());
  ASSERT_EQ(RunHydraApp(fixed, configs, "config", RunConfiguredTask), 0);
  const fs::path clip = testing::SourceDir() / "data" / "cmu_01_01_f0-599.c3d";
  auto label = [&](const std::string& run,
                   const fs::path& model,
                   const std::string& layout,
                   std::string* err) {
    std::vector<std::string> args = {
        "label",
        "hydra.run.dir=" + run,
        "task.input=" + clip.string(),
        "task.checkpoint=" + (model / "checkpoints/best.pt").string()};
    if (!layout.empty()) args.push_back(layout);
    return testing::RunSomaTask(dir, args, err);
  };
  const BodyModel body = MakeProceduralBody();
  std::string err;
  for (const std::string layout : {"pig39", "cmu41"}) {
    SCOPED_TRACE(layout);
    ASSERT_EQ(label(layout, dir / "sampled", "layout=" + layout, &err), 0)
        << err;
    EXPECT_EQ(CountOccurrences(
                  ReadFile(dir / layout / "soma.log"),
                  "label: layout '" + layout + "' (" + layout.substr(3) +
                      " labels, given at label time) on the checkpoint's "
                      "body 'procedural', for a layout-conditioned model "
                      "with 60 label slots"),
              1);
    // The labelled trajectories are that layout's labels, in its order.
    const C3dData labeled =
        ReadC3d(dir / layout / "cmu_01_01_f0-599_labeled.c3d");
    EXPECT_EQ(labeled.num_frames, 600);
    const std::vector<std::string> expected =
        MakeBuiltinLayout(body, layout).Labels();
    ASSERT_GE(labeled.labels.size(), expected.size());
    EXPECT_EQ(std::vector<std::string>(
                  labeled.labels.begin(),
                  labeled.labels.begin() +
                      static_cast<std::ptrdiff_t>(expected.size())),
              expected);
  }
  // label_eval with a layout given at label time: the take is scored on
  // that layout's labels.
  ASSERT_EQ(testing::RunSomaTask(
                dir,
                {"label_eval",
                 "hydra.run.dir=eval",
                 "task.input=" + clip.string(),
                 "task.checkpoint=" +
                     (dir / "sampled" / "checkpoints/best.pt").string(),
                 "layout=cmu41"},
                &err),
            0)
      << err;
  const C3dData evaluated =
      ReadC3d(dir / "eval" / "per_frame" / "cmu_01_01_f0-599_labeled.c3d");
  EXPECT_EQ(evaluated.labels[0], MakeBuiltinLayout(body, "cmu41").Labels()[0]);
  // A layout that names the take's markers by aliases (Plug-in Gait's LASI,
  // RASI, LPSI, RPSI for the CMU take's LFWT, RFWT, LBWT, RBWT): the take is
  // read under the canonical names, so those markers are scored, not lost.
  ASSERT_EQ(testing::RunSomaTask(
                dir,
                {"label_eval",
                 "hydra.run.dir=eval_pig39",
                 "task.input=" + clip.string(),
                 "task.checkpoint=" +
                     (dir / "sampled" / "checkpoints/best.pt").string(),
                 "layout=pig39"},
                &err),
            0)
      << err;
  const std::string pig39_log = ReadFile(dir / "eval_pig39" / "soma.log");
  for (const char* alias : {"LASI", "RASI", "LPSI", "RPSI"}) {
    EXPECT_THAT(pig39_log,
                ::testing::Not(::testing::ContainsRegex(
                    std::string("labels are not in .*") + alias)))
        << pig39_log;
  }

  // `soma stream` with a layout given at label time: the live labels are
  // that layout's, on the optimised forward (the layout's label keys folded
  // into its classifier).
  ASSERT_EQ(testing::RunSomaTask(
                dir,
                {"stream",
                 "hydra.run.dir=stream",
                 "task.c3d.path=" + clip.string(),
                 "task.c3d.realtime=false",
                 "task.c3d.max_frames=40",
                 "task.checkpoint=" +
                     (dir / "sampled" / "checkpoints/best.pt").string(),
                 "layout=cmu41"},
                &err),
            0)
      << err;
  const std::string stream_log = ReadFile(dir / "stream" / "soma.log");
  EXPECT_EQ(CountOccurrences(stream_log,
                             "label: layout 'cmu41' (41 labels, given at "
                             "label time)"),
            1);
  EXPECT_EQ(CountOccurrences(stream_log, "-> 60 labels (fast path"), 1);
  const C3dData streamed =
      ReadC3d(dir / "stream" / "cmu_01_01_f0-599_labeled.c3d");
  EXPECT_EQ(streamed.num_frames, 40);
  const std::vector<std::string> cmu41 =
      MakeBuiltinLayout(body, "cmu41").Labels();
  ASSERT_GE(streamed.labels.size(), cmu41.size());
  EXPECT_EQ(
      std::vector<std::string>(
          streamed.labels.begin(),
          streamed.labels.begin() + static_cast<std::ptrdiff_t>(cmu41.size())),
      cmu41);

  // A layout larger than the model's slots: one line, non-zero, both counts.
  EXPECT_NE(label("big", dir / "sampled", "layout=superset89", &err), 0);
  EXPECT_THAT(err,
              ::testing::HasSubstr("layout 'superset89' has 89 labels, more "
                                   "than the 60 label slots of checkpoint"));
  // A fixed-head model and another layout: refused, naming both.
  EXPECT_NE(label("fixed_pig", dir / "fixed", "layout=pig39", &err), 0);
  EXPECT_THAT(err,
              ::testing::HasSubstr("layout 'pig39' (39 labels) differs from "
                                   "the layout 'cmu41' (41 labels) that "
                                   "checkpoint"));
  // ... its own layout given explicitly is fine.
  EXPECT_EQ(label("fixed_cmu", dir / "fixed", "layout=cmu41", &err), 0) << err;
}

TEST(AnyLayout, TrainsOnADatasetOfRandomPoolLayouts) {
  // Third slice: `soma synth` with synth/layout_sampler=mixed writes slotted
  // frames (a small random pool beside the listed layouts) and their slot
  // table to HDF5; `soma train task.data=hdf5` trains the conditioned model
  // on them and records the dataset as its sampler.
  const fs::path dir = testing::CreateTestDir();
  const std::string configs = (testing::SourceDir() / "configs").string();
  for (const std::string split : {"train", "val"}) {
    ASSERT_EQ(RunHydraApp({"task=synth",
                           "synth/layout_sampler=mixed",
                           "synth.layout_sampler.random_layouts=8",
                           "synth.layout_sampler.max_labels=72",
                           "scale=cpu",
                           "task.num_frames=128",
                           "task.split=" + split,
                           "task.progress=false",
                           "threads=1",
                           "hydra.run.dir=" + (dir / split).string()},
                          configs,
                          "config",
                          RunConfiguredTask),
              0)
        << split;
  }
  const fs::path run = dir / "run";
  std::vector<std::string> args = TinyTrainArgs(run, 1, 64, 64);
  args.push_back("task.data=hdf5");
  args.push_back("task.train_file=" + (dir / "train" / "synth.h5").string());
  args.push_back("task.val_file=" + (dir / "val" / "synth.h5").string());
  ASSERT_EQ(RunHydraApp(args, configs, "config", RunConfiguredTask), 0);
  const std::string log = ReadFile(run / "soma.log");
  EXPECT_THAT(log,
              ::testing::HasSubstr("72 label slots, a layout per placement "
                                   "block sampled from [cmu41, pig39, "
                                   "soma53, random]"));
  EXPECT_THAT(log, ::testing::HasSubstr("random 0."));  // per-layout val
  const CheckpointInfo info =
      ReadCheckpointInfo(run / "checkpoints" / "best.pt");
  const ConfigNode* sampler = info.model_config.Find("layout_sampler");
  ASSERT_NE(sampler, nullptr);
  EXPECT_EQ(sampler->at("dataset").AsString(),
            (dir / "train" / "synth.h5").string());
  EXPECT_EQ(info.labels.size(), 72u);
}

}  // namespace
}  // namespace soma
