// libFuzzer target for the command-line override grammar: ParseOverride on
// arbitrary text must either return or throw soma::Error; never crash or
// hang. When a parse succeeds, the override must survive a round trip:
// ParseOverride(o.ToString()) parses to the same type, key, package and value
// (or the same sweep values), and ToString() is then a fixed point.
//
// Build: scripts/fuzz.sh override (clang, -fsanitize=fuzzer,address,undefined).
#include "framework/config/node.h"
#include "framework/config/override.h"
#include "framework/core/error.h"
#include "framework/core/logging.h"

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace {

// A broken invariant is a finding: name it, then abort so libFuzzer saves
// the input.
void Fail(const char* condition, int line) {
  std::fprintf(
      stderr, "override_fuzzer.cc:%d: invariant broken: %s\n", line, condition);
  std::abort();
}
#define REQUIRE(condition) \
  ((condition) ? static_cast<void>(0) : Fail(#condition, __LINE__))

// Group options a glob() sweep is expanded against.
const std::vector<std::string>& GlobOptions() {
  static const std::vector<std::string> options = {
      "a", "adam", "b", "mysql", "postgres", "sgd", "x*y", "[z]"};
  return options;
}

// The values of a sweep, or nullopt if expanding it is a (legal) error, e.g.
// sort() over values of mixed types.
std::optional<std::vector<soma::ConfigNode>> Values(
    const soma::SweepSpec& spec) {
  try {
    return soma::SweepValues(spec, GlobOptions());
  } catch (const soma::Error&) {
    return std::nullopt;
  }
}

void CheckRoundTrip(const soma::Override& o) {
  const std::optional<std::vector<soma::ConfigNode>> values =
      o.IsSweep() ? Values(*o.sweep) : std::nullopt;
  if (o.IsSweep()) {
    // An empty sweep (e.g. range(0,0)) has no override text of its own. A
    // long range() (up to the parser's limit of a million values) is not
    // written out and parsed again: that costs seconds and gigabytes.
    if (!values.has_value() || values->empty() || values->size() > 1000) {
      return;
    }
    REQUIRE(soma::SweepValueStrings(*o.sweep, GlobOptions()).size() ==
            values->size());
  }
  const std::string text = o.ToString();
  soma::Override r;
  try {
    r = soma::ParseOverride(text);
  } catch (const soma::Error& e) {
    std::fprintf(
        stderr, "'%s' does not parse back: %s\n", text.c_str(), e.what());
    Fail("ParseOverride(o.ToString()) succeeds", __LINE__);
  }
  REQUIRE(r.type == o.type);
  REQUIRE(r.key == o.key);
  REQUIRE(r.package == o.package);
  REQUIRE(r.IsSweep() == o.IsSweep());
  REQUIRE(r.value.has_value() == o.value.has_value());
  if (o.value.has_value()) REQUIRE(*r.value == *o.value);
  if (o.IsSweep()) {
    const std::optional<std::vector<soma::ConfigNode>> again = Values(*r.sweep);
    REQUIRE(again.has_value());
    REQUIRE(*again == *values);
  }
  REQUIRE(r.ToString() == text);
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int* /*argc*/, char*** /*argv*/) {
  soma::Logger::SetConsoleLevel(soma::LogLevel::kError);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  std::optional<soma::Override> o;
  try {
    o = soma::ParseOverride(text);
  } catch (const soma::Error&) {
    return 0;
  }
  REQUIRE(o->input == text);
  (void)o->KeyWithPackage();
  CheckRoundTrip(*o);
  return 0;
}
