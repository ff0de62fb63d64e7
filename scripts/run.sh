#!/usr/bin/env bash
# README command 1: installs what is missing, builds `soma` and runs the main
# job on the embedded default configuration (no downloads, no ../shared).
# Extra arguments are passed to `soma` (overrides and flags).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/build.sh --target soma
exec ./build/soma "$@"
