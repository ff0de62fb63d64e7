#!/usr/bin/env bash
# The test suite under AddressSanitizer + UndefinedBehaviorSanitizer: builds
# with -DSOMA_ASAN=ON into its own build directory (default build-asan; the
# normal build/ is untouched) and runs the tests there. A sanitizer report
# aborts the test binary that triggered it (halt_on_error, for UBSan too), so
# a clean run is rc 0.
#
#   scripts/sanitize.sh                  everything, then the whole CTest suite
#   scripts/sanitize.sh core config io   only those modules' test binaries
#                                        (<module>_tests), each run directly
#
# Module test binaries link only their module and those below it, so the
# lower modules build and run without libtorch or Ceres in minutes; the whole
# suite (libtorch, Ceres, the integration tests spawning an ASan `soma`) takes
# an hour or more on 2 cores. SOMA_ASAN_BUILD_DIR (default build-asan) and
# SOMA_ASAN_JOBS (parallel build jobs, default nproc) adjust the build.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install_deps.sh
build="${SOMA_ASAN_BUILD_DIR:-build-asan}"
jobs="${SOMA_ASAN_JOBS:-$(nproc)}"
export CCACHE_BASEDIR="${CCACHE_BASEDIR:-$PWD}"
cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DSOMA_BUILD_TESTS=ON -DSOMA_ASAN=ON \
  >/dev/null
# detect_leaks=0: libtorch, OpenMP and HDF5 keep process-lifetime allocations
# that LeakSanitizer reports at exit; every other report is fatal.
export ASAN_OPTIONS="halt_on_error=1:detect_leaks=0:strict_string_checks=1:${ASAN_OPTIONS:-}"
export UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1:${UBSAN_OPTIONS:-}"
if (($# == 0)); then
  cmake --build "$build" -j"$jobs"
  ctest --test-dir "$build" --output-on-failure -j"$(nproc)" --timeout 1800
  exit 0
fi
targets=()
for module in "$@"; do
  targets+=("${module}_tests")
done
cmake --build "$build" -j"$jobs" --target "${targets[@]}"
status=0
for target in "${targets[@]}"; do
  echo "[sanitize] $target"
  if ! "$build/tests/$target" --gtest_brief=1; then
    echo "[sanitize] $target FAILED"
    status=1
  fi
done
exit "$status"
