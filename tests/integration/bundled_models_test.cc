// The bundled models (models/) and the main job (README command 1): every
// bundled model labels the bundled take at least as well as its card says
// (weights and code must not drift apart), `soma label` picks a bundled
// model by the capture's labels, and `soma` alone runs the real main job.
#include "framework/config/yaml_io.h"
#include "framework/core/file.h"
#include "framework/testing/testing.h"
#include "framework/train/model_zoo.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "tests/integration/soma_command.h"
#include <filesystem>
#include <string>
#include <vector>

namespace soma {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

ConfigNode Metrics(const fs::path& run_dir) {
  return ParseYaml(ReadFile(run_dir / "metrics.yaml"), "metrics.yaml");
}

TEST(BundledModels, EachScoresTheBundledTakeAsItsCardSays) {
  const std::vector<BundledModel> models =
      ListBundledModels(testing::SourceDir() / "models");
  ASSERT_FALSE(models.empty());
  for (const BundledModel& model : models) {
    SCOPED_TRACE(model.name);
    const fs::path dir = testing::CreateTestDir();
    std::string err;
    ASSERT_EQ(
        testing::RunSomaTask(
            dir,
            {"label_eval", "task.model=" + model.name, "hydra.run.dir=run"},
            &err),
        0)
        << err;
    const ConfigNode metrics = Metrics(dir / "run");
    const ConfigNode& card = model.card.at("bundled_take");
    for (const char* key : {"per_frame_acc", "tracklet_acc"}) {
      const double expected = card.at(key).AsDouble();
      const double measured = metrics.at(key).AsDouble();
      // At most 1 point below the card; better is fine (and worth a new card).
      EXPECT_GE(measured, expected - 0.01)
          << key << ": the card says " << expected << ", measured " << measured;
    }
    EXPECT_THAT(ReadFile(dir / "run/summary.md"),
                HasSubstr("bundled model `" + model.name + "`"));
  }
}

TEST(BundledModels, LabelWithoutACheckpointPicksOneByTheCapturesLabels) {
  const fs::path dir = testing::CreateTestDir();
  std::string err;
  ASSERT_EQ(testing::RunSomaTask(
                dir,
                {"label",
                 (testing::SourceDir() / "data/cmu_01_01_f0-599.c3d").string(),
                 "hydra.run.dir=run"},
                &err),
            0)
      << err;
  const std::string log = ReadFile(dir / "run/soma.log");
  EXPECT_THAT(log, HasSubstr("label: bundled model 'cmu41'"));
  EXPECT_TRUE(fs::exists(dir / "run/cmu_01_01_f0-599_labeled.c3d"));
}

TEST(BundledModels, AnUnlabelledCaptureListsTheModelsInOneLine) {
  const fs::path dir = testing::CreateTestDir();
  std::string err;
  EXPECT_EQ(
      testing::RunSomaTask(
          dir,
          {"label",
           (testing::SharedDataDir() / "c3d/phasespace_sample.c3d").string(),
           "hydra.run.dir=run"},
          &err),
      1);
  EXPECT_THAT(err, HasSubstr("no bundled model matches the capture's labels"));
  EXPECT_THAT(err, HasSubstr("cmu41 (layout cmu41, 41 labels)"));
  EXPECT_THAT(err, HasSubstr("soma train"));
}

TEST(MainJob, SomaAloneLabelsAndScoresTheBundledTake) {
  const fs::path dir = testing::CreateTestDir();
  std::string err;
  ASSERT_EQ(testing::RunSomaTask(dir, {"hydra.run.dir=run"}, &err), 0) << err;
  const fs::path run = dir / "run";
  for (const char* f : {"summary.md",
                        "OC_05_G_03_BT_00/cmu_01_01_f0-599.c3d",
                        "OC_05_G_03_BT_00/cmu_01_01_f0-599.h5",
                        "per_frame/cmu_01_01_f0-599_labeled.c3d",
                        "per_frame/eval.md",
                        "per_frame/confusion.png",
                        "tracklet/cmu_01_01_f0-599_labeled.c3d",
                        "tracklet/eval.md",
                        "tracklet/confusion.png"}) {
    EXPECT_TRUE(fs::exists(run / f)) << f;
  }
  const ConfigNode metrics = Metrics(run);
  EXPECT_EQ(metrics.at("frames").AsDouble(), 600);
  EXPECT_GT(metrics.at("frames_per_s").AsDouble(), 0);
  // Tracklet voting never loses to per-frame labels on this clean clip.
  EXPECT_GE(metrics.at("tracklet_acc").AsDouble(),
            metrics.at("per_frame_acc").AsDouble() - 0.005);
  const std::string log = ReadFile(run / "soma.log");
  EXPECT_THAT(log, HasSubstr("label_eval: per_frame accuracy"));
  EXPECT_THAT(log, HasSubstr("label_eval: tracklet  accuracy"));
}

}  // namespace
}  // namespace soma
