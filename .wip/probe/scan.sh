#!/bin/bash
# scan of arm-model configs: name and mkcfg overrides per line
cd /tmp/probe
while read name args; do
  [ -z "$name" ] && continue
  /work/main/.venv/bin/python mkcfg.py /tmp/s7/$name.yaml $args
  r=$(cd /work/i43 && bash /tmp/probe/xstat.sh /tmp/s7/$name.yaml "0 1 2 3 4 5 6 7" 2>&1 | tail -1)
  echo "$name | $args | $r" >> /tmp/s7/scan.txt
done <<'LIST'
g1 sim.gait.strut_spread=0.3 sim.gait.stick_force_comfort_n=300 controller.gait.comfort_stick_n=300 sim.patient.intention.lean_x=0.62 sim.patient.intention.lean_spread=0.16 controller.compensation.xhat_com=0.7 controller.compensation.alpha=-0.3
g2 sim.gait.strut_spread=0.3 sim.gait.stick_force_comfort_n=330 controller.gait.comfort_stick_n=330 sim.patient.intention.lean_x=0.62 sim.patient.intention.lean_spread=0.16 controller.compensation.xhat_com=0.7 controller.compensation.alpha=-0.35
g3 sim.gait.strut_spread=0.3 sim.gait.stick_force_comfort_n=330 controller.gait.comfort_stick_n=330 sim.patient.intention.lean_x=0.65 sim.patient.intention.lean_spread=0.14 controller.compensation.xhat_com=0.72 controller.compensation.alpha=-0.3
g4 sim.gait.strut_spread=0.15 sim.gait.stick_force_comfort_n=330 controller.gait.comfort_stick_n=330 sim.patient.intention.lean_x=0.62 sim.patient.intention.lean_spread=0.16 controller.compensation.xhat_com=0.7 controller.compensation.alpha=-0.3
g5 sim.gait.strut_spread=0.3 sim.gait.stick_force_comfort_n=360 controller.gait.comfort_stick_n=360 sim.patient.intention.lean_x=0.62 sim.patient.intention.lean_spread=0.16 controller.compensation.xhat_com=0.7 controller.compensation.alpha=-0.3
g6 sim.gait.strut_spread=0.3 sim.gait.stick_force_comfort_n=330 controller.gait.comfort_stick_n=330 sim.patient.intention.lean_x=0.62 sim.patient.intention.lean_spread=0.16 controller.compensation.xhat_com=0.75 controller.compensation.alpha=-0.3
LIST
echo done >> /tmp/s7/scan.txt
