#!/bin/bash
# First and second call of jkatana fit (GTR), fit --bootstrap 200 and compare (all lobes) on one 1188-row table,
# each with an empty $JKATANA_CACHE, on the XLA pool $1 (1 or all). Run from the repository root after
#   .venv/bin/python benchmarks/reports/fit-2026-12-05-pool/table.py   (writes /tmp/jk-pool/t.csv)
T=$1
C=$(mktemp -d)
run() {
  local s; s=$(date +%s.%N)
  JKATANA_XLA_THREADS=$T JKATANA_CACHE=$C .venv/bin/jkatana "$@" >/dev/null 2>"$C/err" || tail -3 "$C/err"
  echo "$(date +%s.%N) - $s" | bc
}
a=$(run fit /tmp/jk-pool/t.csv -o "$C/p.json" --model gtr); b=$(run fit /tmp/jk-pool/t.csv -o "$C/p.json" --model gtr)
c=$(run fit /tmp/jk-pool/t.csv -o "$C/q.json" --model gtr --bootstrap 200); d=$(run fit /tmp/jk-pool/t.csv -o "$C/q.json" --model gtr --bootstrap 200)
e=$(run compare /tmp/jk-pool/t.csv -o "$C/cmp"); f=$(run compare /tmp/jk-pool/t.csv -o "$C/cmp")
echo "pool $T | fit gtr first $a second $b | fit --bootstrap 200 first $c second $d | compare first $e second $f (s)"
rm -rf "$C"
