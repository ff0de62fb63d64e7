// Training throughput of both engines side by side: one optimizer step
// (forward, labelling loss, backward, Adam) on random frames, at the model
// sizes and batch sizes of configs/scale/paper.yaml and configs/scale/cpu.yaml
// (L = 41 labels, N = 44 points, Sinkhorn with 35 iterations), exactly the
// step `soma train` runs: `torch` is libtorch autograd + torch::optim::Adam,
// `fast` is FastTrainer::Step + FusedAdamStep (train.engine=fast),
// `fast_bf16` the same with train.precision=bf16 (AMX, else AVX512_BF16;
// skipped where the CPU has neither).
// `cpu_any_layout_*`: the layout-conditioned labeller (model=soma_any_layout
// at scale=cpu) on label slots as `soma train` samples them after the first
// epoch (synth/layout_sampler=mixed with perturbed copies, as the
// any_layout_perturbed_* variants): L = 96 slots (max_labels), each frame
// from its own placement block, even frames soma53's 53 labels in their own
// slot order, odd frames a perturbed copy of 42 labels of their own, the
// rest padded; N = 56 points. Its fast engine runs the label side on torch
// autograd (FastTrainer::Step), the label encoder once per distinct label
// set (CompactLabelSlots). `label_encoder_{whole,compact}`: that label
// encoder alone (forward and backward, training mode) on the batch's 64 x 96
// slots as they are, and on its distinct label sets (EncodeSlots).
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
// The conditioned rows: L_max slots (configs/synth/layout_sampler), soma53's
// labels on even frames, a perturbed copy's on odd frames.
constexpr int64_t kMaxSlots = 96;
constexpr int64_t kListedLayout = 53;
constexpr int64_t kPerturbedLayout = 42;
constexpr int64_t kConditionedPoints = kListedLayout + 3;

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

/// Labels frame `f` of a conditioned batch holds (in slots 0..K-1).
int64_t ConditionedLabels(int64_t f) {
  return f % 2 == 0 ? kListedLayout : kPerturbedLayout;
}

/// A conditioned training batch's label slots (see the header): one listed
/// layout in a random slot order per even frame, a layout of its own per odd
/// frame, padded to kMaxSlots.
LabelSlots TrainingSlots(int64_t batch, int64_t width) {
  const torch::Tensor listed = torch::randn({kListedLayout, width});
  LabelSlots slots;
  slots.descriptors = torch::zeros({batch, kMaxSlots, width});
  slots.mask = torch::zeros({batch, kMaxSlots}, torch::kBool);
  for (int64_t f = 0; f < batch; ++f) {
    const int64_t k = ConditionedLabels(f);
    slots.descriptors[f].narrow(0, 0, k).copy_(
        f % 2 == 0 ? listed.index_select(0, torch::randperm(k))
                   : torch::randn({k, width}));
    slots.mask[f].narrow(0, 0, k).fill_(true);
  }
  return slots;
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
  const int64_t num_labels = conditioned ? kMaxSlots : kNumLabels;
  const int64_t num_points = conditioned ? kConditionedPoints : kNumPoints;
  torch::manual_seed(0);
  Labeler model = BuildLabeler(scale.model, scale.normalization, num_labels);
  model->train();
  auto optimizer = AdamSpec().Build(model->parameters());
  const SomaLabelingLoss loss;
  const int64_t b = scale.batch_size;
  // Frames: every present label on a point in random order, 3 null points
  // (one ghost, two zero points).
  const LabelSlots slots =
      conditioned ? TrainingSlots(b, model->descriptor_width()) : LabelSlots{};
  torch::Tensor points = torch::randn({b, num_points, 3}) * 0.4;
  torch::Tensor labels = torch::empty({b, num_points}, torch::kLong);
  for (int64_t f = 0; f < b; ++f) {
    const int64_t present = conditioned ? ConditionedLabels(f) : num_labels;
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

void BM_LabelEncoder(benchmark::State& state, bool compact) {
  bench::RegisterComponents();
  SetTorchThreads(static_cast<int>(state.range(0)));
  const Scale scale = LoadScale("cpu", "soma_any_layout");
  torch::manual_seed(0);
  Labeler model = BuildLabeler(scale.model, scale.normalization, kMaxSlots);
  model->train();
  const int64_t b = scale.batch_size;
  const LabelSlots slots = TrainingSlots(b, model->descriptor_width());
  const torch::Tensor upstream =
      torch::randn({b, model->options().d_model, kMaxSlots});
  auto step = [&] {
    model->zero_grad();
    const torch::Tensor labels =
        compact
            ? model->label_encoder->EncodeSlots(slots.descriptors, slots.mask)
            : model->label_encoder->forward(slots.descriptors, slots.mask);
    const torch::Tensor value = (labels * upstream).sum();
    value.backward();
    return value.item<double>();
  };
  step();
  for (auto _ : state) {
    benchmark::DoNotOptimize(step());
  }
  state.SetItemsProcessed(state.iterations() * b);
  state.counters["batch"] = static_cast<double>(b);
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
BENCHMARK_CAPTURE(BM_LabelEncoder, label_encoder_whole, false)
    ->Arg(1)
    ->Arg(2)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK_CAPTURE(BM_LabelEncoder, label_encoder_compact, true)
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
