#!/bin/bash
# usage: cw.sh MODE STEPS "SEEDS" [extra args]
mode=$1; steps=$2; seeds=$3; shift 3
for s in $seeds; do
  (cd /work/i43 && PYTHONPATH=/work/i43 timeout 3000 /work/main/.venv/bin/aider-exo walk --mode $mode --steps $steps --seed $s --quiet "$@" 2>&1 | grep -v pybullet | grep "walk, \|step length" | tr '\n' ' '; echo) &
  if (( $(jobs -r | wc -l) >= 2 )); then wait -n; fi
done
wait
