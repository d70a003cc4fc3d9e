#!/bin/sh
# A/B of the peer study's reference frame (../render-peer-2026-12-02-sample/ab.py: frame CPU and wall, median of
# REPS after a warm-up, each call building its environment and material as the study does): the base commit's
# tree (BASE, a worktree of b384fb0) and this branch (NEW), alternating ROUNDS times, at each of SPPS.
BASE=${BASE:-/tmp/base-d}; NEW=${NEW:-$(cd "$(dirname "$0")/../../.." && pwd)}; ROUNDS=${ROUNDS:-2}
SPPS=${SPPS:-"1 8"}; REPS=${REPS:-5}
AB=$(cd "$(dirname "$0")/../render-peer-2026-12-02-sample" && pwd)/ab.py
for i in $(seq "$ROUNDS"); do
  for spp in $SPPS; do
    for t in "$BASE" "$NEW"; do
      (cd "$t" && PYTHONPATH="$t" AB_OUT=${AB_OUT:-/tmp} python "$AB" "$spp" "$REPS" 2>&1 | grep -v Warn \
        | sed "s|^|$(basename "$t") round $i: |")
    done
  done
done
