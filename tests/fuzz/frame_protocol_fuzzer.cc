// libFuzzer target for the `soma stream` frame protocol
// (framework/stream/frame_protocol.h): DecodeFramePacket, DecodeHelloPacket
// and DecodeLabelPacket on arbitrary bytes must either return or throw
// soma::Error; never crash, read out of bounds or allocate from a garbage
// length. A frame packet that decodes re-encodes to the same bytes.
//
// Build: scripts/fuzz.sh frame_protocol (clang, -fsanitize=fuzzer,address,
// undefined).
#include "framework/core/error.h"
#include "framework/stream/frame_protocol.h"

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <span>
#include <vector>

namespace {

void Fail(const char* condition, int line) {
  std::fprintf(stderr,
               "frame_protocol_fuzzer.cc:%d: invariant broken: %s\n",
               line,
               condition);
  std::abort();
}
#define REQUIRE(condition) \
  ((condition) ? static_cast<void>(0) : Fail(#condition, __LINE__))

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::span<const uint8_t> bytes(data, size);
  try {
    const soma::StreamFrame frame = soma::DecodeFramePacket(bytes, "fuzz");
    REQUIRE(frame.xyz.size() == 3 * frame.track_ids.size());
    REQUIRE(frame.residuals.size() == frame.track_ids.size());
    const std::vector<uint8_t> again = soma::EncodeFramePacket(frame);
    REQUIRE(again.size() == size);
    REQUIRE(std::equal(again.begin(), again.end(), data));
  } catch (const soma::Error&) {
  }
  try {
    soma::DecodeHelloPacket(bytes, "fuzz");
  } catch (const soma::Error&) {
  }
  try {
    const soma::LabelPacket packet = soma::DecodeLabelPacket(bytes, "fuzz");
    REQUIRE(packet.label_ids.size() == packet.confidences.size());
  } catch (const soma::Error&) {
  }
  return 0;
}
