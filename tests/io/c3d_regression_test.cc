// Inputs that once crashed the C3D parser under the fuzzer
// (tests/fuzz/corpus/crash-*): each must now parse or throw soma::Error.
// Run under -DSOMA_ASAN=ON to also catch memory errors and UB.
#include "framework/core/error.h"
#include "framework/io/c3d.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <vector>

namespace soma {
namespace {

std::vector<uint8_t> FileBytes(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::vector<uint8_t>(std::istreambuf_iterator<char>(in), {});
}

// Parses with the default and the most permissive options.
void ParseBothWays(const std::vector<uint8_t>& bytes) {
  try {
    ParseC3d(bytes, "regression");
  } catch (const Error&) {
  }
  try {
    C3dReadOptions options;
    options.allow_truncated = true;
    options.read_analogs = true;
    ParseC3d(bytes, "regression", options);
  } catch (const Error&) {
  }
}

TEST(C3dRegression, FuzzCrashInputsNoLongerCrash) {
  const auto dir = testing::SourceDir() / "tests" / "fuzz" / "corpus" / "c3d";
  ASSERT_TRUE(std::filesystem::is_directory(dir)) << dir;
  int inputs = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    if (entry.path().filename().string().rfind("crash-", 0) != 0) continue;
    SCOPED_TRACE(entry.path().string());
    ParseBothWays(FileBytes(entry.path()));
    ++inputs;
  }
  EXPECT_GE(inputs, 1);
}

// crash-19e1b0bd...: a parameter with zero elements (POINT:LABELS of a file
// with no points) made the parser memcpy from a null pointer (UBSan).
TEST(C3dRegression, EmptyParameterData) {
  C3dData d;
  d.frame_rate = 60.0;
  d.num_frames = 5;
  d.num_points = 0;
  d.points.resize(5, 0);
  const std::vector<uint8_t> bytes = EncodeC3d(d);
  const C3dData r = ParseC3d(bytes, "empty_labels");
  const C3dParameter* labels = r.FindParameter("POINT", "LABELS");
  ASSERT_NE(labels, nullptr);
  EXPECT_TRUE(labels->raw.empty());
  EXPECT_TRUE(labels->AsStrings().empty());
  EXPECT_EQ(r.num_frames, 5);
}

// crash-9676813b...: a float file with POINT:SCALE = -2.8e37 decodes a valid
// point's residual as +inf; the writer then wrote it as invalid, breaking the
// fuzzer's round-trip invariant. +inf residuals are now valid everywhere.
TEST(C3dRegression, InfiniteResidualStaysValid) {
  C3dData d;
  d.frame_rate = 50.0;
  d.num_frames = 1;
  d.num_points = 1;
  d.point_scale = -1.0f;
  d.points.setConstant(1, 3, 7.0f);
  d.residuals.setConstant(1, 1, 200.0f);
  std::vector<uint8_t> bytes = EncodeC3d(d);
  const float huge_scale = -2.8e37f;
  std::memcpy(bytes.data() + 12, &huge_scale, 4);  // header POINT:SCALE
  const C3dData r = ParseC3d(bytes, "huge_scale");
  ASSERT_TRUE(r.valid(0, 0));
  EXPECT_TRUE(std::isinf(r.residuals(0, 0)));
  const C3dData again = ParseC3d(EncodeC3d(r), "again");
  EXPECT_TRUE(again.valid(0, 0));
  EXPECT_EQ(again.Point(0, 0), r.Point(0, 0));
}

}  // namespace
}  // namespace soma
