// C3D read/write throughput. Files are read into memory once; the benchmarks
// measure ParseC3d / EncodeC3d only (bytes/s = file bytes per second).
//
//   <build>/tests/bench/soma_bench_io_c3d_benchmark
//       --benchmark_repetitions=10 --benchmark_report_aggregates_only=true
#include "framework/io/c3d.h"

#include <benchmark/benchmark.h>

#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

namespace soma {
namespace {

// ../shared/data/c3d beside the project root (SOMA_SOURCE_DIR overrides).
std::filesystem::path C3dDir() {
  std::filesystem::path root;
  if (const char* env = std::getenv("SOMA_SOURCE_DIR")) {
    root = env;
  } else {
    root = std::filesystem::path(__FILE__).parent_path() / ".." / ".." / "..";
  }
  return root / ".." / "shared" / "data" / "c3d";
}

std::vector<uint8_t> LoadBytes(const std::string& name) {
  std::ifstream in(C3dDir() / name, std::ios::binary);
  return std::vector<uint8_t>(std::istreambuf_iterator<char>(in), {});
}

void BM_ParseC3d(benchmark::State& state, const std::string& name) {
  const std::vector<uint8_t> bytes = LoadBytes(name);
  if (bytes.empty()) {
    state.SkipWithError(("cannot read " + (C3dDir() / name).string()).c_str());
    return;
  }
  for (auto _ : state) {
    C3dData data = ParseC3d(bytes, name);
    benchmark::DoNotOptimize(data.points.data());
  }
  state.SetBytesProcessed(static_cast<int64_t>(state.iterations()) *
                          static_cast<int64_t>(bytes.size()));
}

void BM_EncodeC3d(benchmark::State& state, const std::string& name) {
  const std::vector<uint8_t> bytes = LoadBytes(name);
  if (bytes.empty()) {
    state.SkipWithError(("cannot read " + (C3dDir() / name).string()).c_str());
    return;
  }
  const C3dData data = ParseC3d(bytes, name);
  int64_t written = 0;
  for (auto _ : state) {
    std::vector<uint8_t> encoded = EncodeC3d(data);
    written += static_cast<int64_t>(encoded.size());
    benchmark::DoNotOptimize(encoded.data());
  }
  state.SetBytesProcessed(written);
}

// Intel float, no analogs (the HDM05 take, 2.8 MB): the headline number.
BENCHMARK_CAPTURE(BM_ParseC3d, hdm05_intel_float, "HDM_mm_01-02_03_120.c3d");
// Intel float with interleaved analog channels (skipped).
BENCHMARK_CAPTURE(BM_ParseC3d,
                  vicon_intel_float_analogs,
                  "vicon_nexus_markers_analogs.c3d");
// The other encodings of the same data.
BENCHMARK_CAPTURE(BM_ParseC3d, eb015_intel_int16, "Eb015pi.c3d");
BENCHMARK_CAPTURE(BM_ParseC3d, eb015_mips_float, "Eb015sr.c3d");
BENCHMARK_CAPTURE(BM_ParseC3d, eb015_dec_float, "Eb015vr.c3d");
BENCHMARK_CAPTURE(BM_EncodeC3d, hdm05, "HDM_mm_01-02_03_120.c3d");

}  // namespace
}  // namespace soma
