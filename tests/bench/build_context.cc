// Linked into every benchmark: records how *our* code was built in the JSON
// `context`. Google Benchmark's own `library_build_type` describes the
// benchmark library (Debian's is built without NDEBUG, so it says "debug"
// whatever our build type is).
#include "framework/core/provenance.h"

#include <benchmark/benchmark.h>

namespace soma {
namespace {

const bool kBuildContextAdded = [] {
  const BuildInfo build = GetBuildInfo();
  benchmark::AddCustomContext("soma_build_type", build.build_type);
  benchmark::AddCustomContext("soma_git_commit", build.git_commit);
  return true;
}();

}  // namespace
}  // namespace soma
