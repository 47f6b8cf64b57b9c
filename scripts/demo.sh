#!/usr/bin/env bash
# The README's first command: installs what is missing, builds, and runs the main job:
#   a loopd server on a private udpm URL (ttl=0), loopd-listen recording what it publishes, and a
#   two-robot stream of manhattan (with 20 random wrong loop closures when loopd-outliers is
#   built, solved by a robust variant) replayed into it by lcm-logplayer; then a summary and a
#   clean SIGINT stop, with loopd-view serving the live map at the printed URL meanwhile.
#   Outputs in build/demo/. Unattended; about a minute after the build.
set -euo pipefail
cd "$(dirname "$0")/.."
if [[ $(id -u) -eq 0 ]]; then bash scripts/install-deps.sh; fi
bash scripts/build.sh -DLOOPD_BUILD_TESTS=OFF

bin=build
data=../shared/datasets
out=build/demo
mkdir -p "$out"
rm -f "$out"/demo.lcmlog "$out"/estimate.g2o "$out"/covariances.txt "$out"/journal.lcmlog

# --- background processes: always cleaned up, also on failure or Ctrl-C -------------------
server_pid="" listen_pid="" player_pid="" view_pid=""
cleanup() {
  local rc=$?
  for p in $player_pid $listen_pid $view_pid; do kill "$p" 2>/dev/null || true; done
  if [[ -n $server_pid ]] && kill -0 "$server_pid" 2>/dev/null; then
    kill -INT "$server_pid" 2>/dev/null || true
    for _ in $(seq 50); do kill -0 "$server_pid" 2>/dev/null || break; sleep 0.1; done
    kill -KILL "$server_pid" 2>/dev/null || true
  fi
  wait 2>/dev/null || true
  [[ $rc -ne 0 ]] && echo "demo: failed (exit $rc); logs in $out/" >&2
  exit $rc
}
trap cleanup EXIT
trap 'exit 130' INT TERM

# --- the stream --------------------------------------------------------------------------
bash scripts/ensure-multicast.sh
url="udpm://239.255.76.67:$((20000 + $$ % 30000))?ttl=0"   # private port, never leaves the host
input="$data/manhattan.g2o"
solver=isam2
if [[ -x $bin/tools/loopd-outliers ]]; then
  echo "== adding 20 random wrong loop closures to manhattan (loopd-outliers)"
  "$bin/tools/loopd-outliers" "$input" --count 20 --mode random --seed 1 \
    --out "$out/manhattan-outliers.g2o" --truth "$out/manhattan-outliers-truth.json"
  input="$out/manhattan-outliers.g2o"
  for s in risam mm dcs; do  # risam: at the optimum on this stream (mm: ATE 0.12 m)
    if "$bin/tools/loopd-solve" --help 2>&1 | grep -qE "^ +$s "; then solver=$s; break; fi
  done
fi
echo "== writing a two-robot stream of $(basename "$input") to $out/demo.lcmlog (loopd-feed --log)"
"$bin/tools/loopd-feed" "$input" --robots 2 --log "$out/demo.lcmlog"

# --- the server and its listener -----------------------------------------------------------
echo "== starting loopd --solver $solver on $url"
"$bin/server/loopd" --lcm-url "$url" --solver "$solver" --journal "$out/journal.lcmlog" \
  >"$out/loopd.log" 2>&1 &
server_pid=$!
for _ in $(seq 100); do
  grep -q "loopd: solver" "$out/loopd.log" 2>/dev/null && break
  kill -0 "$server_pid" 2>/dev/null || { cat "$out/loopd.log" >&2; exit 1; }
  sleep 0.1
done
grep -q "loopd: solver" "$out/loopd.log" || { echo "demo: loopd did not start" >&2; exit 1; }

"$bin/tools/loopd-listen" --lcm-url "$url" --out "$out/estimate.g2o" \
  --covariances "$out/covariances.txt" --until-quiet 8 >"$out/listen.log" 2>&1 &
listen_pid=$!

# --- the live view: open the printed URL in a browser ---------------------------------------
# LOOPD_VIEW_PORT picks the port (default 8080, or any free one if 8080 is taken);
# LOOPD_DEMO_KEEP=1 keeps server and view running after the replay until Ctrl-C.
view_port=${LOOPD_VIEW_PORT:-8080}
for port in "$view_port" 0; do
  "$bin/tools/loopd-view/loopd-view" --lcm-url "$url" --port "$port" >"$out/view.log" 2>&1 &
  view_pid=$!
  for _ in $(seq 30); do grep -q "http://" "$out/view.log" 2>/dev/null && break; sleep 0.1; done
  if kill -0 "$view_pid" 2>/dev/null && grep -q "http://" "$out/view.log"; then break; fi
  view_pid=""
done
view_url=$(grep -o "http://[^ ]*" "$out/view.log" | head -1 || true)
echo "== live view of the map: ${view_url:-not available (see $out/view.log)}"
sleep 1

# --- replay ---------------------------------------------------------------------------------
# The log's clock advances 1 ms per pose; half speed = 500 poses/s, easy for udpm (never -s 0).
echo "== replaying $out/demo.lcmlog into loopd (lcm-logplayer -s 0.5)"
t0=$(date +%s.%N)
lcm-logplayer -s 0.5 -l "$url" "$out/demo.lcmlog" >"$out/logplayer.log" 2>&1 &
player_pid=$!
wait "$player_pid"; player_pid=""
echo "== replay done in $(awk -v a="$t0" -v b="$(date +%s.%N)" 'BEGIN{printf "%.1f", b - a}') s; waiting for the converged estimate"
for _ in $(seq 900); do kill -0 "$listen_pid" 2>/dev/null || break; sleep 0.1; done
if kill -0 "$listen_pid" 2>/dev/null; then kill -INT "$listen_pid"; fi
wait "$listen_pid" || true; listen_pid=""

if [[ ${LOOPD_DEMO_KEEP:-0} == 1 ]]; then
  echo "== server and view keep running (${view_url:-no view}); Ctrl-C to stop"
  wait "$server_pid" || true
fi

# --- stop the server cleanly (SIGINT: finishes the update, flushes the journal) -----------
kill -INT "$server_pid"
wait "$server_pid" || { echo "demo: loopd exited with an error" >&2; exit 1; }
server_pid=""

# --- summary --------------------------------------------------------------------------------
summary=$(grep "loopd-listen:" "$out/listen.log" | tail -1)
stopped=$(grep "loopd: stopped" "$out/loopd.log" | tail -1 | sed 's/.*loopd: //')
poses=$(sed -n 's/^loopd-listen: \([0-9]*\) poses.*/\1/p' <<<"$summary")
chi2=$(sed -n 's/.*chi2 \([^,]*\),.*/\1/p' <<<"$summary")
echo
echo "== loopd demo: $(basename "$input"), 2 robots, solver $solver"
echo "   poses estimated: ${poses:-?}   chi2: ${chi2:-?}   view: ${view_url:-none}"
echo "   listener: ${summary#loopd-listen: }"
echo "   server:   ${stopped:-?}"
echo "   outputs:  $out/estimate.g2o (estimate, g2o vertices)  $out/covariances.txt (latest-pose covariances)"
echo "             $out/journal.lcmlog (server journal; loopd --resume)  $out/demo.lcmlog (the stream)"
echo "             $out/loopd.log  $out/listen.log"
[[ -n $poses && $poses -gt 0 ]] || { echo "demo: no estimate recorded" >&2; exit 1; }
if [[ -x $bin/tools/loopd-eval && -f $out/manhattan-outliers-truth.json ]]; then
  # Quality: against the batch optimum of the clean file (chi2 above counts the wrong closures too).
  "$bin/tools/loopd-solve" "$data/manhattan.g2o" --solver lm --out "$out/reference.g2o" --quiet
  echo "   vs. the batch optimum of clean manhattan (loopd-eval):"
  "$bin/tools/loopd-eval" --reference "$out/reference.g2o" --estimate "$out/estimate.g2o" \
    --truth "$out/manhattan-outliers-truth.json" --graph "$out/manhattan-outliers.g2o" 2>&1 | sed 's/^/     /' || true
fi
