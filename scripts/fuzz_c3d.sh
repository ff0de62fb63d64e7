#!/usr/bin/env bash
# Bounded libFuzzer session for the C3D parser (ASan + UBSan), seeded with the
# shared C3D files (first 64 KiB of each) and the regression inputs in
# tests/fuzz/corpus/. The growing corpus is kept in build-fuzz/c3d_corpus.
#
#   scripts/fuzz_c3d.sh [seconds=60] [seed]
#
# Without a seed libFuzzer picks one (an exploratory session: run it long).
# The test suite passes a fixed seed, so its short run explores the same
# inputs every time and a new finding means a change, not luck; a finding of
# an exploratory session is fixed and its input added to tests/fuzz/corpus/.
#
# Exit 0: no finding, or clang/libFuzzer unavailable (skipped with a message).
# Exit 1: a crash, leak, timeout or sanitizer report; the input is saved in
# build-fuzz/c3d_artifacts/ (copy it to tests/fuzz/corpus/ once fixed).
set -euo pipefail
cd "$(dirname "$0")/.."

seconds="${1:-60}"
seed_flag=()
if [[ -n "${2:-}" ]]; then
  seed_flag=(-seed="$2")
fi
build="${SOMA_FUZZ_BUILD_DIR:-build-fuzz}"

if ! command -v clang >/dev/null 2>&1 || ! command -v clang++ >/dev/null 2>&1; then
  echo "[fuzz_c3d] clang not found; skipping the C3D fuzzer"
  exit 0
fi
probe="$(mktemp -d)"
trap 'rm -rf "$probe"' EXIT
echo 'extern "C" int LLVMFuzzerTestOneInput(const unsigned char*, unsigned long) { return 0; }' \
  >"$probe/probe.cc"
if ! clang++ -fsanitize=fuzzer,address,undefined "$probe/probe.cc" -o "$probe/probe" \
  >/dev/null 2>&1; then
  echo "[fuzz_c3d] libFuzzer runtime not available (Debian: libclang-rt-14-dev); skipping"
  exit 0
fi

log="$probe/build.log"
if ! CC=clang CXX=clang++ cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DSOMA_BUILD_TESTS=ON -DSOMA_BUILD_FUZZERS=ON >"$log" 2>&1 ||
  ! cmake --build "$build" --target c3d_fuzzer -j"$(nproc)" >>"$log" 2>&1; then
  tail -n 40 "$log"
  echo "[fuzz_c3d] building the fuzzer failed"
  exit 1
fi

seeds="$build/c3d_seeds"
corpus="$build/c3d_corpus"
artifacts="$build/c3d_artifacts/"
rm -rf "$seeds"
mkdir -p "$seeds" "$corpus" "$artifacts"
for f in ../shared/data/c3d/*.c3d; do
  [[ -e "$f" ]] && head -c 65536 "$f" >"$seeds/$(basename "$f")"
done
if compgen -G "tests/fuzz/corpus/*" >/dev/null; then
  cp tests/fuzz/corpus/* "$seeds/"
fi

echo "[fuzz_c3d] fuzzing ParseC3d for ${seconds}s${2:+ (seed $2)}"
if ! "$build/tests/fuzz/c3d_fuzzer" "${seed_flag[@]}" -max_total_time="$seconds" -max_len=65536 \
  -rss_limit_mb=2048 -timeout=10 -dict=tests/fuzz/c3d.dict \
  -artifact_prefix="$artifacts" -print_final_stats=1 "$corpus" "$seeds" \
  >"$build/c3d_fuzz.log" 2>&1; then
  grep -v '^#' "$build/c3d_fuzz.log" | tail -n 40
  echo "[fuzz_c3d] FINDING: see $artifacts and $build/c3d_fuzz.log"
  exit 1
fi
grep -E '^#[0-9]+[[:space:]]+DONE|stat::number_of_executed_units' "$build/c3d_fuzz.log" || true
echo "[fuzz_c3d] no crashes"
