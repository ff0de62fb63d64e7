// `soma train` end to end on a tiny synthetic setup (in process): outputs,
// reported metrics, and resume by re-running in the same run dir.
#include "framework/config/app.h"
#include "framework/config/yaml_io.h"
#include "framework/core/file.h"
#include "framework/tasks/task.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <string>
#include <vector>

namespace soma {
namespace {

namespace fs = std::filesystem;

std::vector<std::string> TinyTrainArgs(
    const fs::path& run_dir,
    int epochs,
    const std::string& synth_data = "stream") {
  return {"task=train",
          "train.synth_data=" + synth_data,
          "scale=cpu",
          "hydra.run.dir=" + run_dir.string(),
          "model.d_model=16",
          "model.hidden=16",
          "model.backbone.num_layers=1",
          "model.backbone.num_heads=2",
          "normalization.num_iters=5",
          "train.batch_size=16",
          "train.train_frames=32",
          "train.val_frames=16",
          "train.max_epochs=" + std::to_string(epochs),
          "train.progress=false",
          "threads=1"};
}

int CountLines(const std::string& text) {
  return static_cast<int>(std::count(text.begin(), text.end(), '\n'));
}

TEST(TrainTask, TrainsWritesOutputsAndResumes) {
  const fs::path dir = testing::CreateTestDir() / "run";
  const std::string configs = (testing::SourceDir() / "configs").string();
  ASSERT_EQ(
      RunHydraApp(TinyTrainArgs(dir, 1), configs, "config", RunConfiguredTask),
      0);
  for (const char* file : {"metrics.csv",
                           "loss.png",
                           "accuracy.png",
                           "checkpoints/last.pt",
                           "checkpoints/best.pt",
                           "metrics.yaml"}) {
    EXPECT_TRUE(fs::exists(dir / file)) << file;
  }
  EXPECT_EQ(CountLines(ReadFile(dir / "metrics.csv")), 2);
  const ConfigNode metrics =
      ParseYaml(ReadFile(dir / "metrics.yaml"), "metrics.yaml");
  EXPECT_GE(metrics.at("val_acc").AsDouble(), 0.0);
  EXPECT_EQ(metrics.at("epochs").AsDouble(), 1.0);
  // Same run dir, more epochs: continues from last.pt.
  ASSERT_EQ(
      RunHydraApp(TinyTrainArgs(dir, 2), configs, "config", RunConfiguredTask),
      0);
  EXPECT_EQ(CountLines(ReadFile(dir / "metrics.csv")), 3);
}

TEST(TrainTask, SynthPoolIsReshuffledAcrossEpochs) {
  const fs::path dir = testing::CreateTestDir() / "pool";
  const std::string configs = (testing::SourceDir() / "configs").string();
  ASSERT_EQ(
      RunHydraApp(
          TinyTrainArgs(dir, 2, "pool"), configs, "config", RunConfiguredTask),
      0);
  EXPECT_EQ(CountLines(ReadFile(dir / "metrics.csv")), 3);
}

}  // namespace
}  // namespace soma
