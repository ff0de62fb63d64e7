// Training throughput: one optimizer step (forward, labelling loss, backward,
// Adam) on random frames, at the model sizes and batch sizes of
// configs/scale/paper.yaml and configs/scale/cpu.yaml (L = 41 labels, N = 44
// points, Sinkhorn with 35 iterations). items_per_second = training frames
// per second.
//
//   soma_bench_train_train_benchmark --benchmark_min_time=5
//
// Rows for 1 and 2 intra-op threads. On a loaded 2-core machine 1 thread is
// far more robust: libgomp's spinning threads collapse under contention.
#include "framework/config/yaml_io.h"
#include "framework/core/build_info.h"
#include "framework/framework.h"
#include "framework/model/labeler.h"
#include "framework/model/loss.h"
#include "framework/model/torch_utils.h"
#include "framework/train/optimizer.h"

#include <benchmark/benchmark.h>
#include <torch/torch.h>

#include <string>

namespace soma {
namespace {

constexpr int64_t kNumLabels = 41;
constexpr int64_t kNumPoints = 44;

struct Scale {
  ConfigNode model;
  ConfigNode normalization;
  int64_t batch_size = 0;
};

// configs/model/soma.yaml and configs/normalization/sinkhorn.yaml with the
// `model` and `train.batch_size` overrides of configs/scale/<name>.yaml.
Scale LoadScale(const std::string& name) {
  const std::string configs = std::string(SOMA_SOURCE_DIR) + "/configs/";
  Scale scale;
  scale.model = LoadConfigFile(configs + "model/soma.yaml").content;
  scale.normalization =
      LoadConfigFile(configs + "normalization/sinkhorn.yaml").content;
  const ConfigNode preset =
      LoadConfigFile(configs + "scale/" + name + ".yaml").content;
  if (const ConfigNode* model = preset.Find("model")) {
    for (const auto& [key, value] : model->entries()) {
      if (key == "backbone") {
        for (const auto& [bkey, bvalue] : value.entries()) {
          scale.model.at("backbone").Set(bkey, bvalue);
        }
      } else {
        scale.model.Set(key, value);
      }
    }
  }
  scale.batch_size = preset.at("train").at("batch_size").AsInt();
  return scale;
}

void BM_TrainStep(benchmark::State& state, const std::string& name) {
  InitFramework();  // registries (BuildLabeler); once per process
  SetTorchThreads(static_cast<int>(state.range(0)));
  const Scale scale = LoadScale(name);
  torch::manual_seed(0);
  Labeler model = BuildLabeler(scale.model, scale.normalization, kNumLabels);
  model->train();
  auto optimizer = AdamSpec().Build(model->parameters());
  const SomaLabelingLoss loss;
  const int64_t b = scale.batch_size;
  // Frames: 41 labelled points in random slots, 3 null slots (one ghost, two
  // zero points).
  torch::Tensor points = torch::randn({b, kNumPoints, 3}) * 0.4;
  torch::Tensor labels = torch::empty({b, kNumPoints}, torch::kLong);
  for (int64_t f = 0; f < b; ++f) {
    const torch::Tensor ids = torch::cat(
        {torch::arange(kNumLabels),
         torch::full({kNumPoints - kNumLabels}, kNumLabels, torch::kLong)});
    const torch::Tensor perm = torch::randperm(kNumPoints);
    labels[f] = ids.index_select(0, perm);
    const torch::Tensor null_slots =
        labels[f].eq(kNumLabels).nonzero().view(-1).slice(0, 0, 2);
    points[f].index_fill_(0, null_slots, 0.0);
  }
  const AugmentedTargets targets = BuildAugmentedTargets(labels, kNumLabels);
  auto step = [&] {
    const LabelerOutput out = model->forward(points);
    const torch::Tensor value = loss.Compute(out.log_assignment, targets);
    optimizer->zero_grad();
    value.backward();
    optimizer->step();
    return value;
  };
  for (int warmup = 0; warmup < 2; ++warmup) step();  // first-call costs
  for (auto _ : state) {
    benchmark::DoNotOptimize(step().item<float>());
  }
  state.SetItemsProcessed(state.iterations() * b);
  state.counters["batch"] = static_cast<double>(b);
  state.counters["params"] =
      static_cast<double>(CountTrainableParameters(*model));
}

// Argument: intra-op threads (1, or 2 = the reference machine's cores).
BENCHMARK_CAPTURE(BM_TrainStep, cpu, std::string("cpu"))
    ->Arg(1)
    ->Arg(2)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK_CAPTURE(BM_TrainStep, paper, std::string("paper"))
    ->Arg(1)
    ->Arg(2)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

}  // namespace
}  // namespace soma
