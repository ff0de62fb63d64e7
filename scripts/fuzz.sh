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
# jobs, default nproc) adjust the build. A long exploratory run (the 10 M
# executions of the house issue) is set with:
#   SOMA_FUZZ_RUNS=N        stop after N executions in all (seconds=0: no time
#                           limit) instead of after the time alone
#   SOMA_FUZZ_WORKERS=W     W fuzzing processes sharing one corpus (libFuzzer
#                           -jobs/-workers), each running N/W executions; logs
#                           in <build>/<target>_fuzz.<i>.log
#   SOMA_FUZZ_MAX_LEN=L     the largest input (default per target, below)
#   SOMA_FUZZ_RSS_LIMIT_MB=M  the memory (RSS) a fuzzer may hold before libFuzzer
#                           reports it out of memory (default 2048; in a run of
#                           10 M inputs of the override target ASan's caches
#                           held 1.3 GB, still growing when it ended)
#   SOMA_FUZZ_TIMEOUT=T     seconds one input may take before it counts as a
#                           hang (default 10; 120 with several workers, which
#                           starve each other on few cores)
#   SOMA_FUZZ_SANITIZE=s    the sanitizers besides libFuzzer's coverage
#                           (default address,undefined; `undefined` alone runs
#                           the config target ~2x faster); a non-default value
#                           builds into build-fuzz-<s> unless
#                           SOMA_FUZZ_BUILD_DIR says otherwise
# e.g. SOMA_FUZZ_RUNS=10000000 SOMA_FUZZ_WORKERS=2 bash scripts/fuzz.sh override 0
# The summary line gives the executions of all workers together.
#
# Exit 0: no finding, or clang/libFuzzer unavailable (skipped with a message).
# Exit 1: a crash, leak, timeout or sanitizer report; the input is saved in
# build-fuzz/<target>_artifacts/ (copy it to tests/fuzz/corpus/<target>/ once
# fixed). Exit 2: usage error. Exit 130: the fuzzer was interrupted (SIGINT or
# SIGTERM, e.g. a batch job's time limit) before it found anything; an
# exploratory session's corpus is kept, so the same command goes on from there.
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
max_len="${SOMA_FUZZ_MAX_LEN:-$max_len}"
runs="${SOMA_FUZZ_RUNS:-}"
workers="${SOMA_FUZZ_WORKERS:-1}"
sanitize="${SOMA_FUZZ_SANITIZE:-address,undefined}"
timeout="${SOMA_FUZZ_TIMEOUT:-}"
rss_limit="${SOMA_FUZZ_RSS_LIMIT_MB:-2048}"
for number in "$seconds" "$max_len" "$workers" "$rss_limit" ${runs:+"$runs"} \
  ${timeout:+"$timeout"}; do
  if [[ ! "$number" =~ ^[0-9]+$ ]]; then
    echo "scripts/fuzz.sh: expected a non-negative integer, got '$number'" >&2
    exit 2
  fi
done
if ((workers < 1)); then
  echo "scripts/fuzz.sh: SOMA_FUZZ_WORKERS must be at least 1, got $workers" >&2
  exit 2
fi
if ((workers > 1)) && [[ -n "${3:-}" ]]; then
  echo "scripts/fuzz.sh: a fixed seed with $workers workers would explore the same inputs" \
    "$workers times; give no seed" >&2
  exit 2
fi
timeout="${timeout:-$((workers > 1 ? 120 : 10))}"
if ((seconds == 0)) && [[ -z "$runs" ]]; then
  echo "scripts/fuzz.sh: seconds=0 (no time limit) needs SOMA_FUZZ_RUNS" >&2
  exit 2
fi
seed_flag=()
if [[ -n "${3:-}" ]]; then
  seed_flag=(-seed="$3")
fi
default_build=build-fuzz
if [[ "$sanitize" != "address,undefined" ]]; then
  default_build="build-fuzz-${sanitize//,/-}"
fi
build="${SOMA_FUZZ_BUILD_DIR:-$default_build}"
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
if ! clang++ -fsanitize="fuzzer,$sanitize" "$probe/probe.cc" -o "$probe/probe" \
  >/dev/null 2>&1; then
  echo "$tag libFuzzer runtime not available (Debian: libclang-rt-14-dev); skipping"
  exit 0
fi

log="$probe/build.log"
if ! CC=clang CXX=clang++ cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DSOMA_BUILD_TESTS=ON -DSOMA_BUILD_FUZZERS=ON -DSOMA_FUZZ_SANITIZE="$sanitize" \
  >"$log" 2>&1 ||
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

limits=()
if ((seconds > 0)); then
  limits+=(-max_total_time="$seconds")
fi
if [[ -n "$runs" ]]; then
  limits+=(-runs="$(((runs + workers - 1) / workers))")
fi
log="$build/${target}_fuzz.log"
echo "$tag fuzzing ${what} for ${seconds}s${runs:+ or $runs executions}${3:+ (seed $3)}" \
  "($sanitize, max_len $max_len, $workers worker(s))"
# With several workers libFuzzer writes fuzz-<i>.log into its working
# directory (the build directory here), so every path it is given is absolute.
root="$PWD"
abs() { if [[ "$1" = /* ]]; then echo "$1"; else echo "$root/$1"; fi; }
args=("${seed_flag[@]}" "${limits[@]}" -max_len="$max_len" -rss_limit_mb="$rss_limit"
  -timeout="$timeout" -dict="$(abs "tests/fuzz/${target}.dict")"
  -artifact_prefix="$(abs "$artifacts")" -print_final_stats=1)
logs=("$log")
if ((workers > 1)); then
  args+=(-jobs="$workers" -workers="$workers")
  rm -f "$build/${target}"_fuzz.*.log "$build"/fuzz-*.log
  logs=()
fi
status=0
(cd "$build" && "$(abs "$build/tests/fuzz/${target}_fuzzer")" "${args[@]}" "$(abs "$corpus")" \
  "$(abs "$seeds")" >"$(abs "$log")" 2>&1) || status=$?
if ((workers > 1)); then
  for ((i = 0; i < workers; i++)); do
    mv "$build/fuzz-$i.log" "$build/${target}_fuzz.$i.log" 2>/dev/null || true
    logs+=("$build/${target}_fuzz.$i.log")
  done
fi
executed() {
  local total=0 l n
  for l in "${logs[@]}"; do
    n="$(grep -oE 'stat::number_of_executed_units: [0-9]+' "$l" 2>/dev/null |
      grep -oE '[0-9]+$' || echo 0)"
    total=$((total + n))
  done
  echo "$total"
}
# A worker's failure shows in its own log, not in the exit status of -jobs.
finding=0
if grep -lE '^==[0-9]+==ERROR|^SUMMARY: |runtime error:|invariant broken' "${logs[@]}" \
  >/dev/null 2>&1; then
  finding=1
fi
# libFuzzer exits 72 when SIGINT/SIGTERM interrupts it (a worker killed under
# -jobs leaves its parent to exit non-zero too); with no report in any log
# that is an interruption, not a finding.
if ((status != 0 && finding == 0)) &&
  grep -qE '^==[0-9]+== libFuzzer: run interrupted' "${logs[@]}" 2>/dev/null; then
  echo "$tag interrupted after $(executed) executions, no finding up to then" \
    "(corpus kept in $corpus)"
  exit 130
fi
if ((status != 0 || finding != 0)); then
  for l in "${logs[@]}"; do
    [[ -e "$l" ]] && grep -v '^#' "$l" | tail -n 40
  done
  echo "$tag FINDING: see $artifacts and ${logs[*]}"
  exit 1
fi
for l in "${logs[@]}"; do
  grep -E '^#[0-9]+[[:space:]]+DONE' "$l" || true
done
echo "$tag stat::number_of_executed_units: $(executed)"
echo "$tag no crashes"
