// Training throughput of both engines side by side: one optimizer step
// (forward, labelling loss, backward, Adam) on random frames, at the model
// sizes and batch sizes of configs/scale/paper.yaml and configs/scale/cpu.yaml
// (L = 41 labels, N = 44 points, Sinkhorn with 35 iterations), exactly the
// step `soma train` runs: `torch` is libtorch autograd + torch::optim::Adam,
// `fast` is FastTrainer::Step + FusedAdamStep (train.engine=fast),
// `fast_bf16` the same with train.precision=bf16 (AMX, else AVX512_BF16;
// skipped where the CPU has neither).
// `cpu_any_layout_*`: the layout-conditioned labeller (model=soma_any_layout
// at scale=cpu) on sampled layouts as after the first epoch, every frame its
// own slot descriptors (L = 53 slots; odd frames hold 39 labels and 14 padded
// slots, as pig39 beside soma53), N = 56 points; its fast engine runs the
// label side on torch autograd (FastTrainer::Step).
// items_per_second = training frames per second; peak_rss_mib = the
// process's peak resident memory after the run (the rows run in order, so it
// is cumulative).
//
//   soma_bench_train_train_benchmark --benchmark_min_time=5
//
// Rows for 1 and 2 intra-op threads.
#include "framework/config/yaml_io.h"
#include "framework/core/build_info.h"
#include "framework/model/fast_train.h"
#include "framework/model/label_encoder.h"
#include "framework/model/labeler.h"
#include "framework/model/loss.h"
#include "framework/model/torch_utils.h"
#include "framework/train/optimizer.h"

#include <benchmark/benchmark.h>
#include <torch/torch.h>

#include "tests/bench/registrations.h"
#include <string>
#include <sys/resource.h>

namespace soma {
namespace {

constexpr int64_t kNumLabels = 41;
constexpr int64_t kNumPoints = 44;
constexpr int64_t kNumSlots = 53;     // the conditioned rows: soma53's labels
constexpr int64_t kSmallLayout = 39;  // and pig39's on odd frames

struct Scale {
  ConfigNode model;
  ConfigNode normalization;
  int64_t batch_size = 0;
};

// configs/model/soma.yaml and configs/normalization/sinkhorn.yaml with the
// `model` and `train.batch_size` overrides of configs/scale/<name>.yaml.
Scale LoadScale(const std::string& name, const std::string& model) {
  const std::string configs = std::string(SOMA_SOURCE_DIR) + "/configs/";
  Scale scale;
  scale.model = LoadConfigFile(configs + "model/" + model + ".yaml").content;
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

double PeakRssMib() {
  struct rusage usage {};
  getrusage(RUSAGE_SELF, &usage);
  return static_cast<double>(usage.ru_maxrss) / 1024.0;
}

void BM_TrainStep(benchmark::State& state,
                  const std::string& name,
                  const std::string& engine,
                  const std::string& model_name = "soma") {
  bench::RegisterComponents();  // registries (BuildLabeler); once per process
  SetTorchThreads(static_cast<int>(state.range(0)));
  const Scale scale = LoadScale(name, model_name);
  const bool conditioned = model_name == "soma_any_layout";
  const int64_t num_labels = conditioned ? kNumSlots : kNumLabels;
  const int64_t num_points = conditioned ? kNumSlots + 3 : kNumPoints;
  torch::manual_seed(0);
  Labeler model = BuildLabeler(scale.model, scale.normalization, num_labels);
  model->train();
  auto optimizer = AdamSpec().Build(model->parameters());
  const SomaLabelingLoss loss;
  const int64_t b = scale.batch_size;
  // Frames: every present label on a point in random order, 3 null points
  // (one ghost, two zero points).
  LabelSlots slots;
  if (conditioned) {
    slots.descriptors =
        torch::randn({b, num_labels, model->descriptor_width()});
    slots.mask = torch::ones({b, num_labels}, torch::kBool);
    for (int64_t f = 1; f < b; f += 2) {
      slots.mask[f]
          .narrow(0, kSmallLayout, num_labels - kSmallLayout)
          .fill_(false);
    }
    slots.descriptors.masked_fill_(slots.mask.logical_not().unsqueeze(2), 0.0);
  }
  torch::Tensor points = torch::randn({b, num_points, 3}) * 0.4;
  torch::Tensor labels = torch::empty({b, num_points}, torch::kLong);
  for (int64_t f = 0; f < b; ++f) {
    const int64_t present =
        conditioned && f % 2 == 1 ? kSmallLayout : num_labels;
    const torch::Tensor ids = torch::cat(
        {torch::arange(present),
         torch::full({num_points - present}, num_labels, torch::kLong)});
    const torch::Tensor perm = torch::randperm(num_points);
    labels[f] = ids.index_select(0, perm);
    const torch::Tensor null_slots =
        labels[f].eq(num_labels).nonzero().view(-1).slice(0, 0, 2);
    points[f].index_fill_(0, null_slots, 0.0);
  }
  AugmentedTargets targets = BuildAugmentedTargets(labels, num_labels);
  if (conditioned) {  // as the trainer: padded slots weigh zero
    const torch::Tensor columns =
        torch::cat({slots.mask.to(targets.weights.scalar_type()),
                    torch::ones({b, 1}, targets.weights.options())},
                   1)
            .unsqueeze(1);
    targets.weights = (targets.weights * columns).contiguous();
  }
  std::unique_ptr<FastTrainer> fast;
  if (engine == "fast" || engine == "fast_bf16") {
    std::string why_not;
    FastTrainerOptions options;
    options.bf16 = engine == "fast_bf16";
    fast = FastTrainer::Create(*model, loss, options, &why_not);
    if (fast == nullptr) {
      state.SkipWithError(why_not.c_str());
      return;
    }
  }
  auto step = [&]() -> double {
    if (fast != nullptr) {
      const double value =
          fast->Step(points, labels, conditioned ? &slots : nullptr);
      if (!FusedAdamStep(*optimizer)) optimizer->step();
      return value;
    }
    const LabelerOutput out = conditioned ? model->ForwardSlots(points, slots)
                                          : model->forward(points);
    const torch::Tensor value = loss.Compute(out.log_assignment, targets);
    optimizer->zero_grad();
    value.backward();
    optimizer->step();
    return value.item<double>();
  };
  for (int warmup = 0; warmup < 2; ++warmup) step();  // first-call costs
  for (auto _ : state) {
    benchmark::DoNotOptimize(step());
  }
  state.SetItemsProcessed(state.iterations() * b);
  state.counters["batch"] = static_cast<double>(b);
  state.counters["params"] =
      static_cast<double>(CountTrainableParameters(*model));
  state.counters["peak_rss_mib"] = PeakRssMib();
}

// Argument: intra-op threads (1, or 2 = the reference machine's cores).
BENCHMARK_CAPTURE(BM_TrainStep, cpu_torch, "cpu", "torch")
    ->Arg(1)
    ->Arg(2)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK_CAPTURE(BM_TrainStep, cpu_fast, "cpu", "fast")
    ->Arg(1)
    ->Arg(2)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK_CAPTURE(BM_TrainStep, cpu_fast_bf16, "cpu", "fast_bf16")
    ->Arg(1)
    ->Arg(2)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK_CAPTURE(
    BM_TrainStep, cpu_any_layout_torch, "cpu", "torch", "soma_any_layout")
    ->Arg(1)
    ->Arg(2)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK_CAPTURE(
    BM_TrainStep, cpu_any_layout_fast, "cpu", "fast", "soma_any_layout")
    ->Arg(1)
    ->Arg(2)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK_CAPTURE(BM_TrainStep, paper_torch, "paper", "torch")
    ->Arg(1)
    ->Arg(2)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK_CAPTURE(BM_TrainStep, paper_fast, "paper", "fast")
    ->Arg(1)
    ->Arg(2)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK_CAPTURE(BM_TrainStep, paper_fast_bf16, "paper", "fast_bf16")
    ->Arg(1)
    ->Arg(2)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

}  // namespace
}  // namespace soma
