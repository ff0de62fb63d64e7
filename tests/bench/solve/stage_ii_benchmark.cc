// Stage II throughput (issue #8 target: >= 120 frames/s on 2 cores for the
// 41-marker layout on the procedural body): per-frame pose fits with warm
// starts over a sequence, one Ceres solve per frame (REFERENCE.md 7.4).
//   Synthetic: cmu41 markers of a procedural walk on a shaped body, 2 mm
//              Gaussian noise, the procedural pose prior.
//   CmuReal:   the first 240 frames of ../shared/data/c3d/cmu_01_01.c3d
//              after stage I on 12 frames (CPU time of one thread), and
//              the same on 2 threads (2 chunks, wall-clock time).
// One iteration = one whole sequence; items/s = frames/s.
//
//   soma_bench_solve_stage_ii_benchmark --benchmark_repetitions=3
//       --benchmark_report_aggregates_only=true
#include "framework/body/marker_layout.h"
#include "framework/body/procedural_body.h"
#include "framework/core/random.h"
#include "framework/io/c3d.h"
#include "framework/motion/procedural_motion.h"
#include "framework/solve/labelled_markers.h"
#include "framework/solve/stage_i.h"
#include "framework/solve/stage_ii.h"

#include <benchmark/benchmark.h>

#include <cstdlib>
#include <filesystem>
#include <thread>
#include <vector>

namespace soma {
namespace {

const BodyModel& Body() {
  static const BodyModel* const kBody = new BodyModel(MakeProceduralBody());
  return *kBody;
}

const GaussianPosePrior& Prior() {
  static const GaussianPosePrior* const kPrior = new GaussianPosePrior(
      ProceduralPosePrior(Body(), ProceduralPosePriorOptions{}));
  return *kPrior;
}

struct Sequence {
  MarkerModel model;
  std::vector<Eigen::Matrix3Xd> frames;
};

void Layout(std::vector<int>* vids, std::vector<double>* dist) {
  auto [ids, distances] = MarkerVertices(MakeBuiltinLayout(Body(), "cmu41"));
  *vids = std::move(ids);
  *dist = std::move(distances);
}

Sequence SyntheticSequence() {
  std::vector<int> vids;
  std::vector<double> dist;
  Layout(&vids, &dist);
  Rng rng(7);
  Eigen::VectorXd betas(Body().num_betas());
  for (int b = 0; b < betas.size(); ++b) betas(b) = 0.7 * rng.Normal();
  Sequence s{MarkerModel(Body(), vids), {}};
  s.model.SetShape(betas, NormalOffsets(Body(), betas, vids, dist));
  Rng clip_rng = rng.Stream("clip");
  const PoseSequence clip = GenerateProceduralMotion(
      "walk", Body(), ProceduralMotionOptions{}, clip_rng);
  for (const BodyPose& pose : clip.frames) {
    const Eigen::VectorXd f = PackFrameParams(pose);
    Eigen::Matrix3Xd p;
    s.model.Evaluate(f.data(), {}, &p, nullptr);
    for (int i = 0; i < p.size(); ++i) p.data()[i] += 0.002 * rng.Normal();
    s.frames.push_back(p);
  }
  return s;
}

std::filesystem::path SharedData() {
  if (const char* env = std::getenv("SOMA_SHARED_DATA")) return env;
  return "../shared/data";
}

void RunStageII(benchmark::State& state, const Sequence& s) {
  StageIIOptions options;
  StageIISolver solver(&s.model, &Prior(), options);
  int failed = 0;
  double rms = 0;
  for (auto _ : state) {
    solver.Reset();
    rms = 0;
    for (size_t t = 0; t < s.frames.size(); ++t) {
      Eigen::VectorXd params;
      const SolveSummary summary =
          solver.SolveFrame(static_cast<int>(t), s.frames[t], &params);
      failed += summary.usable() ? 0 : 1;
      rms += summary.rms_m;
      benchmark::DoNotOptimize(params.data());
    }
  }
  state.SetItemsProcessed(state.iterations() * s.frames.size());
  state.counters["frames"] = static_cast<double>(s.frames.size());
  state.counters["failed"] = failed;
  state.counters["mean_rms_mm"] = 1e3 * rms / s.frames.size();
}

void BM_StageIISynthetic(benchmark::State& state) {
  static const Sequence* const kSeq = new Sequence(SyntheticSequence());
  RunStageII(state, *kSeq);
}
BENCHMARK(BM_StageIISynthetic)->Unit(benchmark::kMillisecond);

const Sequence& CmuSequence() {
  static const Sequence* const kSeq = [] {
    std::vector<int> vids;
    std::vector<double> dist;
    Layout(&vids, &dist);
    const MarkerLayout layout = MakeBuiltinLayout(Body(), "cmu41");
    const LabelledMarkers markers =
        MatchToLayout(ReadC3d(SharedData() / "c3d" / "cmu_01_01.c3d"), layout);
    auto* s = new Sequence{MarkerModel(Body(), vids), {}};
    const StageIOptions options;
    std::vector<Eigen::Matrix3Xd> picked;
    for (int f : PickStageIFrames(markers.frames, options)) {
      picked.push_back(markers.frames[f]);
    }
    SolveStageI(Body(), &s->model, dist, picked, &Prior(), options);
    for (int t = 0; t < std::min(240, markers.num_frames()); ++t) {
      s->frames.push_back(markers.frames[t]);
    }
    return s;
  }();
  return *kSeq;
}

void BM_StageIICmuReal(benchmark::State& state) {
  RunStageII(state, CmuSequence());
}
BENCHMARK(BM_StageIICmuReal)->Unit(benchmark::kMillisecond);

// The same 240 frames in 2 contiguous chunks on 2 threads (BodySolveOptions::
// threads = 2), wall-clock time.
void BM_StageIICmuReal2Threads(benchmark::State& state) {
  const Sequence& s = CmuSequence();
  const int count = static_cast<int>(s.frames.size());
  for (auto _ : state) {
    std::vector<std::thread> workers;
    for (int k = 0; k < 2; ++k) {
      workers.emplace_back([&s, k, count] {
        StageIISolver solver(&s.model, &Prior(), StageIIOptions{});
        for (int t = k * count / 2; t < (k + 1) * count / 2; ++t) {
          Eigen::VectorXd params;
          solver.SolveFrame(t, s.frames[t], &params);
          benchmark::DoNotOptimize(params.data());
        }
      });
    }
    for (std::thread& w : workers) w.join();
  }
  state.SetItemsProcessed(state.iterations() * count);
}
BENCHMARK(BM_StageIICmuReal2Threads)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

}  // namespace
}  // namespace soma
