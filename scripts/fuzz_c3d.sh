#!/usr/bin/env bash
# The C3D fuzzer session: scripts/fuzz_c3d.sh [seconds=60] [seed] is
# scripts/fuzz.sh c3d [seconds=60] [seed] (see there).
exec bash "$(dirname "$0")/fuzz.sh" c3d "$@"
