// End-to-end runs of `soma eval` and `soma label` (issue #6) on the real
// HDM05 and CMU takes, through the `soma` binary.
#include "framework/config/yaml_io.h"
#include "framework/core/file.h"
#include "framework/io/c3d.h"
#include "framework/io/mocap_dataset.h"
#include "framework/testing/testing.h"

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "tests/integration/soma_command.h"
#include <algorithm>
#include <filesystem>
#include <string>
#include <vector>

namespace soma {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

std::string Take(const char* name) {
  return (testing::SharedDataDir() / "c3d" / name).string();
}

ConfigNode Metrics(const fs::path& run_dir) {
  return ParseYaml(ReadFile(run_dir / "metrics.yaml"), "metrics.yaml");
}

/// `soma corrupt` of the HDM05 take with one setting; returns the stem of
/// the corrupted capture (`<stem>.c3d` + ground truth `<stem>.h5`).
fs::path CorruptHdm05(const fs::path& dir, const std::string& setting) {
  std::string err;
  EXPECT_EQ(testing::RunSomaTask(
                dir,
                {"corrupt",
                 "hydra.run.dir=corrupt",
                 "task.files=[" + Take("HDM_mm_01-02_03_120.c3d") + "]",
                 "task.settings=[" + setting + "]"},
                &err),
            0)
      << err;
  return dir / "corrupt" / setting / "HDM_mm_01-02_03_120";
}

/// What a perfect labeller would write for a corrupted take: its points in
/// the columns of their ground-truth labels (REFERENCE 5.4 layout: L label
/// columns, then the frame's null points as `*<k>`). `swap` exchanges the
/// names of two label columns. `unknown` >= 0: a labeller without that
/// label (a subset-layout model), which calls its points null.
void WritePerfectLabels(const fs::path& stem,
                        const fs::path& out,
                        std::pair<int, int> swap = {-1, -1},
                        int unknown = -1) {
  const C3dData in = ReadC3d(stem.string() + ".c3d");
  const DatasetReader gt(stem.string() + ".h5");
  LabeledFrames ids;
  gt.Read(0, gt.num_frames(), &ids);
  const int L = gt.info().num_labels(), K = in.num_points;
  C3dData rec;
  rec.frame_rate = in.frame_rate;
  rec.num_frames = in.num_frames;
  rec.num_points = L + K;
  rec.units = in.units;
  rec.labels = gt.info().labels;
  if (swap.first >= 0)
    std::swap(rec.labels[swap.first], rec.labels[swap.second]);
  for (int k = 0; k < K; ++k) rec.labels.push_back(fmt::format("*{}", k));
  if (unknown >= 0) rec.labels[unknown] = fmt::format("*{}", K);  // unused
  rec.num_file_labels = rec.num_points;
  rec.points.setZero(in.num_frames, 3 * int64_t{rec.num_points});
  rec.residuals.setConstant(in.num_frames, rec.num_points, -1.0f);
  for (int t = 0; t < in.num_frames; ++t) {
    int next_null = L;
    for (int k = 0; k < K; ++k) {
      if (!in.valid(t, k)) continue;
      const int16_t id = ids.frame_labels(t)[k];
      const int column = id < L && id != unknown ? id : next_null++;
      rec.points.row(t).segment<3>(3 * column) =
          in.points.row(t).segment<3>(3 * k);
      rec.residuals(t, column) = 0.0f;
    }
  }
  WriteC3d(out, rec);
}

TEST(EvalTask, CleanTakeAgainstItselfScoresOne) {
  const auto dir = testing::CreateTestDir();
  std::string err;
  ASSERT_EQ(testing::RunSomaTask(dir,
                                 {"eval",
                                  "hydra.run.dir=out",
                                  "task.gt=" + Take("cmu_01_01.c3d"),
                                  "task.rec=" + Take("cmu_01_01.c3d")},
                                 &err),
            0)
      << err;
  const ConfigNode m = Metrics(dir / "out");
  EXPECT_EQ(m.at("acc_mean").AsDouble(), 1.0);
  EXPECT_EQ(m.at("f1_mean").AsDouble(), 1.0);
  EXPECT_EQ(m.at("num_frames").AsDouble(), 2751.0);
  for (const char* f : {"eval.md",
                        "per_frame.csv",
                        "class_report.csv",
                        "confusion.csv",
                        "confusion.png"}) {
    EXPECT_TRUE(fs::exists(dir / "out" / f)) << f;
  }
}

TEST(EvalTask, PerfectAndSwappedLabelsOfACorruptedTake) {
  const auto dir = testing::CreateTestDir();
  const fs::path stem = CorruptHdm05(dir, "OC_05_G_03_BT_00");
  WritePerfectLabels(stem, dir / "perfect.c3d");
  WritePerfectLabels(stem, dir / "swapped.c3d", {0, 1});
  std::string err;
  ASSERT_EQ(
      testing::RunSomaTask(dir,
                           {"eval",
                            "hydra.run.dir=out",
                            "task.gt=" + stem.string() + ".h5",
                            "task.rec=[" + (dir / "perfect.c3d").string() +
                                "," + (dir / "swapped.c3d").string() + "]"},
                           &err),
      0)
      << err;
  const ConfigNode m = Metrics(dir / "out");
  // The first output is the job's headline; ghosts are evaluated as "nan".
  EXPECT_EQ(m.at("acc_mean").AsDouble(), 1.0);
  EXPECT_EQ(m.at("f1_mean").AsDouble(), 1.0);
  EXPECT_EQ(m.at("num_frames").AsDouble(), 3990.0);
  // Two of 41 labels exchanged: about 2/43 of the points are wrong.
  const double mean = m.at("acc_mean_over_runs").AsDouble();
  EXPECT_LT(mean, 1.0);
  EXPECT_GT(mean, 0.95);
  EXPECT_GT(m.at("acc_std_over_runs").AsDouble(), 0.0);
  const std::string md = ReadFile(dir / "out/eval.md");
  EXPECT_THAT(md, HasSubstr("mean ± population std over outputs"));
  // Each output's soma view page, and eval.md's links to its worst frames:
  // none for the perfect labels, frames with the swapped pair otherwise.
  EXPECT_TRUE(fs::exists(dir / "out/view/0_perfect.html"));
  EXPECT_TRUE(fs::exists(dir / "out/view/1_swapped.html"));
  EXPECT_THAT(md, HasSubstr("## Worst frames"));
  EXPECT_THAT(md,
              HasSubstr("`perfect` ([page](view/0_perfect.html)): every "
                        "frame 100%."));
  EXPECT_THAT(md,
              HasSubstr("`swapped` ([page](view/1_swapped.html)): [frame "));
  EXPECT_THAT(md, HasSubstr("(view/1_swapped.html#frame="));
  const std::string confusion = ReadFile(dir / "out/confusion.csv");
  EXPECT_THAT(confusion, HasSubstr("nan"));
}

TEST(EvalTask, SubsetLayoutsRemoveMarkersAndUnknownLabelsCanScoreAsNull) {
  const auto dir = testing::CreateTestDir();
  std::string err;
  // `layout.exclude` removes markers from the corrupted take (Table 4's
  // "markers removed" tests).
  ASSERT_EQ(testing::RunSomaTask(
                dir,
                {"corrupt",
                 "hydra.run.dir=fewer",
                 "task.files=[" + Take("HDM_mm_01-02_03_120.c3d") + "]",
                 "task.settings=[OCE_00_G_00_BT_00]",
                 "layout.exclude=[RBAC,lshn]"},
                &err),
            0)
      << err;
  const DatasetReader fewer(
      (dir / "fewer/OCE_00_G_00_BT_00/HDM_mm_01-02_03_120.h5").string());
  EXPECT_EQ(fewer.info().num_labels(), 39);
  EXPECT_EQ(fewer.info().num_points, 39);
  for (const char* gone : {"RBAC", "LSHN"}) {
    EXPECT_EQ(std::count(fewer.info().labels.begin(),
                         fewer.info().labels.end(),
                         std::string(gone)),
              0)
        << gone;
  }
  EXPECT_NE(testing::RunSomaTask(dir,
                                 {"corrupt",
                                  "hydra.run.dir=bad",
                                  "task.settings=[OCE_00_G_00_BT_00]",
                                  "layout.exclude=[RBAC,XYZ1]"},
                                 &err),
            0);
  EXPECT_THAT(err,
              HasSubstr("layout.exclude: 'XYZ1' is not a label of the layout"));

  // A labeller without label 0 (as a model trained with layout.exclude):
  // its points are null in the output. Counted as errors by default, or
  // scored as null with task.unknown_gt_labels=ghost.
  const fs::path stem = CorruptHdm05(dir, "OCE_00_G_00_BT_00");
  WritePerfectLabels(stem, dir / "subset.c3d", {-1, -1}, 0);
  for (const char* mode : {"wrong", "ghost"}) {
    SCOPED_TRACE(mode);
    ASSERT_EQ(
        testing::RunSomaTask(dir,
                             {"eval",
                              std::string("hydra.run.dir=") + mode,
                              "task.gt=" + stem.string() + ".h5",
                              "task.rec=" + (dir / "subset.c3d").string(),
                              std::string("task.unknown_gt_labels=") + mode},
                             &err),
        0)
        << err;
    const ConfigNode m = Metrics(dir / mode);
    EXPECT_EQ(m.at("unknown_gt_labels").AsDouble(), 1.0);
    if (std::string(mode) == "wrong") {
      EXPECT_LT(m.at("acc_mean").AsDouble(), 0.99);  // 1 of 41 labels lost
      EXPECT_GT(m.at("acc_mean").AsDouble(), 0.95);
    } else {
      EXPECT_EQ(m.at("acc_mean").AsDouble(), 1.0);
    }
  }
}

TEST(EvalTask, BadInputIsOneClearError) {
  const auto dir = testing::CreateTestDir();
  std::string err;
  EXPECT_NE(
      testing::RunSomaTask(dir,
                           {"eval",
                            "hydra.run.dir=out",
                            "task.gt=" + Take("cmu_01_01.c3d"),
                            "task.rec=" + Take("HDM_mm_01-02_03_120.c3d")},
                           &err),
      0);
  EXPECT_THAT(err, HasSubstr("frames, but the ground truth"));
  EXPECT_NE(testing::RunSomaTask(
                dir,
                {"eval", "hydra.run.dir=out2", "task.gt=x.txt", "task.rec=y"},
                &err),
            0);
  EXPECT_THAT(err, HasSubstr("x.txt: ground truth must be"));
}

TEST(LabelTask, TinyModelLabelsACorruptedTakeAndIsScored) {
  const auto dir = testing::CreateTestDir();
  std::string err;
  // A deliberately tiny model trained for one short epoch: this tests the
  // pipeline, not the accuracy.
  ASSERT_EQ(testing::RunSomaTask(dir,
                                 {"train",
                                  "hydra.run.dir=train",
                                  "model.d_model=16",
                                  "model.hidden=16",
                                  "model.backbone.num_layers=1",
                                  "model.backbone.num_heads=2",
                                  "train.train_frames=128",
                                  "train.val_frames=64",
                                  "train.batch_size=32",
                                  "train.max_epochs=1",
                                  "train.progress=false"},
                                 &err),
            0)
      << err;
  const fs::path stem = CorruptHdm05(dir, "OC_05_G_03_BT_50");
  const std::string checkpoint = (dir / "train/checkpoints/best.pt").string();
  for (const char* mode : {"false", "true"}) {
    const std::string run = std::string("label_tracklet_") + mode;
    ASSERT_EQ(testing::RunSomaTask(dir,
                                   {"label",
                                    "hydra.run.dir=" + run,
                                    "task.input=" + stem.string() + ".c3d",
                                    "task.checkpoint=" + checkpoint,
                                    std::string("task.tracklet=") + mode},
                                   &err),
              0)
        << err;
    const fs::path out = dir / run / "HDM_mm_01-02_03_120_labeled.c3d";
    const C3dData labeled = ReadC3d(out);
    EXPECT_EQ(labeled.num_frames, 3990);
    ASSERT_GE(labeled.num_points, 41);
    EXPECT_EQ(labeled.labels[0], "C7");  // model label order (sorted)
    const DatasetReader sidecar(dir / run / "HDM_mm_01-02_03_120_labels.h5");
    EXPECT_EQ(sidecar.num_frames(), 3990);
    EXPECT_EQ(sidecar.info().attributes.at("mode"),
              std::string(mode) == "true" ? "tracklet" : "per_frame");
    const std::vector<float> confidence = sidecar.ReadPointArray("confidence");
    EXPECT_TRUE(std::all_of(confidence.begin(), confidence.end(), [](float c) {
      return c >= 0.0f && c <= 1.0f;
    }));
    const std::vector<float> column = sidecar.ReadPointArray("column");
    EXPECT_EQ(*std::max_element(column.begin(), column.end()),
              94 - 1);  // BT_50 adds 50 trajectories to 41 + 3 ghosts

    ASSERT_EQ(testing::RunSomaTask(dir,
                                   {"eval",
                                    "hydra.run.dir=eval_" + run,
                                    "task.gt=" + stem.string() + ".h5",
                                    "task.rec=" + out.string()},
                                   &err),
              0)
        << err;
    const double acc = Metrics(dir / ("eval_" + run)).at("acc_mean").AsDouble();
    EXPECT_GE(acc, 0.0);
    EXPECT_LE(acc, 1.0);
  }
  // A Vicon Nexus export: the Plug-in Gait model's angles, forces ... and
  // virtual points are no optical points; only the 39 markers are labelled
  // and written.
  const fs::path nexus =
      testing::SharedDataDir() / "c3d" / "Movement_trial.c3d";
  ASSERT_EQ(testing::RunSomaTask(dir,
                                 {"label",
                                  "hydra.run.dir=label_nexus",
                                  "task.input=" + nexus.string(),
                                  "task.checkpoint=" + checkpoint},
                                 &err),
            0)
      << err;
  EXPECT_THAT(err, HasSubstr("are model outputs"));
  const C3dData input = ReadC3d(nexus);
  const std::vector<bool> outputs = ModelOutputColumns(input);
  const C3dData labeled =
      ReadC3d(dir / "label_nexus" / "Movement_trial_labeled.c3d");
  ASSERT_EQ(labeled.num_frames, input.num_frames);
  for (int t = 0; t < input.num_frames; ++t) {
    int markers = 0;
    for (int k = 0; k < input.num_points; ++k) {
      const Eigen::Vector3f x = input.Point(t, k);
      markers += !outputs[k] && input.valid(t, k) && !(x.array() == 0).all();
    }
    ASSERT_EQ(labeled.valid.row(t).count(), markers) << "frame " << t;
  }

  // Appendix A on the same tiny model (one attention layer).
  ASSERT_EQ(
      testing::RunSomaTask(dir,
                           {"attention_span",
                            "hydra.run.dir=span",
                            "task.checkpoints=" + checkpoint,
                            "task.input=" + (testing::SharedDataDir() / "c3d" /
                                             "HDM_mm_01-02_03_120.c3d")
                                                .string(),
                            "task.max_frames=64"},
                           &err),
      0)
      << err;
  const double span = Metrics(dir / "span").at("span_layer1_m").AsDouble();
  EXPECT_GT(span, 0.05);  // metres: a body-sized spread, not a NaN or 0
  EXPECT_LT(span, 2.0);
  EXPECT_TRUE(fs::exists(dir / "span/attention_span.png"));
  EXPECT_NE(ReadFile(dir / "span/attention_span.md").find("| 1 |"),
            std::string::npos);
  // The markers are placed by the model's training layout (its run's
  // .hydra/config.yaml), not by this run's layout group: a layout without
  // RBAC does not matter unless task.use_training_layout=false.
  const std::vector<std::string> span_args = {
      "attention_span",
      "task.checkpoints=" + checkpoint,
      "task.input=" +
          (testing::SharedDataDir() / "c3d" / "HDM_mm_01-02_03_120.c3d")
              .string(),
      "task.max_frames=16",
      "layout.exclude=[RBAC]"};
  std::vector<std::string> args = span_args;
  args.push_back("hydra.run.dir=span_trained_layout");
  ASSERT_EQ(testing::RunSomaTask(dir, args, &err), 0) << err;
  EXPECT_THAT(ReadFile(dir / "span_trained_layout/attention_span.md"),
              HasSubstr("(the layout of " +
                        (dir / "train/.hydra/config.yaml").string() + ")"));
  args = span_args;
  args.push_back("hydra.run.dir=span_run_layout");
  args.push_back("task.use_training_layout=false");
  EXPECT_NE(testing::RunSomaTask(dir, args, &err), 0);
  EXPECT_THAT(err, HasSubstr("the model's label 'RBAC' is not in the layout"));
  EXPECT_NE(
      testing::RunSomaTask(dir,
                           {"label",
                            "hydra.run.dir=bad",
                            "task.input=" + stem.string() + ".c3d",
                            "task.checkpoint=" + (dir / "nope.pt").string()},
                           &err),
      0);
  EXPECT_THAT(err, HasSubstr("nope.pt"));
}

}  // namespace
}  // namespace soma
