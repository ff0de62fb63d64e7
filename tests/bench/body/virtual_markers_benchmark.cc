// Virtual-marker synthesis throughput: one frame = new betas + new pose ->
// marker positions with normals (REFERENCE.md 3.3). Target: >= 100k frames/s
// on one core for the 41-marker CMU layout.
//
//   soma_bench_body_virtual_markers_benchmark --benchmark_repetitions=5
//       --benchmark_report_aggregates_only=true
#include "framework/body/marker_layout.h"
#include "framework/body/procedural_body.h"
#include "framework/body/virtual_markers.h"
#include "framework/core/random.h"

#include <benchmark/benchmark.h>

#include <vector>

namespace soma {
namespace {

const BodyModel& Body() {
  static const BodyModel* const kBody = new BodyModel(MakeProceduralBody());
  return *kBody;
}

struct Samples {
  std::vector<Eigen::VectorXd> betas;
  std::vector<BodyPose> poses;
};

const Samples& RandomSamples() {
  static const Samples* const kSamples = [] {
    auto* samples = new Samples();
    Rng rng(42);
    for (int i = 0; i < 1024; ++i) {
      Eigen::VectorXd b(Body().num_betas());
      for (int k = 0; k < b.size(); ++k) b(k) = rng.Normal();
      BodyPose pose = BodyPose::Rest(Body().num_joints());
      for (int j = 0; j < Body().num_joints(); ++j) {
        for (int c = 0; c < 3; ++c) pose.rotations(c, j) = 0.4 * rng.Normal();
      }
      pose.translation =
          Eigen::Vector3d(rng.Normal(), rng.Normal(), rng.Normal());
      samples->betas.push_back(b);
      samples->poses.push_back(pose);
    }
    return samples;
  }();
  return *kSamples;
}

void BM_VirtualMarkers(benchmark::State& state, const char* layout_name) {
  const MarkerLayout layout = MakeBuiltinLayout(Body(), layout_name);
  const VirtualMarkerSampler sampler(Body(), layout);
  const Samples& samples = RandomSamples();
  VirtualMarkerSampler::Workspace workspace;
  Eigen::Matrix3Xd markers;
  size_t i = 0;
  for (auto _ : state) {
    sampler.Sample(samples.betas[i], samples.poses[i], &workspace, &markers);
    benchmark::DoNotOptimize(markers.data());
    benchmark::ClobberMemory();
    i = (i + 1) % samples.betas.size();
  }
  state.SetItemsProcessed(state.iterations());  // frames
  state.counters["markers"] = layout.num_markers();
  state.counters["local_vertices"] = sampler.num_local_vertices();
}
BENCHMARK_CAPTURE(BM_VirtualMarkers, cmu41, "cmu41");
BENCHMARK_CAPTURE(BM_VirtualMarkers, superset89, "superset89");

// The reference path: pose every vertex and compute all normals.
void BM_FullMeshMarkers(benchmark::State& state) {
  const MarkerLayout layout = MakeBuiltinLayout(Body(), "cmu41");
  const Samples& samples = RandomSamples();
  size_t i = 0;
  for (auto _ : state) {
    const Eigen::Matrix3Xd v =
        PoseVertices(Body(), samples.betas[i], samples.poses[i]);
    const Eigen::Matrix3Xd m =
        MarkerPositions(layout, v, VertexNormals(v, Body().faces));
    benchmark::DoNotOptimize(m.data());
    i = (i + 1) % samples.betas.size();
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_FullMeshMarkers)->Unit(benchmark::kMillisecond);

void BM_MakeProceduralBody(benchmark::State& state) {
  for (auto _ : state) {
    const BodyModel body = MakeProceduralBody();
    benchmark::DoNotOptimize(body.template_vertices.data());
  }
}
BENCHMARK(BM_MakeProceduralBody)->Unit(benchmark::kMillisecond)->Iterations(3);

}  // namespace
}  // namespace soma
