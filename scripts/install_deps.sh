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

SUDO=""
if [[ $(id -u) -ne 0 ]]; then SUDO="sudo"; fi

# Makes OpenBLAS' OpenMP flavour the BLAS/LAPACK that libtorch resolves
# (../shared/TOOLCHAIN.md section 1.2): through libblas.so.3 and
# liblapack.so.3, and through libopenblas.so.0, which the executables link
# directly (Ceres' CMake package finds BLAS for SuiteSparse as
# libopenblas.so). Debian's
# default for libopenblas.so.0 is the pthread flavour, whose own two threads
# spin beside torch's OpenMP ones: measured 1.7x slower training steps of the
# layout-conditioned model on 2 threads. Changes nothing when already set.
use_openmp_openblas() {
  local alt target current
  for alt in libblas.so.3-x86_64-linux-gnu liblapack.so.3-x86_64-linux-gnu \
    libopenblas.so.0-x86_64-linux-gnu; do
    target=$(update-alternatives --list "$alt" 2>/dev/null | grep openblas-openmp | head -1 || true)
    current=$(update-alternatives --query "$alt" 2>/dev/null | awk '/^Value:/ {print $2}' || true)
    if [[ -n "$target" && "$target" != "$current" ]]; then
      $SUDO update-alternatives --set "$alt" "$target" >/dev/null
      echo "[install_deps] $alt -> $target"
    fi
  done
}

missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if ((${#missing[@]} == 0)); then
  use_openmp_openblas
  exit 0
fi

echo "[install_deps] installing: ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
use_openmp_openblas
echo "[install_deps] done"
