// The speed figures README.md quotes are the ones in the committed Google
// Benchmark JSONs of results/benchmarks/: each expected phrase is formatted
// here from the JSON's medians, so a regenerated JSON cannot leave a stale
// number behind in the README (issue #23's audit: the README once quoted a
// C3D rate that was in no JSON). Reads files only; fast.
#include "framework/core/file.h"
#include "framework/core/json.h"
#include "framework/testing/testing.h"

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <filesystem>
#include <string>

namespace soma {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

fs::path BenchmarkDir() { return testing::SourceDir() / "results/benchmarks"; }

std::string Readme() { return ReadFile(testing::SourceDir() / "README.md"); }

/// A benchmark JSON. Google Benchmark writes a user counter named like one of
/// its own keys twice (model_labeler.json's `threads`), which ReadJsonFile
/// refuses; nlohmann's own parser keeps the last, the counter.
Json ReadBenchmarkJson(const std::string& name) {
  return Json::parse(ReadFile(BenchmarkDir() / name));
}

/// The `median` aggregate of benchmark `run_name` in `file`; fails the test
/// (and returns null) when the JSON has no such row.
const Json* Median(const Json& file, const std::string& run_name) {
  for (const Json& row : JsonArray(*JsonFind(file, "benchmarks"))) {
    const Json* name = JsonFind(row, "run_name");
    const Json* aggregate = JsonFind(row, "aggregate_name");
    if (name != nullptr && aggregate != nullptr &&
        JsonString(*name) == run_name && JsonString(*aggregate) == "median") {
      return &row;
    }
  }
  ADD_FAILURE() << "no median row of " << run_name;
  return nullptr;
}

double Field(const Json* row, const char* key) {
  if (row == nullptr) return std::nan("");
  const Json* value = JsonFind(*row, key);
  return value == nullptr ? std::nan("") : JsonNumber(*value);
}

/// A row's real or CPU time in milliseconds, whatever its time_unit.
double Milliseconds(const Json* row, const char* key) {
  if (row == nullptr) return std::nan("");
  const std::string unit = JsonString(*JsonFind(*row, "time_unit"));
  const double scale = unit == "ns"   ? 1e-6
                       : unit == "us" ? 1e-3
                       : unit == "ms" ? 1.0
                                      : 1e3;
  return Field(row, key) * scale;
}

/// 3038.4 -> "3,038" (rounded, thousands separated as the README writes).
std::string Thousands(double value) {
  const auto n = static_cast<int64_t>(std::llround(value));
  std::string digits = std::to_string(n < 0 ? -n : n);
  for (int i = static_cast<int>(digits.size()) - 3; i > 0; i -= 3) {
    digits.insert(static_cast<size_t>(i), ",");
  }
  return (n < 0 ? "-" : "") + digits;
}

TEST(BenchmarkQuotesTest, ReadmeQuotesTheTrainingStepTableAsItsJsonSaysIt) {
  const Json json = ReadBenchmarkJson("train_step.json");
  const std::string readme = Readme();
  struct Model {
    const char* scale;
    const char* first_column;
  };
  for (const Model& model :
       {Model{"cpu", "| `scale=cpu` (191,934 parameters, batch 64) | "},
        Model{"paper",
              "| `scale=paper` (1,435,471 parameters, batch 256) | "}}) {
    std::string row = model.first_column;
    double rate[3][2] = {};  // [engine][threads - 1]
    int e = 0;
    for (const char* engine : {"torch", "fast", "fast_bf16"}) {
      const Json* one = Median(
          json,
          fmt::format("BM_TrainStep/{}_{}/1/real_time", model.scale, engine));
      const Json* two = Median(
          json,
          fmt::format("BM_TrainStep/{}_{}/2/real_time", model.scale, engine));
      rate[e][0] = Field(one, "items_per_second");
      rate[e][1] = Field(two, "items_per_second");
      row += fmt::format("{} / {} frames/s (CPU {} / {} ms) | ",
                         Thousands(rate[e][0]),
                         Thousands(rate[e][1]),
                         Thousands(Milliseconds(one, "cpu_time")),
                         Thousands(Milliseconds(two, "cpu_time")));
      ++e;
    }
    for (int engine : {1, 2}) {
      row += fmt::format("{:.1f}× / **{:.1f}×** |",
                         rate[engine][0] / rate[0][0],
                         rate[engine][1] / rate[0][1]);
      if (engine == 1) row += " ";
    }
    EXPECT_THAT(readme, HasSubstr(row));
  }
  // The run the table names: its date and its commit.
  const Json& context = *JsonFind(json, "context");
  const std::string date = JsonString(*JsonFind(context, "date"));
  EXPECT_THAT(readme,
              HasSubstr(fmt::format(
                  "{} {} UTC", date.substr(0, 10), date.substr(11, 5))));
  EXPECT_THAT(
      readme,
      HasSubstr(fmt::format(
          "commit {}",
          JsonString(*JsonFind(context, "soma_git_commit")).substr(0, 7))));
}

TEST(BenchmarkQuotesTest, ReadmeQuotesTheOtherBenchmarksAsTheirJsonsSayThem) {
  const std::string readme = Readme();

  const Json c3d = ReadBenchmarkJson("io_c3d.json");
  const double gib =
      Field(Median(c3d, "BM_ParseC3d/hdm05_intel_float"), "bytes_per_second") /
      (1024.0 * 1024.0 * 1024.0);
  EXPECT_THAT(
      readme,
      HasSubstr(fmt::format(
          "C3D parse of the HDM05 float file, median {:.2f} GiB/s", gib)));

  const Json markers = ReadBenchmarkJson("body_virtual_markers.json");
  EXPECT_THAT(
      readme,
      HasSubstr(fmt::format("median {:.0f}k\nframes/s",
                            Field(Median(markers, "BM_VirtualMarkers/cmu41"),
                                  "items_per_second") /
                                1e3)));

  const Json synth = ReadBenchmarkJson("synth_synthesizer.json");
  const auto k = [&](const char* name) {
    return Field(Median(synth, name), "items_per_second") / 1e3;
  };
  EXPECT_THAT(
      readme,
      HasSubstr(fmt::format("frames {:.0f}k frames/s on 1 thread, {:.0f}k on "
                            "2, with HDF5 writing "
                            "{:.1f}k frames/s",
                            k("BM_Synthesize/b_c_g/threads:1/ring:1/real_time"),
                            k("BM_Synthesize/b_c_g/threads:2/ring:1/real_time"),
                            k("BM_SynthesizeAndWrite/threads:1/real_time"))));

  const Json labeler = ReadBenchmarkJson("model_labeler.json");
  const Json* fast30 =
      Median(labeler, "BM_FastForward/batch:30/threads:2/block:0/real_time");
  const Json* fast1 =
      Median(labeler, "BM_FastForward/batch:1/threads:2/block:0/real_time");
  const Json* torch30 =
      Median(labeler, "BM_TorchForward/batch:30/threads:2/real_time");
  const Json* torch1 =
      Median(labeler, "BM_TorchForward/batch:1/threads:1/real_time");
  EXPECT_THAT(readme,
              HasSubstr(fmt::format(
                  "the optimised forward {} frames/s at batch 30 and {:.2f} ms "
                  "at batch 1 on 2 threads (plain\nlibtorch: {} frames/s, "
                  "{:.1f} ms on 1 thread)",
                  Thousands(Field(fast30, "items_per_second")),
                  Milliseconds(fast1, "real_time"),
                  Thousands(Field(torch30, "items_per_second")),
                  Milliseconds(torch1, "real_time"))));
}

}  // namespace
}  // namespace soma
