#!/usr/bin/env bash
# CPU (user+sys) of `jkatana fit TABLE --region hiraji` on the base and the branch, alternated ROUNDS times:
# a first call with an empty persistent compilation cache ($JKATANA_CACHE) and a second call with the cache
# the first one filled. Usage: cli_ab.sh BASE_CHECKOUT BRANCH_CHECKOUT TABLE [ROUNDS]; the branch's .venv
# python runs both (PYTHONPATH selects the checkout). Prints one line per call with the 1-minute load.
set -euo pipefail
base=$1 branch=$2 table=$3 rounds=${4:-2}
py=$branch/.venv/bin/python
work=$(mktemp -d)
for r in $(seq "$rounds"); do
  for v in base branch; do
    src=$base; [ "$v" = branch ] && src=$branch
    rm -rf "$work/cache"
    for call in first second; do
      s=$( { JKATANA_CACHE=$work/cache PYTHONPATH=$src /usr/bin/time -f "%U %S %e" \
             "$py" -m jkatana.cli fit "$table" --region hiraji -o "$work/p.json" >/dev/null 2>"$work/err"; } 2>&1; \
           tail -1 "$work/err")
      read -r u sy wall <<<"$s"
      printf '%s round %d %-6s call: cpu %6.2f s (user %s sys %s) wall %s s load %s\n' "$v" "$r" "$call" \
        "$(echo "$u + $sy" | bc)" "$u" "$sy" "$wall" "$(cut -d' ' -f1 /proc/loadavg)"
    done
  done
done
