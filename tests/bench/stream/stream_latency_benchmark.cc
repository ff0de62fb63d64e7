// Per-frame latency of live labelling (issue #26 item 4): one frame at a time,
// as `soma stream` sees it, on the real CMU 01_01 take (2751 frames at 120 Hz)
// corrupted with OC_05_G_03_BT_50 (seed 0), with the bundled cmu41 model.
//   BM_StreamLabel/threads:T      per-frame labels + the online tracklet vote
//                                 (StreamLabeler), T intra-op threads;
//   BM_TcpRoundTrip               the reference client sends a frame (mm)
//                                 over localhost TCP, the TCP source +
//                                 StreamLabeler label it on another thread
//                                 and reply; time = send -> labels received;
//   BM_StreamLabelSolve/...       the same labelling, then stage II on the
//   frame's
//                                 labelled markers, warm-started from the
//                                 previous frame, with a Ceres time limit
//                                 (ms); stage I on the first 2 s of the clean
//                                 take (the calibration segment), procedural
//                                 body, cmu41 layout.
// One iteration = one frame (manual time); one pass over the take. Counters:
// p50_ms, p99_ms, max_ms of the per-frame latency (the iteration times).
//
//   soma_bench_stream_stream_latency_benchmark --benchmark_repetitions=3
// Run from the project root (models/cmu41, ../shared/data; or set
// SOMA_SOURCE_DIR / SOMA_SHARED_DATA).
#include "framework/body/marker_layout.h"
#include "framework/body/procedural_body.h"
#include "framework/io/c3d.h"
#include "framework/model/labeler.h"
#include "framework/model/torch_utils.h"
#include "framework/solve/labelled_markers.h"
#include "framework/solve/stage_i.h"
#include "framework/solve/stage_ii.h"
#include "framework/stream/frame_source.h"
#include "framework/stream/stream_labeler.h"
#include "framework/stream/stream_recorder.h"
#include "framework/synth/corruption.h"
#include "framework/train/trainer.h"

#include <benchmark/benchmark.h>

#include "tests/bench/registrations.h"
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <future>
#include <map>
#include <vector>

namespace soma {
namespace {

namespace fs = std::filesystem;

fs::path SharedData() {
  if (const char* env = std::getenv("SOMA_SHARED_DATA")) return env;
  return "../shared/data";
}

fs::path SourceDir() {
  if (const char* env = std::getenv("SOMA_SOURCE_DIR")) return env;
  return ".";
}

fs::path CmuTake() { return SharedData() / "c3d" / "cmu_01_01.c3d"; }

struct Take {
  std::vector<std::string> labels;  // the model's
  std::shared_ptr<LabelerImpl> model;
  std::vector<StreamFrame> frames;  // corrupted, metres, ids = columns
};

const Take& CorruptedTake() {
  static const Take* const kTake = [] {
    bench::RegisterComponents();  // the model registry, for the checkpoint
    auto* take = new Take;
    const fs::path checkpoint = SourceDir() / "models/cmu41/model.pt";
    take->labels = ReadCheckpointInfo(checkpoint).labels;
    take->model = LoadLabelerFromCheckpoint(checkpoint).ptr();
    const LabeledSequence clean = ReadLabeledC3d(CmuTake(), take->labels);
    const LabeledSequence corrupted = CorruptSequence(
        clean, ParseCorruptionSettingName("OC_05_G_03_BT_50"), 0);
    const LabeledFrames& f = corrupted.frames;
    for (int64_t t = 0; t < f.num_frames(); ++t) {
      StreamFrame& frame = take->frames.emplace_back();
      frame.number = t + 1;
      const float* p = f.frame_points(t);
      for (int k = 0; k < f.num_points; ++k) {
        const float* x = p + 3 * k;
        if (x[0] == 0 && x[1] == 0 && x[2] == 0) continue;
        frame.Add(k, x[0], x[1], x[2], 0.0f);
      }
    }
    return take;
  }();
  return *kTake;
}

void Report(benchmark::State& state, const LatencyStats& ms) {
  state.counters["p50_ms"] = ms.Quantile(0.5);
  state.counters["p99_ms"] = ms.Quantile(0.99);
  state.counters["max_ms"] = ms.Max();
  state.counters["frames"] = double(ms.count());
  state.counters["threads"] = TorchThreads();
}

double Seconds(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start)
      .count();
}

void BM_StreamLabel(benchmark::State& state) {
  SetTorchThreads(static_cast<int>(state.range(0)));
  const Take& take = CorruptedTake();
  StreamLabeler labeler(take.model, StreamLabelerOptions{});
  LatencyStats ms;
  int64_t t = 0;
  for (auto _ : state) {
    const StreamFrame& frame = take.frames[size_t(t) % take.frames.size()];
    const auto start = std::chrono::steady_clock::now();
    StreamLabels out = labeler.Label(frame, 1.0, t);
    benchmark::DoNotOptimize(out.labels.data());
    const double s = Seconds(start);
    state.SetIterationTime(s);
    ms.Add(1e3 * s);
    ++t;
  }
  Report(state, ms);
}
BENCHMARK(BM_StreamLabel)
    ->ArgName("threads")
    ->Arg(1)
    ->Arg(2)
    ->Iterations(2751)
    ->UseManualTime()
    ->Unit(benchmark::kMillisecond);

void BM_TcpRoundTrip(benchmark::State& state) {
  SetTorchThreads(1);
  const Take& take = CorruptedTake();
  TcpSourceOptions options;
  options.port = 0;
  TcpFrameSource source(options);
  const int port = source.Listen();
  std::future<void> server = std::async(std::launch::async, [&] {
    source.Open(take.labels);
    StreamLabeler labeler(take.model, StreamLabelerOptions{});
    StreamFrame frame;
    for (int64_t t = 0; source.Next(&frame); ++t) {
      const StreamLabels out = labeler.Label(frame, 0.001, t);
      LabelPacket reply;
      reply.number = frame.number;
      for (int l : out.labels) {
        reply.label_ids.push_back(l == labeler.num_labels() ? -1 : l);
      }
      reply.confidences = out.confidence;
      source.Reply(reply);
    }
  });
  FrameClient client("127.0.0.1", port, 10);
  LatencyStats ms;
  int64_t t = 0;
  for (auto _ : state) {
    StreamFrame frame = take.frames[size_t(t) % take.frames.size()];
    frame.number = t + 1;
    for (float& x : frame.xyz) x *= 1000.0f;  // the protocol's millimetres
    const auto start = std::chrono::steady_clock::now();
    client.Send(frame);
    const LabelPacket reply = client.Receive();
    benchmark::DoNotOptimize(reply.label_ids.data());
    const double s = Seconds(start);
    state.SetIterationTime(s);
    ms.Add(1e3 * s);
    ++t;
  }
  client.Close();
  server.get();
  Report(state, ms);
}
BENCHMARK(BM_TcpRoundTrip)
    ->Iterations(2751)
    ->UseManualTime()
    ->Unit(benchmark::kMillisecond);

const BodyModel& Body() {
  static const BodyModel* const kBody = new BodyModel(MakeProceduralBody());
  return *kBody;
}

const GaussianPosePrior& Prior() {
  static const GaussianPosePrior* const kPrior = new GaussianPosePrior(
      ProceduralPosePrior(Body(), ProceduralPosePriorOptions{}));
  return *kPrior;
}

struct Calibrated {
  MarkerModel model;
  std::vector<std::string> layout_labels;
};

/// Stage I on frames picked from the first 2 s of the clean take.
const Calibrated& Calibration() {
  static const Calibrated* const kCalibrated = [] {
    const MarkerLayout layout = MakeBuiltinLayout(Body(), "cmu41");
    auto [vids, dist] = MarkerVertices(layout);
    const LabelledMarkers markers = MatchToLayout(ReadC3d(CmuTake()), layout);
    auto* c = new Calibrated{MarkerModel(Body(), vids), markers.labels};
    const std::vector<Eigen::Matrix3Xd> segment(
        markers.frames.begin(),
        markers.frames.begin() + std::min<size_t>(240, markers.frames.size()));
    const StageIOptions options;
    std::vector<Eigen::Matrix3Xd> picked;
    for (int f : PickStageIFrames(segment, options))
      picked.push_back(segment[f]);
    SolveStageI(Body(), &c->model, dist, picked, &Prior(), options);
    return c;
  }();
  return *kCalibrated;
}

void BM_StreamLabelSolve(benchmark::State& state) {
  SetTorchThreads(1);
  const Take& take = CorruptedTake();
  const Calibrated& calibrated = Calibration();
  // Model label id -> layout marker index (-1: not in the layout).
  std::vector<int> marker_of(take.labels.size(), -1);
  for (size_t l = 0; l < take.labels.size(); ++l) {
    for (size_t m = 0; m < calibrated.layout_labels.size(); ++m) {
      if (calibrated.layout_labels[m] == take.labels[l]) marker_of[l] = int(m);
    }
  }
  StageIIOptions options;
  options.solver.max_solver_time_s = 1e-3 * double(state.range(0));
  StageIISolver solver(&calibrated.model, &Prior(), options);
  StreamLabeler labeler(take.model, StreamLabelerOptions{});
  const int M = static_cast<int>(calibrated.layout_labels.size());
  LatencyStats ms;
  int64_t t = 0;
  int failed = 0, time_limited = 0;
  double rms = 0;
  for (auto _ : state) {
    const StreamFrame& frame = take.frames[size_t(t) % take.frames.size()];
    const auto start = std::chrono::steady_clock::now();
    const StreamLabels out = labeler.Label(frame, 1.0, t);
    Eigen::Matrix3Xd observed = Eigen::Matrix3Xd::Constant(3, M, std::nan(""));
    for (int i = 0; i < frame.num_points(); ++i) {
      const int l = out.labels[size_t(i)];
      if (l >= int(marker_of.size()) || marker_of[size_t(l)] < 0) continue;
      for (int c = 0; c < 3; ++c) {
        observed(c, marker_of[size_t(l)]) = frame.xyz[3 * size_t(i) + c];
      }
    }
    Eigen::VectorXd params;
    const SolveSummary summary =
        solver.SolveFrame(static_cast<int>(t), observed, &params);
    benchmark::DoNotOptimize(params.data());
    const double s = Seconds(start);
    state.SetIterationTime(s);
    ms.Add(1e3 * s);
    failed += summary.usable() ? 0 : 1;
    time_limited += summary.termination == SolveTermination::kNoConvergence;
    rms += summary.usable() ? summary.rms_m : 0.0;
    ++t;
  }
  Report(state, ms);
  state.counters["time_limit_ms"] = double(state.range(0));
  state.counters["failed"] = failed;
  state.counters["no_convergence"] = time_limited;
  state.counters["mean_rms_mm"] = 1e3 * rms / std::max(1, int(t) - failed);
}
BENCHMARK(BM_StreamLabelSolve)
    ->ArgName("time_limit_ms")
    ->Arg(2)
    ->Arg(4)
    ->Arg(7)
    ->Iterations(2751)
    ->UseManualTime()
    ->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace soma
