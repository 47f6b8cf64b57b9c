#!/usr/bin/env bash
# The README's first command: installs what is missing, builds, and runs the main job.
# Until the server lands, the main job is the offline solver on a bundled benchmark world:
# manhattan (3500 poses) solved batch, then fed pose by pose as a robot would.
set -euo pipefail
cd "$(dirname "$0")/.."
if [[ $(id -u) -eq 0 ]]; then bash scripts/install-deps.sh; fi
bash scripts/build.sh -DLOOPD_BUILD_TESTS=OFF
data=../shared/datasets
out=build/demo
mkdir -p "$out"
echo "== batch Levenberg-Marquardt on manhattan"
build/tools/loopd-solve "$data/manhattan.g2o" --solver lm --out "$out/manhattan-lm.g2o" \
  --stats "$out/manhattan-lm.json"
echo "== wrote $out/manhattan-lm.g2o and $out/manhattan-lm.json"
