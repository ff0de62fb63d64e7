// The synthesizer built from the project config (tasks/components.h) and the
// synth task writing byte-identical datasets (moved from
// tests/synth/synthesizer_test.cc: they compose configs/ and build through
// tasks/, above the synth module).
#include "framework/config/compose.h"
#include "framework/config/interpolation.h"
#include "framework/config/override.h"
#include "framework/io/mocap_dataset.h"
#include "framework/registry/registry.h"
#include "framework/synth/synthesizer.h"
#include "framework/tasks/components.h"
#include "framework/tasks/task.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

namespace soma {

// framework/tasks/synth_task.cc
void RegisterSynthTask(Registry<Task>& registry);

namespace {

bool SameFrames(const LabeledFrames& a,
                int64_t a_first,
                const LabeledFrames& b,
                int64_t b_first,
                int64_t count) {
  if (a.num_points != b.num_points) return false;
  const int n = a.num_points;
  return std::memcmp(a.frame_points(a_first),
                     b.frame_points(b_first),
                     sizeof(float) * 3 * n * count) == 0 &&
         std::memcmp(a.frame_labels(a_first),
                     b.frame_labels(b_first),
                     sizeof(int16_t) * n * count) == 0;
}

ConfigNode ComposeConfig(const std::vector<std::string>& overrides) {
  const std::string configs = (testing::SourceDir() / "configs").string();
  ComposeRequest request{.search_path = {configs}};
  for (const std::string& text : overrides) {
    request.overrides.push_back(ParseOverride(text));
  }
  const ComposeResult result = Compose(request);
  ConfigNode resolved = Resolve(result.root, DefaultResolvers());
  resolved.Erase("hydra");
  return resolved;
}

TEST(BuildSynthesizer, FromTheProjectConfig) {
  const ConfigNode cfg = ComposeConfig({"motion.clips_per_type=1",
                                        "motion.duration_s=1.0",
                                        "synth.layouts=[cmu41,soma53]"});
  BuildContext ctx(3, "");
  const Synthesizer synth = BuildSynthesizer(cfg, Split::kTrain, ctx);
  EXPECT_EQ(synth.num_layouts(), 2);
  EXPECT_EQ(synth.num_labels(), 53);
  EXPECT_EQ(synth.num_points(), 56);  // b_c_g: 3 ghost slots
  EXPECT_EQ(synth.noise().stage_names(),
            (std::vector<std::string>{"occlusion", "ghosts", "permutation"}));
  LabeledFrames frames;
  synth.Generate(0, 0, 64, &frames, 2);
  EXPECT_EQ(frames.num_frames(), 64);
}

TEST(SynthTask, WritesByteIdenticalDatasets) {
  // A local registry, so the test does not depend on RegisterTasks().
  Registry<Task> tasks("task");
  RegisterSynthTask(tasks);
  const std::filesystem::path dir = testing::CreateTestDir();
  std::vector<std::string> files;
  for (int run = 0; run < 2; ++run) {
    const ConfigNode cfg = ComposeConfig({"task=synth",
                                          "task.num_frames=3000",
                                          "task.block_size=1000",
                                          "task.progress=false",
                                          "motion.clips_per_type=1",
                                          "motion.duration_s=1.0",
                                          "seed=17"});
    RunContext ctx;
    ctx.output_dir = dir / std::to_string(run);
    std::filesystem::create_directories(ctx.output_dir);
    ctx.seed = 17;
    ctx.num_threads = run + 1;
    BuildContext build(ctx.seed, ctx.output_dir.string());
    tasks
        .Create(
            "synth", internal::CreatorNode(cfg.at("task"), ConfigNode()), build)
        ->Run(cfg, ctx);
    files.push_back((ctx.output_dir / "synth.h5").string());
  }
  auto bytes = [](const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), {});
  };
  EXPECT_EQ(bytes(files[0]), bytes(files[1]));
  const DatasetReader reader(files[0]);
  EXPECT_EQ(reader.num_frames(), 3000);
  EXPECT_EQ(reader.info().num_points, 44);
  EXPECT_EQ(reader.info().seed, 17u);
  LabeledFrames read;
  reader.Read(1500, 10, &read);
  BuildContext build(17, "");
  const Synthesizer synth = BuildSynthesizer(
      ComposeConfig(
          {"motion.clips_per_type=1", "motion.duration_s=1.0", "seed=17"}),
      Split::kTrain,
      build);
  LabeledFrames expected;
  synth.Generate(17, 1500, 10, &expected);
  EXPECT_TRUE(SameFrames(read, 0, expected, 0, 10));
}

}  // namespace
}  // namespace soma
