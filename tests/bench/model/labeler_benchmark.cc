// Labeler inference at the paper configuration (d_model 125, 8 layers, 5
// heads, 35 Sinkhorn iterations, L = 41 labels, N = 44 points per frame):
// the libtorch forward and the optimised FastLabeler at batch 1 and 30, and
// the Sinkhorn normalization alone, and the two ways of turning its rows into
// labels (task.inference.decode: argmax + SOMA's duplicate rule, or the
// one-to-one matching). items_per_second = frames per second.
//
//   soma_bench_model_labeler_benchmark --benchmark_repetitions=5
//       --benchmark_report_aggregates_only=true
//
// Intra-op threads: 2 (the reference machine's cores; libtorch would use 1),
// plus single-thread rows of the optimised path for reference.
#include "framework/model/fast_kernels.h"
#include "framework/model/fast_labeler.h"
#include "framework/model/inference.h"
#include "framework/model/labeler.h"
#include "framework/model/torch_utils.h"

#include <benchmark/benchmark.h>
#include <torch/torch.h>

#include <vector>

namespace soma {
namespace {

constexpr int64_t kNumLabels = 41;
constexpr int64_t kNumPoints = 44;
constexpr int kThreads = 2;

Labeler PaperModel() {
  torch::manual_seed(0);
  LabelerOptions options;
  options.num_labels = kNumLabels;
  SelfAttentionOptions attention;  // 125 / 8 layers / 5 heads
  Labeler model(options,
                SelfAttention(attention).ptr(),
                Sinkhorn(SinkhornOptions{}).ptr());
  model->eval();
  return model;
}

torch::Tensor Frames(int64_t batch) {
  torch::manual_seed(1);
  torch::Tensor points = torch::randn({batch, kNumPoints, 3}) * 0.4;
  points.select(1, kNumPoints - 1).zero_();  // a padding point per frame
  return points;
}

void BM_TorchForward(benchmark::State& state) {
  SetTorchThreads(static_cast<int>(state.range(1)));
  Labeler model = PaperModel();
  const torch::Tensor points = Frames(state.range(0));
  c10::InferenceMode guard;
  for (auto _ : state) {
    LabelerOutput out = model(points);
    benchmark::DoNotOptimize(out.label_ids.data_ptr<int64_t>());
  }
  state.SetItemsProcessed(state.iterations() * state.range(0));
  state.counters["threads"] = TorchThreads();
}
BENCHMARK(BM_TorchForward)
    ->ArgNames({"batch", "threads"})
    ->Args({1, kThreads})
    ->Args({30, kThreads})
    ->Args({1, 1})
    ->Args({30, 1})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

void BM_FastForward(benchmark::State& state) {
  SetTorchThreads(static_cast<int>(state.range(1)));
  Labeler model = PaperModel();
  FastLabelerOptions options;
  if (state.range(2) > 0)
    options.frames_per_block = static_cast<int>(state.range(2));
  FastLabeler fast(*model, options);
  const torch::Tensor points = Frames(state.range(0));
  for (auto _ : state) {
    LabelerOutput out = fast.Forward(points);
    benchmark::DoNotOptimize(out.label_ids.data_ptr<int64_t>());
  }
  state.SetItemsProcessed(state.iterations() * state.range(0));
  state.counters["threads"] = TorchThreads();
  state.counters["avx512"] = fast.isa() == internal::KernelIsa::kAvx512 ? 1 : 0;
}
// block = frames_per_block (0: the default, 8).
BENCHMARK(BM_FastForward)
    ->ArgNames({"batch", "threads", "block"})
    ->Args({1, kThreads, 0})
    ->Args({30, kThreads, 0})
    ->Args({1, 1, 0})
    ->Args({30, 1, 0})
    ->Args({30, kThreads, 4})
    ->Args({30, kThreads, 15})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

/// libtorch log-domain optimal transport (LogOptimalTransport), batch 30.
void BM_TorchSinkhorn(benchmark::State& state) {
  SetTorchThreads(kThreads);
  const int64_t batch = state.range(0);
  torch::manual_seed(2);
  const torch::Tensor scores = torch::randn({batch, kNumPoints, kNumLabels});
  const torch::Tensor alpha = torch::tensor(1.0f);
  c10::InferenceMode guard;
  for (auto _ : state) {
    torch::Tensor p = LogOptimalTransport(scores, alpha, 35);
    benchmark::DoNotOptimize(p.data_ptr<float>());
  }
  state.SetItemsProcessed(state.iterations() * batch);
}
BENCHMARK(BM_TorchSinkhorn)
    ->ArgName("batch")
    ->Arg(1)
    ->Arg(30)
    ->Unit(benchmark::kMicrosecond)
    ->UseRealTime();

/// The optimised per-frame Sinkhorn (double, scaling form), single thread.
void BM_FastSinkhorn(benchmark::State& state) {
  const int64_t batch = state.range(0);
  torch::manual_seed(2);
  const torch::Tensor scores = torch::randn({batch, kNumPoints, kNumLabels});
  std::vector<float> out(
      static_cast<size_t>(batch * (kNumPoints + 1) * (kNumLabels + 1)));
  std::vector<double> scratch;
  const internal::KernelIsa isa =
      internal::ResolveIsa(internal::KernelIsa::kAuto);
  for (auto _ : state) {
    for (int64_t b = 0; b < batch; ++b) {
      internal::SinkhornFrame(
          isa,
          scores.data_ptr<float>() + b * kNumPoints * kNumLabels,
          kNumLabels,
          kNumPoints,
          kNumLabels,
          1.0,
          35,
          out.data() + b * (kNumPoints + 1) * (kNumLabels + 1),
          scratch);
    }
    benchmark::DoNotOptimize(out.data());
  }
  state.SetItemsProcessed(state.iterations() * batch);
}
BENCHMARK(BM_FastSinkhorn)
    ->ArgName("batch")
    ->Arg(1)
    ->Arg(30)
    ->Unit(benchmark::kMicrosecond)
    ->UseRealTime();

/// Peaked per-point rows over L + 1 columns, as a trained labeler's: each
/// point puts most of its mass on one label, some frames' points on the same
/// one (so the duplicate rule and the matching have work to do).
torch::Tensor DecodeRows(int64_t batch) {
  torch::manual_seed(3);
  const torch::Tensor logits =
      torch::randn({batch, kNumPoints, kNumLabels + 1}) * 4.0;
  return logits.softmax(-1);
}

/// task.inference.decode: argmax per row with duplicates -> null, or the
/// one-to-one matching (the Hungarian method per frame).
void BM_Decode(benchmark::State& state, LabelDecode decode) {
  at::set_num_threads(1);
  const torch::Tensor rows = DecodeRows(state.range(0));
  const torch::Tensor valid =
      torch::ones({state.range(0), kNumPoints}, torch::kBool);
  for (auto _ : state) {
    benchmark::DoNotOptimize(
        decode == LabelDecode::kMatching
            ? MatchLabels(rows, valid)
            : ResolveDuplicateLabels(rows.argmax(-1), valid, kNumLabels));
  }
  state.SetItemsProcessed(state.iterations() * state.range(0));
}
BENCHMARK_CAPTURE(BM_Decode, argmax, LabelDecode::kArgmax)
    ->ArgName("batch")
    ->Arg(512)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK_CAPTURE(BM_Decode, matching, LabelDecode::kMatching)
    ->ArgName("batch")
    ->Arg(512)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

}  // namespace
}  // namespace soma
