#!/usr/bin/env bash
# README command 2: installs what is missing, builds everything and runs the
# whole test suite (CTest; tests read real data from ../shared/data).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/build.sh
ctest --test-dir build --output-on-failure -j"$(nproc)" --timeout 600
# A bounded libFuzzer run of the C3D reader (clang; crashes fail the run),
# with a fixed seed so the same inputs are explored on every run.
bash scripts/fuzz_c3d.sh 30 1
