// `soma synth`: writes a synthetic labelled dataset (HDF5, README "File
// formats") from the config's body, layout(s), motion, noise and synth
// options. Frames are generated and written in blocks, so memory stays
// bounded for any size; the same config and seed write byte-identical data.
#include "framework/config/decode.h"
#include "framework/config/yaml_io.h"
#include "framework/core/logging.h"
#include "framework/core/progress.h"
#include "framework/core/provenance.h"
#include "framework/core/timer.h"
#include "framework/io/mocap_dataset.h"
#include "framework/tasks/components.h"
#include "framework/tasks/task.h"

#include <fmt/format.h>

#include <algorithm>
#include <filesystem>
#include <future>

namespace soma {
namespace {

struct SynthTaskOptions {
  int64_t num_frames = 100000;      // frames written
  std::string split = "train";      // motion clips used: train, val or test
  std::string output = "synth.h5";  // relative to the run directory
  int block_size = 4096;            // frames generated per write
  int threads = 0;                  // 0 = the job's `threads`
  bool progress = true;             // show a progress bar
};

class SynthTask : public Task {
 public:
  explicit SynthTask(SynthTaskOptions options) : options_(std::move(options)) {}

  void Run(const ConfigNode& cfg, RunContext& ctx) override {
    BuildContext build(ctx.seed, ctx.output_dir.string());
    const Synthesizer synthesizer =
        BuildSynthesizer(cfg, SplitFromString(options_.split), build);
    const int threads =
        options_.threads > 0 ? options_.threads : std::max(1, ctx.num_threads);

    DatasetInfo info;
    info.labels = synthesizer.labels();
    info.num_points = synthesizer.num_points();
    info.frame_rate = synthesizer.frame_rate();
    info.seed = ctx.seed;
    if (const SlotTable* table = synthesizer.slot_table(); table != nullptr) {
      // A layout per placement block: the labels are slot indices.
      info.num_slots = synthesizer.num_labels();
      info.slot_table = *table;
    }
    info.config_yaml = DumpYaml(cfg);
    const BuildInfo build_info = GetBuildInfo();
    const GitState git = QueryGit();
    info.code_version = git.available && !git.sha.empty()
                            ? fmt::format("{} ({}{})",
                                          build_info.version,
                                          git.sha,
                                          git.dirty ? "-dirty" : "")
                            : build_info.version;
    info.attributes["created_by"] = "soma synth";
    info.attributes["split"] = options_.split;
    info.attributes["noise"] = synthesizer.noise().Describe();

    std::filesystem::path path(options_.output);
    if (path.is_relative()) path = ctx.output_dir / path;
    SOMA_LOG(INFO,
             "synth: {} frames (L = {}, N = {}) -> {} with {} thread(s)",
             options_.num_frames,
             synthesizer.num_labels(),
             synthesizer.num_points(),
             path.string(),
             threads);
    Timer timer;
    DatasetWriter writer(path, info);
    ProgressBar bar(
        options_.num_frames,
        ProgressBar::Options{
            .label = "synth", .unit = "frames", .enabled = options_.progress});
    // Double buffering: block k is written (HDF5, compression) on a helper
    // thread while block k + 1 is generated.
    LabeledFrames blocks[2];
    std::future<void> pending;
    int current = 0;
    for (int64_t first = 0; first < options_.num_frames;
         first += options_.block_size) {
      const int64_t count =
          std::min<int64_t>(options_.block_size, options_.num_frames - first);
      synthesizer.Generate(ctx.seed, first, count, &blocks[current], threads);
      if (pending.valid()) pending.get();
      pending = std::async(
          std::launch::async,
          [&writer, &block = blocks[current]] { writer.Append(block); });
      bar.Update(count);
      current = 1 - current;
    }
    if (pending.valid()) pending.get();
    writer.Close();
    bar.Finish();
    const double seconds = timer.ElapsedSeconds();
    SOMA_LOG(INFO,
             "synth: wrote {} frames to {} in {:.1f}s ({:.0f} frames/s)",
             options_.num_frames,
             path.string(),
             seconds,
             options_.num_frames / std::max(seconds, 1e-9));
    ctx.ReportMetric("frames", static_cast<double>(options_.num_frames));
    ctx.ReportMetric("frames_per_second",
                     options_.num_frames / std::max(seconds, 1e-9));
    ctx.ReportMetric("num_points", synthesizer.num_points());
  }

 private:
  SynthTaskOptions options_;
};

}  // namespace

void RegisterSynthTask(Registry<Task>& registry) {
  registry.Register("synth", [](const ConfigNode& node, BuildContext&) {
    ConfigReader reader(node);
    SynthTaskOptions options;
    reader.Read("num_frames", &options.num_frames);
    reader.Read("split", &options.split);
    reader.Read("output", &options.output);
    reader.Read("block_size", &options.block_size);
    reader.Read("threads", &options.threads);
    reader.Read("progress", &options.progress);
    reader.Check("num_frames", options.num_frames >= 0, "num_frames >= 0");
    reader.Check("split",
                 options.split == "train" || options.split == "val" ||
                     options.split == "test",
                 "split is train, val or test");
    reader.Check("output", !options.output.empty(), "a non-empty file name");
    reader.Check("block_size", options.block_size >= 1, "block_size >= 1");
    reader.Check("threads", options.threads >= 0, "threads >= 0");
    reader.Finish();
    return std::make_unique<SynthTask>(options);
  });
}

}  // namespace soma
