#!/usr/bin/env bash
# Configures and builds somalab into build/ (Release, tests on). Extra
# arguments are passed to `cmake --build` (e.g. --target soma).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install_deps.sh
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release -DSOMA_BUILD_TESTS=ON >/dev/null
cmake --build build -j"$(nproc)" "$@"
