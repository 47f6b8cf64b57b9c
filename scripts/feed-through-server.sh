#!/bin/bash
# Feeds a dataset through a fresh loopd server and prints what loopd-listen saw at the end
# (robots, common frame, chi2, batches, decisions) and the wall time from the first batch to the
# converged estimate. With --keep DIR it leaves there what loopd-listen wrote (est.g2o, and
# decisions.json in loopd-solve's stats form) and the logs, for loopd-eval.
#   scripts/feed-through-server.sh [--build DIR] [--port P] [--keep DIR] DATASET [loopd flags] \
#       -- [loopd-feed flags]
# e.g. scripts/feed-through-server.sh ../shared/datasets/victoria_park.txt --solver risam \
#        -- --robots 2 --interleave --rate 0
set -euo pipefail
build=build
port=$((50000 + RANDOM % 10000))  # above the tests' own ports (20000-49999)
keep=""
while [[ $# -gt 0 && $1 == --* ]]; do
  case $1 in
    --build) build=$2; shift 2 ;;
    --port) port=$2; shift 2 ;;
    --keep) keep=$2; shift 2 ;;
    *) break ;;
  esac
done
[[ $# -ge 1 ]] || { sed -n 2,9p "$0"; exit 2; }
dataset=$1; shift
server_args=()
while [[ $# -gt 0 && $1 != -- ]]; do server_args+=("$1"); shift; done
[[ $# -gt 0 ]] && shift
url="udpm://239.255.76.67:$port?ttl=0"
if [[ -n $keep ]]; then
  mkdir -p "$keep"
  work=$keep
  trap 'kill $server 2>/dev/null || true' EXIT
else
  work=$(mktemp -d)
  trap 'kill $server 2>/dev/null || true; rm -rf "$work"' EXIT
fi
# The batches loopd-feed will send: one per pose that has something due.
batches=$("$build/tools/loopd-feed" "$dataset" "$@" --log "$work/feed.lcmlog" 2>&1 |
  sed -n 's/.* \([0-9]*\) batches logged.*/\1/p')
"$build/server/loopd" --lcm-url "$url" "${server_args[@]}" > "$work/loopd.log" 2>&1 &
server=$!
sleep 0.5
"$build/tools/loopd-listen" --lcm-url "$url" --out "$work/est.g2o" --decisions "$work/decisions.json" \
  --until-batches "$batches" \
  > "$work/listen.log" 2>&1 &
listen=$!
sleep 0.3
start=$(date +%s.%N)
"$build/tools/loopd-feed" "$dataset" "$@" --lcm-url "$url" --quiet
wait $listen
end=$(date +%s.%N)
kill -INT $server
wait $server || true
cat "$work/listen.log"
grep -E "join|anchor" "$work/loopd.log" || true
awk -v a="$start" -v b="$end" \
  'BEGIN { printf "wall time from the feed'"'"'s start to the converged estimate: %.2f s\n", b - a }'
