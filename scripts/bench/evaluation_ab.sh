#!/bin/bash
# The sample DAG and a 16-view evaluation, two builds alternated (BENCHMARKS.md "The
# sample DAG's wall time" and "Without the Inception measures").
#
# usage: scripts/bench/evaluation_ab.sh A_REPO B_REPO [PAIRS] [B_EVALUATE_FLAGS]
#
# Each REPO is a checkout with a release build (target/release) and its data-sample/;
# a git worktree of an older commit, built with CARGO_TARGET_DIR=<worktree>/target,
# with vendor/ linked to this checkout's, serves as A. The 16-view case is bob_100k x
# mosaic from the keep benchmark's runs (its source views and default views must
# exist: benches/quality/keep.toml). B_EVALUATE_FLAGS (default "--inception false")
# are given to B's evaluate in the 16-view case, as the sample DAG does. Prints one line
# per run; compares the two sample scene.ply files at the end. JOBS (default 2, as
# scripts/run-sample.sh runs it) is the sample DAG's --jobs.
set -euo pipefail
A=$(realpath "$1"); B=$(realpath "$2"); PAIRS=${3:-3}; BFLAGS=${4:---inception false}
JOBS=${JOBS:-2}
HERE=$(cd "$(dirname "$0")/../.." && pwd)
K=$HERE/benches/quality/runs-keep/bob_100k
ST=$HERE/benches/quality/styles/mosaic.png
W=$(mktemp -d)
trap 'rm -rf "$W"' EXIT
for r in $(seq "$PAIRS"); do
  for v in A B; do
    repo=$A; [ $v = B ] && repo=$B
    rm -rf "$W/sample" && mkdir "$W/sample" && cp -r "$repo/data-sample/." "$W/sample/"
    # A fresh work directory: none of the checkout's earlier runs, records or locks.
    rm -rf "$W/sample/runs" "$W/sample/.pipeline" "$W/sample/"*.lock
    t=$( (cd "$W/sample" && "$repo/target/release/pipeline" run --dag stylize.toml --jobs "$JOBS" 2>&1) \
      | grep -o "ran [0-9]*, .*(.*s)" | grep -o "([0-9.]*s)")
    echo "sample $v run $r $t"
    cp "$W/sample/runs/final/scene.ply" "$W/scene_$v.ply"
  done
  for v in A B; do
    repo=$A; flags=(); [ $v = B ] && { repo=$B; read -ra flags <<< "$BFLAGS"; }
    e=$repo/target/release/evaluate
    rm -rf "$W/ev" && mkdir "$W/ev"
    s=$(date +%s.%N)
    "$e" "${flags[@]}" --original "$K/source" --reference-only source --threads 0 --out "$W/ev/src" 2>/dev/null
    a=$(date +%s.%N)
    "$e" "${flags[@]}" --reference-only style --style "$ST" --original "$K/source" --threads 0 --out "$W/ev/sty" 2>/dev/null
    b=$(date +%s.%N)
    "$e" "${flags[@]}" --original "$K/source" --stylized "$K/mosaic/default-views" --style "$ST" \
      --reference "$W/ev/src" --reference "$W/ev/sty" --threads 0 --out "$W/ev/eval" 2>/dev/null
    c=$(date +%s.%N)
    python3 -c "print('eval16 $v run $r: eval-source %.1f s, eval-style %.1f s, evaluate %.1f s, total %.1f s' % ($a - $s, $b - $a, $c - $b, $c - $s))"
  done
done
cmp -s "$W/scene_A.ply" "$W/scene_B.ply" && echo "sample scene.ply: identical" || echo "sample scene.ply: differs"
