#!/usr/bin/env bash
# Installs what loopd needs on Debian 12 (run as root). Idempotent: installs only what is
# missing, so a machine that has everything spends no time here.
set -euo pipefail

packages=(
  build-essential cmake ninja-build pkg-config
  libeigen3-dev libsuitesparse-dev libopenblas0-serial
  liblcm-dev liblcm-bin liblcm-java default-jdk-headless
  libspdlog-dev libgtest-dev
  libceres-dev          # optional comparison baseline for the benchmarks
  clang-format          # the format check (tests/CMakeLists.txt, scripts/check-format.sh)
  iproute2 procps
  python3               # tools/compare (and its end-to-end test)
  chromium              # loopd-view's end-to-end test drives it headless (tests/tools/test_loopd_view)
)

missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "installing: ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq
  apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

# CHOLMOD calls BLAS through Debian's alternatives; the single-threaded OpenBLAS is the fast
# one for our small supernodes (the pthread build spins threads per call, the reference BLAS
# is 1.3-1.6x slower on the 3D factorizations).
arch_dir=/usr/lib/x86_64-linux-gnu
if [[ -e $arch_dir/openblas-serial/libblas.so.3 ]]; then
  update-alternatives --set libblas.so.3-x86_64-linux-gnu "$arch_dir/openblas-serial/libblas.so.3" >/dev/null
  update-alternatives --set liblapack.so.3-x86_64-linux-gnu "$arch_dir/openblas-serial/liblapack.so.3" >/dev/null
fi
