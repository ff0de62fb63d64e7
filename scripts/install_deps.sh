#!/usr/bin/env bash
# Installs the Debian packages somalab needs. Idempotent: when every package is
# already installed it only runs one dpkg query (well under a second).
set -euo pipefail

PACKAGES=(
  build-essential cmake git pkg-config ccache clang-format
  # scripts/tidy.sh (CI runs it from scripts/test.sh).
  clang-tidy
  # The fuzzers (scripts/fuzz.sh): clang, its libFuzzer/sanitizer
  # runtimes and its OpenMP headers (the model library needs OpenMP).
  clang libclang-rt-14-dev libomp-14-dev
  libtorch-dev libeigen3-dev libyaml-cpp-dev libceres-dev libhdf5-dev
  libfmt-dev libgtest-dev libgmock-dev libbenchmark-dev
  libopenblas-dev libopenblas0-openmp zlib1g-dev
  # JSON (core/json), .npz archives (io/zip), PNG images (core/image).
  nlohmann-json3-dev libzip-dev libpng-dev
  python3 python3-h5py python3-numpy
  python3-nbconvert python3-nbformat python3-ipykernel python3-pandas python3-matplotlib
  # The browser test of `soma view` (tests/view/browser_test.py): headless.
  chromium
  # A one-node SLURM for the SLURM launcher's test (tests/integration/slurm_test.sh).
  slurm-wlm munge
)

missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if ((${#missing[@]} == 0)); then
  exit 0
fi

echo "[install_deps] installing: ${missing[*]}"
SUDO=""
if [[ $(id -u) -ne 0 ]]; then SUDO="sudo"; fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
# Make OpenBLAS (OpenMP flavour) the system BLAS/LAPACK that libtorch resolves
# through libblas.so.3; see ../shared/TOOLCHAIN.md section 1.2.
for alt in libblas.so.3-x86_64-linux-gnu liblapack.so.3-x86_64-linux-gnu; do
  target=$(update-alternatives --list "$alt" 2>/dev/null | grep openblas-openmp | head -1 || true)
  if [[ -n "$target" ]]; then $SUDO update-alternatives --set "$alt" "$target" >/dev/null; fi
done
echo "[install_deps] done"
