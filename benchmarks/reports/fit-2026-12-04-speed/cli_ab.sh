#!/usr/bin/env bash
# CPU (user+sys) of `jkatana fit TABLE --region hiraji` on the base and the branch, alternated ROUNDS times, with
# JAX's persistent compilation cache off (JKATANA_NO_JAX_CACHE=1): a first call with an empty $JKATANA_CACHE and a
# second call with the $JKATANA_CACHE the first one filled. Usage: cli_ab.sh BASE BRANCH TABLE [ROUNDS]; the
# branch's .venv python runs both, from /tmp (so that the working directory does not shadow PYTHONPATH).
set -euo pipefail
base=$1 branch=$2 table=$3 rounds=${4:-2}
py=$branch/.venv/bin/python
work=$(mktemp -d)
cd /tmp
for r in $(seq "$rounds"); do
  for v in base branch; do
    src=$base; [ "$v" = branch ] && src=$branch
    rm -rf "$work/cache"
    for call in first second; do
      s=$( { JKATANA_NO_JAX_CACHE=1 JKATANA_CACHE=$work/cache PYTHONPATH=$src /usr/bin/time -f "%U %S %e" \
             "$py" -m jkatana.cli fit "$table" --region hiraji -o "$work/p.json" >/dev/null 2>"$work/err"; } 2>&1; \
           tail -1 "$work/err")
      read -r u sy wall <<<"$s"
      printf '%s round %d %-6s call: cpu %6.2f s (user %s sys %s) wall %s s load %s\n' "$v" "$r" "$call" \
        "$(echo "$u + $sy" | bc)" "$u" "$sy" "$wall" "$(cut -d' ' -f1 /proc/loadavg)"
    done
  done
done
