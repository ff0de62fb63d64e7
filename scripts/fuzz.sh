#!/usr/bin/env bash
# Bounded libFuzzer session (ASan + UBSan) of one target of tests/fuzz/:
#   c3d       the C3D parser (ParseC3d), seeded with the shared C3D files
#             (first 64 KiB of each) and tests/fuzz/corpus/c3d/
#   override  the command-line override grammar (ParseOverride), seeded with
#             tests/fuzz/corpus/override/
#   config    YAML loading, composition and interpolation (ParseYaml, Compose,
#             Resolve over a small config tree), seeded with configs/**/*.yaml
#             and tests/fuzz/corpus/config/
#   frame_protocol  the `soma stream` frame/hello/label packet decoders,
#             seeded with tests/fuzz/corpus/frame_protocol/
# An exploratory session (no seed) keeps its growing corpus in
# build-fuzz/<target>_corpus; a fixed-seed run starts from the committed seeds
# alone (build-fuzz/<target>_corpus_fixed, emptied first), so that a corpus an
# earlier session grew on the machine does not change what it explores.
#
#   scripts/fuzz.sh <target> [seconds=60] [seed]
#
# Without a seed libFuzzer picks one (an exploratory session: run it long).
# The test suite passes a fixed seed, so its short run explores the same
# inputs every time and a new finding means a change, not luck; a finding of
# an exploratory session is fixed and its input added to
# tests/fuzz/corpus/<target>/.
#
# SOMA_FUZZ_BUILD_DIR (default build-fuzz) and SOMA_FUZZ_JOBS (parallel build
# jobs, default nproc) adjust the build.
#
# Exit 0: no finding, or clang/libFuzzer unavailable (skipped with a message).
# Exit 1: a crash, leak, timeout or sanitizer report; the input is saved in
# build-fuzz/<target>_artifacts/ (copy it to tests/fuzz/corpus/<target>/ once
# fixed). Exit 2: usage error.
set -euo pipefail
cd "$(dirname "$0")/.."

target="${1:-}"
case "$target" in
  c3d)
    what="ParseC3d"
    max_len=65536
    ;;
  override)
    what="ParseOverride"
    max_len=512
    ;;
  config)
    what="ParseYaml + Compose + Resolve"
    max_len=4096
    ;;
  frame_protocol)
    what="DecodeFramePacket + DecodeHelloPacket + DecodeLabelPacket"
    max_len=4096
    ;;
  *)
    echo "usage: scripts/fuzz.sh c3d|override|config|frame_protocol [seconds=60] [seed]" >&2
    exit 2
    ;;
esac
seconds="${2:-60}"
seed_flag=()
if [[ -n "${3:-}" ]]; then
  seed_flag=(-seed="$3")
fi
build="${SOMA_FUZZ_BUILD_DIR:-build-fuzz}"
jobs="${SOMA_FUZZ_JOBS:-$(nproc)}"
tag="[fuzz_${target}]"

if ! command -v clang >/dev/null 2>&1 || ! command -v clang++ >/dev/null 2>&1; then
  echo "$tag clang not found; skipping the ${target} fuzzer"
  exit 0
fi
probe="$(mktemp -d)"
trap 'rm -rf "$probe"' EXIT
echo 'extern "C" int LLVMFuzzerTestOneInput(const unsigned char*, unsigned long) { return 0; }' \
  >"$probe/probe.cc"
if ! clang++ -fsanitize=fuzzer,address,undefined "$probe/probe.cc" -o "$probe/probe" \
  >/dev/null 2>&1; then
  echo "$tag libFuzzer runtime not available (Debian: libclang-rt-14-dev); skipping"
  exit 0
fi

log="$probe/build.log"
if ! CC=clang CXX=clang++ cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DSOMA_BUILD_TESTS=ON -DSOMA_BUILD_FUZZERS=ON >"$log" 2>&1 ||
  ! cmake --build "$build" --target "${target}_fuzzer" -j"$jobs" >>"$log" 2>&1; then
  tail -n 40 "$log"
  echo "$tag building the fuzzer failed"
  exit 1
fi

seeds="$build/${target}_seeds"
corpus="$build/${target}_corpus"
if [[ -n "${3:-}" ]]; then
  corpus="$build/${target}_corpus_fixed"
  rm -rf "$corpus"
fi
artifacts="$build/${target}_artifacts/"
rm -rf "$seeds"
mkdir -p "$seeds" "$corpus" "$artifacts"
case "$target" in
  c3d)
    for f in ../shared/data/c3d/*.c3d; do
      [[ -e "$f" ]] && head -c 65536 "$f" >"$seeds/$(basename "$f")"
    done
    ;;
  config)
    while IFS= read -r f; do
      cp "$f" "$seeds/configs_$(echo "${f#configs/}" | tr / _)"
    done < <(find configs -name '*.yaml' -size -4k | sort)
    ;;
esac
if compgen -G "tests/fuzz/corpus/$target/*" >/dev/null; then
  cp tests/fuzz/corpus/"$target"/* "$seeds/"
fi

echo "$tag fuzzing ${what} for ${seconds}s${3:+ (seed $3)}"
if ! "$build/tests/fuzz/${target}_fuzzer" "${seed_flag[@]}" -max_total_time="$seconds" \
  -max_len="$max_len" -rss_limit_mb=2048 -timeout=10 -dict="tests/fuzz/${target}.dict" \
  -artifact_prefix="$artifacts" -print_final_stats=1 "$corpus" "$seeds" \
  >"$build/${target}_fuzz.log" 2>&1; then
  grep -v '^#' "$build/${target}_fuzz.log" | tail -n 40
  echo "$tag FINDING: see $artifacts and $build/${target}_fuzz.log"
  exit 1
fi
grep -E '^#[0-9]+[[:space:]]+DONE|stat::number_of_executed_units' \
  "$build/${target}_fuzz.log" || true
echo "$tag no crashes"
