#!/bin/bash
# The default end alone on bob_100k x mosaic (16 views of 256x256), two builds
# alternated (BENCHMARKS.md "The sample DAG's wall time", the bob_100k line).
#
# usage: scripts/bench/end_ab.sh A_REPO B_REPO [PAIRS]
#
# Each REPO is a checkout with a release build (target/release); see evaluation_ab.sh
# for an older commit as a worktree. Needs the keep benchmark's bob_100k source views
# (benches/quality/keep.toml) and ../shared/data/scenes. Prints one line per run with
# the end's balance, search and colour fit phases and its CPU time (both cores' seconds:
# steadier than the wall time on a shared host); compares the two scene.ply files.
set -euo pipefail
A=$(realpath "$1"); B=$(realpath "$2"); PAIRS=${3:-3}
HERE=$(cd "$(dirname "$0")/../.." && pwd)
K=$HERE/benches/quality/runs-keep/bob_100k
SCENE=$HERE/../shared/data/scenes/bob_100k.splat
W=$(mktemp -d)
trap 'rm -rf "$W"' EXIT
for r in $(seq "$PAIRS"); do
  for v in A B; do
    repo=$A; [ $v = B ] && repo=$B
    rm -rf "$W/$v"
    s=$(date +%s.%N)
    PIPELINE_TIMING_FILE="$W/$v.json" "$repo/target/release/distill" --scene "$SCENE" \
      --source-views "$K/source" --model "$HERE/priors/patch" \
      --style "$HERE/benches/quality/styles/mosaic.png" --preset default --set seed=0 \
      --iters 0 --threads 0 --out "$W/$v" >/dev/null 2>&1
    e=$(date +%s.%N)
    python3 - "$W/$v.json" "$v" "$r" "$s" "$e" <<'PY'
import json, sys
d = json.load(open(sys.argv[1]))
ph = lambda k: d.get('phase:patch synthesis/' + k, 0.0)
print('end %s run %s: %.2f s (balance %.2f, search %.2f, colour fit %.2f; CPU %.2f s)' % (
    sys.argv[2], sys.argv[3], float(sys.argv[5]) - float(sys.argv[4]),
    ph('balance'), ph('search'), ph('colour fit'), d.get('cpu:patch synthesis', 0.0)))
PY
  done
done
cmp -s "$W/A/scene.ply" "$W/B/scene.ply" && echo "bob_100k scene.ply: identical" || echo "bob_100k scene.ply: differs"
