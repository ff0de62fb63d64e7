// libFuzzer target for the C3D reader: ParseC3d on arbitrary bytes must
// either return or throw soma::Error; never crash, hang or over-allocate.
// When a parse succeeds, the result must be self-consistent and survive an
// EncodeC3d → ParseC3d round trip (points and validity unchanged), and
// ModelOutputColumns must flag each point once (these two consumer-side
// checks only up to kMaxCheckedPoints points; see there).
//
// Build: scripts/fuzz.sh c3d (clang, -fsanitize=fuzzer,address,undefined).
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

// A header may declare up to 65,535 points in a file of a few hundred bytes;
// the reader then makes a label per point, and the round trip and the column
// checks redo that work three more times (~100 ms per input under ASan with
// 63k points). The exploratory run's corpus filled with such inputs and its
// rate fell from ~4,500 to ~200 inputs/s. Both parses still run on every
// input, whatever it declares; the consumer-side checks, whose code paths are
// the same for 4,096 points as for 65,535 (the encoder's LABELS2.. chunks of
// 255 start at 256; POINT:USED above 32,767 is C3dWriter's unit test), run up
// to this many points.
constexpr int kMaxCheckedPoints = 4096;

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

// What the tools do with a parsed capture: write it back (the round trip),
// and tell model outputs (POINT:ANGLES..., Plug-in Gait's virtual points)
// from markers, one flag per point whatever the labels and groups.
void CheckConsumers(const soma::C3dData& d) {
  CheckRoundTrip(d);
  const std::vector<bool> outputs = soma::ModelOutputColumns(d);
  const std::vector<bool> non_position = soma::NonPositionColumns(d);
  REQUIRE(outputs.size() == static_cast<size_t>(d.num_points));
  REQUIRE(non_position.size() == outputs.size());
  for (size_t k = 0; k < outputs.size(); ++k) {
    REQUIRE(!non_position[k] || outputs[k]);
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
    if (d.num_points <= kMaxCheckedPoints) CheckConsumers(d);
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
