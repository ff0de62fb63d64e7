// libFuzzer target for the C3D reader: ParseC3d on arbitrary bytes must
// either return or throw soma::Error; never crash, hang or over-allocate.
// When a parse succeeds, the result must be self-consistent and survive an
// EncodeC3d → ParseC3d round trip (points and validity unchanged), and
// ModelOutputColumns must flag each point once.
//
// Build: scripts/fuzz_c3d.sh (clang, -fsanitize=fuzzer,address,undefined).
#include "framework/core/error.h"
#include "framework/core/logging.h"
#include "framework/io/c3d.h"

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <span>
#include <vector>

namespace {

// A broken invariant is a finding: name it, then abort so libFuzzer saves
// the input.
void Fail(const char* condition, int line) {
  std::fprintf(
      stderr, "c3d_fuzzer.cc:%d: invariant broken: %s\n", line, condition);
  std::abort();
}
#define REQUIRE(condition) \
  ((condition) ? static_cast<void>(0) : Fail(#condition, __LINE__))

bool SameFloat(float a, float b) {
  return a == b || (std::isnan(a) && std::isnan(b));
}

void CheckInvariants(const soma::C3dData& d) {
  REQUIRE(d.num_frames >= 0 && d.num_points >= 0);
  REQUIRE(d.points.rows() == d.num_frames);
  REQUIRE(d.points.cols() == 3 * static_cast<Eigen::Index>(d.num_points));
  REQUIRE(d.residuals.rows() == d.num_frames);
  REQUIRE(d.residuals.cols() == d.num_points);
  REQUIRE(d.valid.rows() == d.num_frames && d.valid.cols() == d.num_points);
  REQUIRE(d.labels.size() == static_cast<size_t>(d.num_points));
  REQUIRE(d.descriptions.size() == static_cast<size_t>(d.num_points));
  for (Eigen::Index f = 0; f < d.points.rows(); ++f) {
    for (Eigen::Index p = 0; p < d.residuals.cols(); ++p) {
      if (d.valid(f, p)) {
        REQUIRE(d.residuals(f, p) >= 0.0f);
        REQUIRE(d.Point(f, p).allFinite());
      } else {
        REQUIRE(d.residuals(f, p) == -1.0f);
      }
    }
  }
}

void CheckRoundTrip(const soma::C3dData& d) {
  std::vector<uint8_t> encoded;
  try {
    encoded = soma::EncodeC3d(d);
  } catch (const soma::Error&) {
    return;  // e.g. a zero frame rate cannot be written: not a reader bug
  }
  const soma::C3dData r = soma::ParseC3d(encoded, "roundtrip");  // must work
  REQUIRE(r.num_frames == d.num_frames && r.num_points == d.num_points);
  REQUIRE(r.labels == d.labels);
  REQUIRE((r.valid == d.valid).all());
  for (Eigen::Index i = 0; i < d.points.size(); ++i) {
    REQUIRE(SameFloat(r.points.data()[i], d.points.data()[i]));
  }
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int* /*argc*/, char*** /*argv*/) {
  soma::Logger::SetConsoleLevel(soma::LogLevel::kError);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::span<const uint8_t> bytes(data, size);
  try {
    const soma::C3dData d = soma::ParseC3d(bytes, "fuzz");
    CheckInvariants(d);
    CheckRoundTrip(d);
    // Which columns are model outputs (POINT:ANGLES..., Plug-in Gait's
    // virtual points): one flag per point whatever the labels and groups.
    const std::vector<bool> outputs = soma::ModelOutputColumns(d);
    const std::vector<bool> non_position = soma::NonPositionColumns(d);
    REQUIRE(outputs.size() == static_cast<size_t>(d.num_points));
    REQUIRE(non_position.size() == outputs.size());
    for (size_t k = 0; k < outputs.size(); ++k) {
      REQUIRE(!non_position[k] || outputs[k]);
    }
  } catch (const soma::Error&) {
  }
  try {
    soma::C3dReadOptions options;
    options.allow_truncated = true;
    options.read_analogs = true;
    const soma::C3dData d = soma::ParseC3d(bytes, "fuzz", options);
    CheckInvariants(d);
    for (Eigen::Index i = 0; i < d.analog.samples.size(); ++i) {
      (void)d.analog.samples.data()[i];
    }
    for (const soma::C3dGroup& g : d.groups) {
      for (const soma::C3dParameter& p : g.parameters) {
        (void)p.NumElements();
        if (p.type == soma::C3dParameterType::kChar) {
          (void)p.AsStrings();
        } else {
          (void)p.AsFloats();
          try {
            (void)p.AsInts();
          } catch (const soma::IoError&) {
          }
        }
      }
    }
  } catch (const soma::Error&) {
  }
  return 0;
}
