#!/usr/bin/env bash
# README command 2: installs what is missing, builds everything and runs the
# whole test suite (CTest; tests read real data from ../shared/data).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/build.sh
ctest --test-dir build --output-on-failure -j"$(nproc)" --timeout 600
# clang-tidy (.clang-tidy, warnings are errors) on the modules brought clean
# so far (scripts/tidy.sh --ci; its header says which and why not all).
bash scripts/tidy.sh --ci
# Bounded libFuzzer runs (clang; crashes fail the run) of the C3D reader, the
# override grammar and YAML loading + composition, 30 s each with a fixed seed
# so the same inputs are explored on every run.
for target in c3d override config; do
  bash scripts/fuzz.sh "$target" 30 1
done
