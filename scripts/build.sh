#!/usr/bin/env bash
# Configures and builds somalab into build/ (Release, tests on). Extra
# arguments are passed to `cmake --build` (e.g. --target soma).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install_deps.sh
# ccache keys on the compiler command line, which holds absolute paths: with
# the repository root as its base directory they become relative, so another
# clone of the same commit (CI's fresh checkout) reuses this one's objects.
export CCACHE_BASEDIR="${CCACHE_BASEDIR:-$PWD}"
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release -DSOMA_BUILD_TESTS=ON >/dev/null
cmake --build build -j"$(nproc)" "$@"
