#!/bin/sh
# A/B of prof.py: the base commit's tree (BASE, a worktree of f131f7c) and this branch (NEW), alternating
# ROUNDS times; JKATANA_SHARED must name the shared folder.
BASE=${BASE:-/tmp/base-b}; NEW=${NEW:-$(cd "$(dirname "$0")/../../.." && pwd)}; ROUNDS=${ROUNDS:-2}
HERE=$(cd "$(dirname "$0")" && pwd)
for i in $(seq "$ROUNDS"); do
  for t in "$BASE" "$NEW"; do
    (cd "$t" && PYTHONPATH="$t" python "$HERE/prof.py" 2>&1 | grep -v Warn | sed "s|^|$(basename "$t") round $i: |")
  done
done
