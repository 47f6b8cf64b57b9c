#!/usr/bin/env bash
# Installs what is missing, builds, and runs the whole test suite (what CI runs).
set -euo pipefail
cd "$(dirname "$0")/.."
if [[ $(id -u) -eq 0 ]]; then bash scripts/install-deps.sh; fi
bash scripts/ensure-multicast.sh
bash scripts/build.sh "$@"
cd build
ctest --output-on-failure --timeout 900 -j "$(nproc)"
