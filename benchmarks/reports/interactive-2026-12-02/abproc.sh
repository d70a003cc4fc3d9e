#!/bin/bash
# alternate processes: abproc.sh OUT ROUNDS name=dir ... ; env VARIANTS (ab.py variant names), VIEWS
out=$1; rounds=$2; shift 2
for i in $(seq 1 $rounds); do
  for spec in "$@"; do
    name=${spec%%=*}; dir=${spec#*=}
    echo "== $name round $i $(uptime)" >> $out
    (cd $dir && JKATANA_SHARED=/work/shared PYTHONPATH=$dir timeout 600 /work/main/.venv/bin/python "$(dirname "$0")"/ab.py 3 $VARIANTS 2>&1 | grep -v Warn | grep -v "^caps" >> $out)
  done
done
echo DONE >> $out
