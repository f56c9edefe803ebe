#!/bin/bash
# usage: xstat.sh CONFIG "SEEDS" -> X at swing start: median, sd, p10, p90 over all steps
cfg=$1; seeds=$2; out=$(mktemp -d)
for s in $seeds; do
  (cd /work/i43 && PYTHONPATH=/work/i43 timeout 3000 /work/main/.venv/bin/aider-exo walk --mode full3d --steps 10 --seed $s --json --quiet --config $cfg > $out/$s.json 2>/dev/null) &
  if (( $(jobs -r | wc -l) >= 2 )); then wait -n; fi
done; wait
python3 - $out <<'PY'
import json, sys, glob, statistics as st
xs=[]; full=0; n=0
for f in glob.glob(sys.argv[1]+"/*.json"):
    d=json.load(open(f)); n+=1; full+= d["cycles_completed"]==10
    xs+=[s["x_ratio"] for s in d["steps"] if s.get("x_ratio") is not None]
    if d["cycles_completed"]!=10: print(" ", f.split("/")[-1], d["cycles_completed"], str(d.get("end") or d.get("fall_reason") or d.get("stalled"))[:80], [s.get("length_m") for s in d["steps"]][-3:])
xs.sort(); q=lambda p: xs[int(p*(len(xs)-1))]
print(f"walks {full}/{n}; X median {q(0.5):.3f} sd {st.pstdev(xs):.3f} p10 {q(0.1):.3f} p90 {q(0.9):.3f} (n={len(xs)})")
PY
