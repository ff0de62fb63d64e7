// Synthetic-frame throughput (issue #4 target: >= 50k frames/s on 2 cores for
// the 41-marker layout with the full b_c_g pipeline, writing HDF5).
// One iteration = one block of 4096 frames.
//
//   soma_bench_synth_synthesizer_benchmark --benchmark_repetitions=3
//       --benchmark_report_aggregates_only=true
#include "framework/body/marker_layout.h"
#include "framework/body/procedural_body.h"
#include "framework/config/yaml_io.h"
#include "framework/core/random.h"
#include "framework/io/mocap_dataset.h"
#include "framework/synth/synthesizer.h"

#include <benchmark/benchmark.h>

#include "tests/bench/registrations.h"
#include <filesystem>
#include <future>
#include <string>
#include <unistd.h>
#include <vector>

namespace soma {
namespace {

constexpr int64_t kBlock = 4096;

constexpr const char* kBCG = R"(
modules:
  - {name: occlusion, max_count: 5}
  - {name: ghosts, distribution: spherical_gaussian, max_count: 3}
  - {name: permutation}
)";

const BodyModel& Body() {
  static const BodyModel* const kBody = new BodyModel(MakeProceduralBody());
  return *kBody;
}

std::vector<PoseSequence> RandomMotions() {
  Rng rng(5);
  std::vector<PoseSequence> motions;
  for (int s = 0; s < 10; ++s) {
    PoseSequence sequence;
    sequence.name = "random_" + std::to_string(s);
    for (int f = 0; f < 100; ++f) {
      BodyPose pose = BodyPose::Rest(Body().num_joints());
      for (int j = 0; j < Body().num_joints(); ++j) {
        for (int c = 0; c < 3; ++c) pose.rotations(c, j) = 0.3 * rng.Normal();
      }
      pose.translation = Eigen::Vector3d(rng.Normal(), rng.Normal(), 0.0);
      sequence.frames.push_back(pose);
    }
    motions.push_back(std::move(sequence));
  }
  return motions;
}

Synthesizer MakeSynthesizer(const char* noise_yaml, int ring) {
  bench::RegisterComponents();
  BuildContext ctx;
  SynthesisOptions options;
  options.marker_ring = ring;
  return Synthesizer(Body(),
                     {MakeBuiltinLayout(Body(), "cmu41")},
                     RandomMotions(),
                     BuildNoisePipeline(ParseYaml(noise_yaml, "bench"), ctx),
                     options);
}

/// args: threads, marker ring.
void BM_Synthesize(benchmark::State& state, const char* noise_yaml) {
  const int threads = static_cast<int>(state.range(0));
  const Synthesizer synth =
      MakeSynthesizer(noise_yaml, static_cast<int>(state.range(1)));
  LabeledFrames frames;
  int64_t first = 0;
  for (auto _ : state) {
    synth.Generate(7, first, kBlock, &frames, threads);
    benchmark::DoNotOptimize(frames.points.data());
    first += kBlock;
  }
  state.SetItemsProcessed(state.iterations() * kBlock);  // frames
  state.counters["points"] = synth.num_points();
  state.counters["candidates"] = synth.num_candidate_markers();
}
BENCHMARK_CAPTURE(BM_Synthesize, b_c_g, kBCG)
    ->ArgsProduct({{1, 2}, {0, 1}})
    ->ArgNames({"threads", "ring"})
    ->UseRealTime()
    ->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_Synthesize, b, "modules: [{name: permutation}]")
    ->Args({1, 1})
    ->ArgNames({"threads", "ring"})
    ->UseRealTime()
    ->Unit(benchmark::kMillisecond);

/// Synthesis + streaming into an HDF5 dataset (the `soma synth` loop).
void BM_SynthesizeAndWrite(benchmark::State& state) {
  const int threads = static_cast<int>(state.range(0));
  const Synthesizer synth = MakeSynthesizer(kBCG, 1);
  DatasetInfo info;
  info.labels = synth.labels();
  info.num_points = synth.num_points();
  info.seed = 7;
  const std::filesystem::path path =
      std::filesystem::temp_directory_path() /
      ("soma_synth_bench_" + std::to_string(::getpid()) + ".h5");
  // As `soma synth`: block k is written on a helper thread while block
  // k + 1 is generated.
  LabeledFrames frames[2];
  int64_t first = 0;
  {
    DatasetWriter writer(path, info);
    std::future<void> pending;
    int current = 0;
    for (auto _ : state) {
      synth.Generate(7, first, kBlock, &frames[current], threads);
      if (pending.valid()) pending.get();
      pending = std::async(
          std::launch::async,
          [&writer, &block = frames[current]] { writer.Append(block); });
      current = 1 - current;
      first += kBlock;
    }
    if (pending.valid()) pending.get();
    writer.Close();
  }
  state.counters["file_MB"] = std::filesystem::file_size(path) / 1e6;
  std::filesystem::remove(path);
  state.SetItemsProcessed(state.iterations() * kBlock);
}
BENCHMARK(BM_SynthesizeAndWrite)
    ->Arg(1)
    ->Arg(2)
    ->ArgName("threads")
    ->UseRealTime()
    ->Unit(benchmark::kMillisecond);

/// HDF5 writing alone (the DatasetWriter of framework/io), for comparison.
void BM_WriteOnly(benchmark::State& state) {
  const Synthesizer synth = MakeSynthesizer(kBCG, 1);
  DatasetInfo info;
  info.labels = synth.labels();
  info.num_points = synth.num_points();
  const std::filesystem::path path =
      std::filesystem::temp_directory_path() /
      ("soma_synth_bench_w_" + std::to_string(::getpid()) + ".h5");
  LabeledFrames frames;
  synth.Generate(7, 0, kBlock, &frames, 2);
  {
    DatasetWriter writer(path, info);
    for (auto _ : state) writer.Append(frames);
    writer.Close();
  }
  std::filesystem::remove(path);
  state.SetItemsProcessed(state.iterations() * kBlock);
}
BENCHMARK(BM_WriteOnly)->UseRealTime()->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace soma
