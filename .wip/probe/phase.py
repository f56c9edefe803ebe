"""phase.py WT CFG LENGTH SEED: time and both-stick force by controller part x patient phase (fixed length)."""
import sys
wt, cfgp, L, seed = sys.argv[1], sys.argv[2], float(sys.argv[3]), int(sys.argv[4])
sys.path.insert(0, wt)
from collections import defaultdict
from config.loader import load_config
from tools import pipeline
from controller.factory import step_bounds
from controller.policy import StepPolicy
cfg = load_config(cfgp if cfgp != "-" else wt + "/config/default.yaml")
acc = defaultdict(lambda: [0, 0.0, 0.0])
def on_tick(res, core, host):
    w = host.patient; p = w.patient; f = w.world.contact_normal_force
    k = (core.gait_part[:6], p.phase.value[:6])
    s = f('forearm_l') + f('forearm_r')
    a = acc[k]; a[0] += 1; a[1] += s
    a[2] += w.kin.com[0] - max(p.ankle_xy('l')[0], p.ankle_xy('r')[0])
out = pipeline.walk(cfg, cycles=10, seed=seed, mode="full3d", on_tick=on_tick, compare_ratio=False,
                    policy=StepPolicy(step_bounds(cfg.controller), fixed_m=L))
n = sum(a[0] for a in acc.values()); tot = sum(a[1] for a in acc.values())
print(f"L {L} seed {seed}: cycles {out.cycles_completed} fall {out.fall_reason} ticks {n} mean both {tot/n:.0f} N; steps {len(out.landed)} mean step force (ctl) {2*out.mean_stick_force_n:.0f}")
for k, a in sorted(acc.items(), key=lambda kv: -kv[1][0]):
    print(f"  {k[0]:6s} {k[1]:6s} {a[0]/n*100:5.1f}% ticks  {a[1]/a[0]:5.0f} N  com-front ankle {a[2]/a[0]:+.3f}  share {a[1]/tot*100:5.1f}%")
